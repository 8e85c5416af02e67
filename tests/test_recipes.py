"""The recipes: the recommended Grasper's YAML is the shipped agent's, and training aids reach training envs only."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
import yaml

from grasp_envs.registration import RECOMMENDED_GRASPER
from sb3_trpo_plus.application import cli
from sb3_trpo_plus.application.zoo import ALGO_FILES, ZOO_DIR, HyperparameterError, check_wrappers, evaluation_wrappers

ROOT = Path(__file__).resolve().parent.parent
AGENT = ROOT / "trained_agents" / "trpo_plus" / f"{RECOMMENDED_GRASPER}_1"
SCRIPTED_STARTS = "grasp_envs.wrappers.ScriptedStarts"


def _raw_entry(algo: str, env_id: str) -> dict[str, Any]:
    return yaml.safe_load((ZOO_DIR / ALGO_FILES[algo]).read_text())[env_id]  # type: ignore[no-any-return]


def test_recommended_grasper_yaml_is_the_shipped_agents_config() -> None:
    """The shipped agent is the run of the README's command, the YAML's recipe as it stands (agents.json names the
    command): its config.yml and the hyperparameters saved in its model zip (read as plain data, nothing unpickled)
    equal the YAML entry."""
    from sb3_trpo_plus.application.agents import read_model_data

    entry = _raw_entry("trpo_plus", RECOMMENDED_GRASPER)
    config = json.loads((AGENT / RECOMMENDED_GRASPER / "config.yml").read_text())
    assert config == entry
    manifest = json.loads((AGENT.parent.parent / "agents.json").read_text())[RECOMMENDED_GRASPER]
    assert manifest["command"] == f"trpo-plus train --env {RECOMMENDED_GRASPER} --seed 0 --sim-threads 2 --num-threads 1"
    assert manifest["command"] in (ROOT / "README.md").read_text()
    saved = read_model_data(AGENT / f"{RECOMMENDED_GRASPER}.zip")
    algorithm_keys = {
        "n_steps",
        "batch_size",
        "gamma",
        "gae_lambda",
        "target_kl",
        "n_critic_updates",
        "sample_reuse",
        "reuse_batches",
        "policy_update",
        "projection_epochs",
        "projection_minibatches",
        "overlap_collection",
    }
    assert algorithm_keys <= set(entry)
    for key in algorithm_keys:
        assert saved[key] == entry[key], key
    assert saved["n_envs"] == entry["n_envs"]
    assert entry["env_wrapper"] == [{SCRIPTED_STARTS: {"probability": 0.25, "steps": [50, 100]}}]
    assert entry["policy_kwargs"]["log_std_init"] == -1.0


@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("os.system", "is not a class of"),
        ([{"subprocess.call": {"args": "touch /tmp/x"}}], "is not a class of"),
        ("grasp_envs.Grasper3DEnv", "not a Wrapper subclass"),
        ("grasp_envs.wrappers.NoSuchWrapper", "no class"),
        ([{SCRIPTED_STARTS: [0.25]}], "must be a mapping"),
        ([{SCRIPTED_STARTS: {}, "gymnasium.wrappers.ClipAction": {}}], "with arguments is"),
    ],
)
def test_env_wrapper_names_only_wrapper_classes_of_known_packages(value: Any, message: str) -> None:
    with pytest.raises(HyperparameterError, match=message):
        check_wrappers(value, "f.yml: Grasper3D-v7: env_wrapper")


def test_evaluation_wrappers_leave_training_aids_out() -> None:
    clip = "gymnasium.wrappers.ClipAction"
    assert check_wrappers([clip, {SCRIPTED_STARTS: {"probability": 0.5}}], "here") == [
        clip,
        {SCRIPTED_STARTS: {"probability": 0.5}},
    ]
    assert evaluation_wrappers([clip, {SCRIPTED_STARTS: {"probability": 0.5}}]) == [clip]
    assert evaluation_wrappers([{SCRIPTED_STARTS: {}}]) is None
    assert evaluation_wrappers(None) is None


def test_trpo_plus_train_wraps_training_envs_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`trpo-plus train --env Grasper3D-v7 --vec-env dummy` with evaluation: the recipe's scripted starts wrap each of
    the training envs and none of the evaluation envs (rl-zoo3 alone would wrap both). The batched engine runs them
    itself (tests/test_zoo.py trains the recipe both ways to the same parameters)."""
    from grasp_envs.wrappers import ScriptedStarts

    made: list[int] = []
    original = ScriptedStarts.__init__

    def counting(self: ScriptedStarts, *args: Any, **kwargs: Any) -> None:
        made.append(1)
        original(self, *args, **kwargs)

    monkeypatch.setattr(ScriptedStarts, "__init__", counting)
    monkeypatch.chdir(tmp_path)
    tiny = [
        "-params",
        "n_envs:2",
        "n_steps:16",
        "batch_size:16",
        "rollout_workers:None",
        "overlap_collection:False",
        "--num-threads",
        "1",
        "--vec-env",
        "dummy",
    ]
    evaluation = ["--eval-freq", "16", "--eval-episodes", "1", "--n-eval-envs", "1"]
    cli.main(
        ["train", "--env", RECOMMENDED_GRASPER, "-n", "64", "--seed", "0", "-f", str(tmp_path / "logs"), *evaluation, *tiny]
    )
    assert len(made) == 2  # the two training envs; the evaluation env has none
    assert (tmp_path / "logs" / "trpo_plus" / f"{RECOMMENDED_GRASPER}_1" / f"{RECOMMENDED_GRASPER}.zip").is_file()


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("normalize: \"__import__('os').system('touch {mark}')\"", "normalize must be text of the form"),
        ("normalize: \"dict(norm_obs=__import__('os').system('touch {mark}'))\"", "must be a literal"),
        ("monitor_kwargs: \"__import__('os').system('touch {mark}')\"", "monitor_kwargs must be text"),
        ("callback: os.system", "is not a class of"),
        ("callback: stable_baselines3.common.vec_env.VecNormalize", "not a BaseCallback subclass"),
    ],
)
def test_yaml_text_is_never_evaluated(tmp_path: Path, line: str, message: str) -> None:
    """rl-zoo3 evals the text of ``normalize`` and ``monitor_kwargs`` and calls what ``callback`` names: our loader
    parses the text as literals and accepts callback classes of known packages only."""
    from sb3_trpo_plus.application.zoo import load_hyperparameters

    mark = tmp_path / "pwned"
    path = tmp_path / "bad.yml"
    path.write_text(f"Reacher2D-v1:\n  n_timesteps: 1000\n  policy: MlpPolicy\n  {line.format(mark=mark)}\n")
    with pytest.raises(HyperparameterError, match=message) as error:
        load_hyperparameters(path, "trpo_plus")
    assert str(path) in str(error.value)
    assert not mark.exists()


def test_yaml_dict_text_is_read_as_literals(tmp_path: Path) -> None:
    from sb3_trpo_plus.application.zoo import load_hyperparameters

    path = tmp_path / "ok.yml"
    path.write_text(
        'Reacher2D-v1:\n  n_timesteps: 1000\n  policy: MlpPolicy\n  normalize: "dict(norm_obs=True, norm_reward=False)"\n'
    )
    assert load_hyperparameters(path, "trpo_plus")["Reacher2D-v1"]["normalize"] == {"norm_obs": True, "norm_reward": False}


def test_make_model_builds_the_recipe_in_python() -> None:
    """``make_model`` gives the model ``trpo-plus train`` trains: the recipe's hyperparameters, its rollout worker
    collecting the next segment during each update, and its scripted training starts."""
    from stable_baselines3.common.vec_env import VecNormalize

    from grasp_envs.wrappers import ScriptedStarts
    from sb3_trpo_plus import TRPOPlus, make_model, recipe
    from sb3_trpo_plus.rollouts import ProcessRollouts

    params = recipe(RECOMMENDED_GRASPER)
    assert (params["rollout_workers"], params["overlap_collection"]) == ("process:1", True)
    model = make_model(RECOMMENDED_GRASPER, seed=3, n_steps=16, batch_size=16)
    try:
        assert isinstance(model, TRPOPlus) and model.n_steps == 16 and model.seed == 3 and model.overlap_collection
        assert (model.gamma, model.policy_update) == (params["gamma"], "projection")
        assert (model.projection_epochs, model.projection_minibatches) == (5, 8)
        assert model.projection_optimizer is not None  # the projected trust region trains the actor
        env = model.get_env()
        assert isinstance(env, VecNormalize) and env.num_envs == params["n_envs"] and env.gamma == params["gamma"]
        assert isinstance(env.venv, ProcessRollouts) and env.venv.num_workers == 1
        model.learn(3 * 16 * params["n_envs"])
        assert model.num_timesteps == 3 * 16 * params["n_envs"]
        assert env.venv.env_is_wrapped(ScriptedStarts) == [True] * params["n_envs"]  # in the worker's batched envs
    finally:
        model.get_env().close()
    with pytest.raises(HyperparameterError, match="no recipe for 'CartPole-v1'"):
        make_model("CartPole-v1")
    with pytest.raises(ValueError, match="algo must be one of"):
        recipe(RECOMMENDED_GRASPER, algo="sac")


def test_make_model_on_one_process_names_the_recipes_workers() -> None:
    """vec_env='batch' or 'dummy' on a recipe with rollout workers says how to leave them out, and then builds."""
    from grasp_envs import BatchVecEnv
    from sb3_trpo_plus import make_model

    with pytest.raises(ValueError, match=r"rollout_workers='process:1'.*needs rollout_workers=None and overlap"):
        make_model(RECOMMENDED_GRASPER, vec_env="batch")
    model = make_model(RECOMMENDED_GRASPER, vec_env="batch", rollout_workers=None, overlap_collection=False, n_envs=2)
    assert isinstance(model.get_vec_normalize_env().venv, BatchVecEnv) and not model.overlap_collection


def test_make_model_workers_replace_the_recipes() -> None:
    from sb3_trpo_plus import make_model
    from sb3_trpo_plus.rollouts import InProcessRollouts

    model = make_model(RECOMMENDED_GRASPER, workers="inprocess:2", n_envs=4, n_steps=8, batch_size=32)
    try:
        pool = model.get_vec_normalize_env().venv
        assert isinstance(pool, InProcessRollouts) and (pool.num_workers, pool.envs_per_worker) == (2, 2)
        model.learn(3 * 8 * 4)
        assert model.overlap_collection and pool.collecting
    finally:
        model.get_env().close()


def test_make_model_on_the_batched_engine_collects_what_dummy_vec_env_collects() -> None:
    """The front door's batched engine (with the recipe's scripted starts) and SB3's DummyVecEnv: the same rollout."""
    from sb3_trpo_plus import make_model

    buffers = []
    one_process = {"rollout_workers": None, "overlap_collection": False}
    for vec_env in ("batch", "dummy"):
        model = make_model(RECOMMENDED_GRASPER, seed=5, vec_env=vec_env, n_steps=120, batch_size=120, n_envs=4, **one_process)
        model.learn(120 * 4)
        buffers.append(model.rollout_buffer)
    for name in ("observations", "actions", "rewards", "episode_starts", "returns"):
        np.testing.assert_array_equal(getattr(buffers[0], name), getattr(buffers[1], name), err_msg=name)
    assert buffers[0].episode_starts[1:].any(), "no episode ended: the scripted starts were not exercised"


def test_make_model_names_an_env_without_a_batched_engine() -> None:
    from sb3_trpo_plus import make_model

    with pytest.raises(ValueError, match="vec_env='batch' runs the tasks of grasp_envs"):
        make_model("Pendulum-v1", vec_env="batch")
    with pytest.raises(ValueError, match="vec_env must be"):
        make_model("Pendulum-v1", vec_env="subproc")
    assert type(make_model("Pendulum-v1").get_env()).__name__ == "DummyVecEnv"


def test_shipped_recommended_agent_is_evaluated_without_training_aids() -> None:
    """The shipped agent's config names the recipe's scripted starts; its evaluation env (the weights-only path of
    ``trpo-plus enjoy``) leaves them out, so its success is measured from the task's own start states."""
    from grasp_envs.wrappers import ScriptedStarts
    from sb3_trpo_plus.application.agents import load_eval_agent

    _, env = load_eval_agent(AGENT, RECOMMENDED_GRASPER, seed=0)
    try:
        inner = env.venv.envs[0]  # type: ignore[attr-defined]
        while hasattr(inner, "env"):
            assert not isinstance(inner, ScriptedStarts)
            inner = inner.env
    finally:
        env.close()


def test_recipe_policy_is_an_alias_never_an_import(tmp_path: Path) -> None:
    from sb3_trpo_plus.application.zoo import load_hyperparameters

    path = tmp_path / "bad.yml"
    path.write_text("Reacher2D-v1:\n  n_timesteps: 1000\n  policy: os.system\n")
    with pytest.raises(HyperparameterError, match="policy must be one of"):
        load_hyperparameters(path, "trpo_plus")


@pytest.mark.parametrize(
    ("key", "value"),
    [("env_wrapper", "os.system"), ("callback", "subprocess.Popen"), ("vec_env_wrapper", "builtins.exec"), ("policy", "a.b")],
)
def test_a_run_config_naming_other_code_is_refused(tmp_path: Path, key: str, value: str) -> None:
    """A downloaded run folder's config.yml names a function where rl-zoo3 expects a wrapper, callback or policy."""
    from sb3_trpo_plus.application.agents import RunFileError, validate_run_files

    run = tmp_path / "trpo_plus" / "Reacher2D-v1_1"
    (run / "Reacher2D-v1").mkdir(parents=True)
    config = {"policy": "MlpPolicy", "normalize": True, key: value}
    (run / "Reacher2D-v1" / "config.yml").write_text(json.dumps(config))
    with pytest.raises(RunFileError, match=f"config.yml: {key}.*refused"):
        validate_run_files(run, "Reacher2D-v1")


def test_make_model_overrides_run_keys_and_keeps_rl_zoos_discount_and_schedules() -> None:
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus import make_model

    model = make_model("Reacher2D-v1", algo="ppo", seed=0, n_envs=2, gamma=0.9, learning_rate="lin_1e-3", n_steps=16)
    env = model.get_env()
    assert isinstance(env, VecNormalize) and env.num_envs == 2 and env.gamma == model.gamma == 0.9
    assert model.lr_schedule(1.0) == pytest.approx(1e-3) and model.lr_schedule(0.5) == pytest.approx(5e-4)


def test_make_model_reads_policy_kwargs_overrides_as_the_yaml() -> None:
    from sb3_trpo_plus import make_model
    from sb3_trpo_plus.application.zoo import HyperparameterError

    kwargs = {"net_arch": [8, 8], "activation_fn": "tanh", "log_std_init": -0.5}
    model = make_model("Reacher2D-v1", seed=0, n_envs=1, n_steps=16, batch_size=16, policy_kwargs=kwargs)
    assert isinstance(model.policy.mlp_extractor.policy_net[1], th.nn.Tanh)
    assert model.policy.log_std.detach().tolist() == [-0.5, -0.5]
    model = make_model("Reacher2D-v1", n_envs=1, n_steps=16, batch_size=16, policy_kwargs="dict(activation_fn=nn.ReLU)")
    assert isinstance(model.policy.mlp_extractor.policy_net[1], th.nn.ReLU)
    with pytest.raises(HyperparameterError, match=r"make_model\('Reacher2D-v1'\): unknown activation_fn 'swish'"):
        make_model("Reacher2D-v1", n_envs=1, policy_kwargs={"activation_fn": "swish"})
    with pytest.raises(HyperparameterError, match="unknown policy_kwargs key 'net_size'"):
        make_model("Reacher2D-v1", n_envs=1, policy_kwargs={"net_size": 8})


def test_a_recipe_is_parsed_once_into_a_typed_record() -> None:
    """The record's fields are the run keys, its constructor the rest; it reads as the YAML entry; ``lin_<x>`` becomes
    SB3's ``LinearSchedule`` only where the constructor receives it; overrides re-split."""
    from stable_baselines3.common.utils import LinearSchedule

    from sb3_trpo_plus import recipe
    from sb3_trpo_plus.application.zoo import RUN_KEYS, Recipe

    entry = {
        "n_timesteps": 1000,
        "policy": "MlpPolicy",
        "n_envs": 4,
        "rollout_workers": "process:2",
        "monitor_kwargs": {"info_keywords": ["is_success"]},
        "env_wrapper": [{"grasp_envs.wrappers.ScriptedStarts": {"probability": 0.25}}],
        "learning_rate": "lin_1e-3",
        "gamma": 0.98,
    }
    chosen = Recipe.of("Grasper3D-v7", "trpo_plus", entry)
    assert (chosen.n_envs, chosen.rollout_workers, chosen.info_keywords) == (4, "process:2", ("is_success",))
    assert chosen.scripted_starts == {"probability": 0.25}
    assert chosen.constructor == {"learning_rate": "lin_1e-3", "gamma": 0.98}
    assert set(RUN_KEYS).isdisjoint(chosen.constructor)
    assert dict(chosen) == {**entry, "normalize": False}  # n_envs and normalize always, as rl-zoo3 defaults them
    schedule = chosen.constructor_arguments()["learning_rate"]
    assert isinstance(schedule, LinearSchedule) and (schedule(1.0), schedule(0.5), schedule(0.0)) == (1e-3, 5e-4, 0.0)
    moved = chosen.replace(n_envs=2, gamma=0.99, rollout_workers=None)
    assert (moved.n_envs, moved.rollout_workers, moved.constructor["gamma"]) == (2, None, 0.99)
    with pytest.raises(ValueError, match=r"per-env wrapper but grasp_envs\.wrappers\.ScriptedStarts"):
        _ = chosen.replace(env_wrapper="gymnasium.wrappers.ClipAction").scripted_starts
    assert recipe(RECOMMENDED_GRASPER).rollout_workers == recipe(RECOMMENDED_GRASPER)["rollout_workers"]
