"""Zoo YAML, the trpo-plus command (train, -i, enjoy, record-video, plot) and the docs build."""

import inspect
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rl_zoo3.utils import get_wrapper_class
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sb3_trpo_plus import make_model
from sb3_trpo_plus.application import cli
from sb3_trpo_plus.application.run_folders import load_trained
from sb3_trpo_plus.application.zoo import ALGO_FILES, ZOO_DIR, HyperparameterError, algorithms, load_hyperparameters
from sb3_trpo_plus.common.arguments import got

ROOT = Path(__file__).resolve().parent.parent
ENTRIES = [(algo, env_id) for algo, f in ALGO_FILES.items() for env_id in load_hyperparameters(ZOO_DIR / f, algo)]
TINY_ZOO = ["-params", "n_envs:2", "n_steps:32", "batch_size:32", "--num-threads", "1"]


@pytest.mark.parametrize(("algo", "env_id"), ENTRIES, ids=[f"{a}-{e}" for a, e in ENTRIES])
def test_every_yaml_entry_builds_and_runs(algo: str, env_id: str) -> None:
    params = dict(load_hyperparameters(ZOO_DIR / ALGO_FILES[algo], algo)[env_id])
    if params.get("rollout_workers") is not None:  # the recipe's own rollout workers (tests/test_recipes.py)
        model = make_model(env_id, algo, seed=0, n_envs=2, n_steps=64, batch_size=64)
        try:
            model.learn(256)
        finally:
            model.get_env().close()
        assert model.num_timesteps >= 256
        return
    for key in ("n_timesteps", "n_envs", "normalize", "monitor_kwargs", "callback"):
        params.pop(key, None)
    policy = params.pop("policy")
    params.update(n_steps=64, batch_size=64)
    wrapper = get_wrapper_class({"env_wrapper": params.pop("env_wrapper", None)})
    env = VecNormalize(make_vec_env(env_id, n_envs=2, seed=0, wrapper_class=wrapper))
    model = algorithms()[algo](policy, env, seed=0, **params)
    model.learn(256)
    assert model.num_timesteps >= 256


def test_all_envs_have_entries_in_every_file() -> None:
    expected = {
        "Reacher2D-v0",
        "Reacher2D-v1",
        "Reacher3D-v1",
        "Reacher3D-v0",
        "Grasper3D-v0",
        "Grasper3D-v1",
        "Grasper3D-v2",
        "Grasper3D-v3",
        "Grasper3D-v4",
        "Grasper3D-v5",
        "Grasper3D-v6",
        "Grasper3D-v7",
        "WallReacher3D-v0",
        "Reacher-v5",
        "Pendulum-v1",
        "Hopper-v5",
        "HalfCheetah-v5",
        "Walker2d-v5",
    }
    for algo, name in ALGO_FILES.items():
        assert set(load_hyperparameters(ZOO_DIR / name, algo)) == expected, name


def test_policy_kwargs_mapping_and_zoo_text_form(tmp_path: Path) -> None:
    from torch import nn

    text = (
        "Pendulum-v1:\n  n_timesteps: 1000\n  policy: MlpPolicy\n"
        '  policy_kwargs: "dict(net_arch=[8], activation_fn=nn.ReLU)"\n'
    )
    (tmp_path / "a.yml").write_text(text)
    params = load_hyperparameters(tmp_path / "a.yml", "trpo")["Pendulum-v1"]
    assert params["policy_kwargs"] == {"net_arch": [8], "activation_fn": nn.ReLU}
    mapping = load_hyperparameters(ZOO_DIR / "trpo_plus.yml", "trpo_plus")["Reacher2D-v0"]["policy_kwargs"]
    assert mapping["activation_fn"] is nn.Tanh


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "Pendulum-v1:\n  n_timesteps: 1000\n  policy: MlpPolicy\n  replay_memry: 3\n",
            "replay_memry: unknown hyperparameter",
        ),
        ("Pendulum-v1:\n  n_timesteps: 1000\n  policy: MlpPolicy\n  gamma: high\n", "gamma: expected"),
        ("Pendulum-v1:\n  n_timesteps: 1000\n  policy: MlpPolicy\n  cg_warm_start: 1\n", "cg_warm_start: expected bool"),
        ("NoSuchEnv-v9:\n  n_timesteps: 1000\n  policy: MlpPolicy\n", "unknown env id 'NoSuchEnv-v9'"),
        ("Pendulum-v1:\n  n_timesteps: [1000\n", "malformed YAML"),
        ("Pendulum-v1:\n  policy: MlpPolicy\n", "n_timesteps and policy are required"),
        ("Pendulum-v1:\n  n_timesteps: 1\n  policy: MlpPolicy\n  policy_kwargs: \"__import__('os')\"\n", "dict(key=value"),
        ('Pendulum-v1:\n  n_timesteps: 1\n  policy: MlpPolicy\n  policy_kwargs: "dict(net_arch=os.getcwd())"\n', "literal"),
        ("Pendulum-v1:\n  n_timesteps: 1\n  policy: MlpPolicy\n  policy_kwargs:\n    activation_fn: swish\n", "activation_fn"),
        ("Pendulum-v1:\n  n_timesteps: 1\n  policy: MlpPolicy\n  policy_kwargs:\n    net_arc: [8]\n", "net_arc"),
        ("Pendulum-v1:\n  n_timesteps: 1\n  policy: MlpPolicy\n  rollout_workers: process\n", "expected 'BACKEND:N'"),
        ("Pendulum-v1:\n  n_timesteps: 1\n  policy: MlpPolicy\n  rollout_workers: 2\n", "rollout_workers: expected str"),
    ],
)
def test_bad_yaml_gives_error_naming_file_and_key(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.yml"
    path.write_text(text)
    with pytest.raises(HyperparameterError, match=re.escape(message)) as error:
        load_hyperparameters(path, "trpo_plus")
    assert str(path) in str(error.value)


# YAML values of the wrong type for a constructor argument, by the type of its default: an int default takes no float
# (`n_steps: 64.0`) and no bool, a bool default no number or text, a float default (an int is fine) no bool or list, a
# str default no number or bool. An argument whose default is None takes several types.
WRONG_YAML_VALUES: dict[type, list[Any]] = {
    bool: [1, 0.0, "no", [True]],
    int: [64.0, 1e6, True, "64", [64]],
    float: [True, "0.5", [0.5]],
    str: [1, True, ["auto"]],
}
NOT_YAML_KEYS = {"policy", "env", "_init_setup_model"}  # the zoo gives these itself


def _constructor_defaults(algo: str) -> dict[str, Any]:
    parameters = inspect.signature(algorithms()[algo]).parameters
    return {name: p.default for name, p in parameters.items() if name not in NOT_YAML_KEYS}


def _write_entry(path: Path, hyperparameters: dict[str, Any]) -> Path:
    entry = {"n_timesteps": 1000, "policy": "MlpPolicy", **hyperparameters}
    path.write_text(yaml.safe_dump({"Pendulum-v1": entry}))
    return path


@pytest.mark.parametrize("algo", ALGO_FILES)
def test_yaml_type_table_covers_every_constructor_argument(algo: str) -> None:
    for name, default in _constructor_defaults(algo).items():
        assert default is None or type(default) in WRONG_YAML_VALUES, f"{algo}: {name} needs a row in WRONG_YAML_VALUES"


@pytest.mark.parametrize("algo", ALGO_FILES)
def test_yaml_values_of_the_defaults_type_are_accepted(tmp_path: Path, algo: str) -> None:
    defaults = {name: value for name, value in _constructor_defaults(algo).items() if value is not None}
    loaded = load_hyperparameters(_write_entry(tmp_path / "defaults.yml", defaults), algo)["Pendulum-v1"]
    assert {name: loaded[name] for name in defaults} == defaults
    as_ints = {name: int(value) for name, value in defaults.items() if type(value) is float}  # an int where a float is
    load_hyperparameters(_write_entry(tmp_path / "ints.yml", as_ints), algo)


def _wrong_yaml_cases() -> list[Any]:
    return [
        pytest.param(algo, name, value, id=f"{algo}-{name}-{i}")
        for algo in ALGO_FILES
        for name, default in _constructor_defaults(algo).items()
        if default is not None
        for i, value in enumerate(WRONG_YAML_VALUES[type(default)])
    ]


@pytest.mark.parametrize(("algo", "name", "value"), _wrong_yaml_cases())
def test_yaml_value_of_another_type_is_named_with_its_file_and_entry(tmp_path: Path, algo: str, name: str, value: Any) -> None:
    path = _write_entry(tmp_path / "wrong.yml", {name: value})
    with pytest.raises(HyperparameterError) as error:
        load_hyperparameters(path, algo)
    message = str(error.value)
    assert message.startswith(f"{path}: Pendulum-v1: {name}: expected "), message
    assert message.endswith(got(value, with_type=True)), message


def test_a_float_is_no_int_but_n_timesteps_takes_rl_zoos_float(tmp_path: Path) -> None:
    path = tmp_path / "steps.yml"
    path.write_text("Pendulum-v1:\n  n_timesteps: !!float 1e6\n  policy: MlpPolicy\n  n_steps: 64.0\n")
    with pytest.raises(HyperparameterError, match=re.escape(f"{path}: Pendulum-v1: n_steps: expected int, got float 64.0")):
        load_hyperparameters(path, "trpo_plus")
    path.write_text("Pendulum-v1:\n  n_timesteps: !!float 1e6\n  policy: MlpPolicy\n  n_steps: 64\n")
    assert load_hyperparameters(path, "trpo_plus")["Pendulum-v1"]["n_timesteps"] == 1e6


def test_an_exponent_without_a_decimal_point_is_named_as_yamls_str(tmp_path: Path) -> None:
    """YAML 1.1 reads ``1e-2`` as a str: the error says so and how to write the number (rl-zoo3's ``!!float``)."""
    path = tmp_path / "kl.yml"
    path.write_text("Pendulum-v1:\n  n_timesteps: !!float 1e6\n  policy: MlpPolicy\n  target_kl: 1e-2\n")
    expected = (
        "target_kl: expected int/float, got str '1e-2' (a number as a str; YAML 1.1 reads 6e-4 as one: write !!float 1e-2"
    )
    with pytest.raises(HyperparameterError, match=re.escape(expected)):
        load_hyperparameters(path, "trpo_plus")
    path.write_text(path.read_text().replace("1e-2", "!!float 1e-2"))
    assert load_hyperparameters(path, "trpo_plus")["Pendulum-v1"]["target_kl"] == 0.01


def _tensorboard_tags(folder: Path) -> set[str]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    tags: set[str] = set()
    for events in folder.rglob("events.out.tfevents*"):
        accumulator = EventAccumulator(str(events))
        accumulator.Reload()
        tags |= set(accumulator.Tags()["scalars"])
    return tags


@pytest.mark.slow
def test_train_continue_enjoy_video_and_plot(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    logs, tb = tmp_path / "logs", tmp_path / "tb"
    # with evaluation and checkpoints, which save the model while it trains
    evaluation = ["--eval-freq", "64", "--eval-episodes", "1", "--save-freq", "64"]
    cli.main(
        ["train", "--env", "Reacher2D-v0", "-n", "256", "--seed", "1", "-f", str(logs), "-tb", str(tb), *evaluation, *TINY_ZOO]
    )
    run = logs / "trpo_plus" / "Reacher2D-v0_1"
    assert (run / "Reacher2D-v0.zip").is_file()
    assert list(run.glob("*.monitor.csv"))
    assert "is_success" in next(run.glob("*.monitor.csv")).read_text().splitlines()[1]
    assert (run / "best_model.zip").is_file() and list(run.glob("rl_model_*_steps.zip"))
    assert [p.name for p in (tb / "Reacher2D-v0" / "seed1").iterdir()] == ["TRPOPlus_1"]
    tags = _tensorboard_tags(tb)
    assert {"train/cg_iterations", "rollout/success_rate", "rollout/reward_dist"} <= tags, sorted(tags)

    # -i: continue training from the saved model (a new run folder; rl-zoo restarts the timestep count,
    # the update counter and the replay memory carry on)
    continue_args = ["-n", "128", "-f", str(logs), "-i", str(run / "Reacher2D-v0.zip"), "--eval-freq", "-1"]
    cli.main(["train", "--env", "Reacher2D-v0", *continue_args, *TINY_ZOO])
    continued = logs / "trpo_plus" / "Reacher2D-v0_2" / "Reacher2D-v0.zip"
    from sb3_trpo_plus import TRPOPlus

    first, second = TRPOPlus.load(run / "Reacher2D-v0.zip"), TRPOPlus.load(continued)
    assert second._n_updates == first._n_updates + 2  # 128 steps = 2 rollouts of 2 envs x 32 steps

    cli.main(["enjoy", "--env", "Reacher2D-v0", "-f", str(logs), "--no-render", "-n", "60"])

    video = cli.record_video(["--env", "Reacher2D-v0", "-f", str(logs), "-n", "40", "-o", str(tmp_path / "v.mp4"), "--gif"])
    assert [p.suffix for p in video] == [".mp4", ".gif"]
    from moviepy import VideoFileClip

    with VideoFileClip(str(video[0])) as clip:
        frames = list(clip.iter_frames())
    assert len(frames) >= 30 and np.std(frames[len(frames) // 2]) > 5.0

    png = cli.plot(["--env", "Reacher2D-v0", "-f", str(logs), "--algos", "trpo_plus", "-o", str(tmp_path / "c.png")])
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unknown_command_and_module_entry_point() -> None:
    result = subprocess.run([sys.executable, "-m", "sb3_trpo_plus", "nonsense"], capture_output=True, text=True)
    assert result.returncode == 2 and "trpo-plus: error: unknown command 'nonsense'" in result.stderr


@pytest.mark.skipif(
    shutil.which("mkdocs") is None and not (Path(sys.executable).parent / "mkdocs").exists(), reason="docs extra"
)
def test_docs_build_strict(tmp_path: Path) -> None:
    mkdocs = shutil.which("mkdocs") or str(Path(sys.executable).parent / "mkdocs")
    result = subprocess.run(
        [mkdocs, "build", "--strict", "-d", str(tmp_path / "site")], cwd=ROOT, capture_output=True, text=True
    )
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.slow
def test_optuna_samples_trpo_plus_hyperparameters(tmp_path: Path) -> None:
    options = ["--n-trials", "1", "-n", "256", "--sampler", "random", "--pruner", "none", "--n-evaluations", "1"]
    cli.main(
        ["train", "--env", "Pendulum-v1", "-optimize", *options, "-f", str(tmp_path), "--eval-episodes", "1", "--seed", "0"]
    )
    report = next((tmp_path / "trpo_plus").glob("report_Pendulum-v1_*.csv")).read_text()
    for name in ("params_replay_memory", "params_cg_warm_start", "params_cg_damping", "params_value_baseline"):
        assert name in report.splitlines()[0]
    assert "COMPLETE" in report


def test_a_saved_runs_env_kwargs_come_back_as_rl_zoo3s_enjoy_reads_them(tmp_path: Path) -> None:
    """config.yml's env_kwargs make the test env (a shipped agent trained on a non-default env), and the training
    command's env_kwargs in args.yml replace them, as in rl-zoo3's enjoy."""
    import json

    import grasp_envs  # noqa: F401
    from sb3_trpo_plus import TRPOPlus

    run = tmp_path / "trpo_plus" / "Grasper3D-v6_1"
    (run / "Grasper3D-v6").mkdir(parents=True)
    TRPOPlus("MlpPolicy", "Grasper3D-v6", n_steps=64, batch_size=64).save(run / "Grasper3D-v6.zip")
    config = {"policy": "MlpPolicy", "n_steps": 64, "env_kwargs": {"start_pose": "ready"}}
    (run / "Grasper3D-v6" / "config.yml").write_text(json.dumps(config))

    def start_pose() -> str:
        _, env, _ = load_trained("trpo_plus", "Grasper3D-v6", str(tmp_path), 1, False, 0, False)
        pose = env.get_attr("_ezpickle_kwargs")[0]["start_pose"]
        env.close()
        return pose

    assert start_pose() == "ready"
    (run / "Grasper3D-v6" / "args.yml").write_text("env_kwargs:\n  start_pose: stretched\n")
    assert start_pose() == "stretched"
    (run / "Grasper3D-v6" / "args.yml").write_text("env_kwargs: null\n")  # not given on the command line
    assert start_pose() == "ready"


def test_train_with_the_batched_engine_trains_as_with_dummy_vec_env(tmp_path: Path, monkeypatch) -> None:
    """``--vec-env batch``: the same transitions as ``dummy`` (scripted starts of the recipe included), so the same
    trained parameters; episode statistics in the run's monitor file."""
    monkeypatch.chdir(tmp_path)
    params = {}
    for vec_env in ("dummy", "batch"):
        logs = tmp_path / vec_env
        cli.main(
            [
                "train",
                "--env",
                "Grasper3D-v7",
                "-n",
                "256",
                "--seed",
                "3",
                "-f",
                str(logs),
                "--eval-freq",
                "-1",
                "--vec-env",
                vec_env,
                "-params",
                "n_envs:2",
                "n_steps:64",
                "batch_size:64",
                "rollout_workers:None",
                "overlap_collection:False",
                "--num-threads",
                "1",
            ]
        )
        from sb3_trpo_plus import TRPOPlus

        run = logs / "trpo_plus" / "Grasper3D-v7_1"
        params[vec_env] = TRPOPlus.load(run / "Grasper3D-v7.zip").policy.state_dict()
        assert list(run.glob("*monitor.csv"))
    assert params["dummy"].keys() == params["batch"].keys()
    for key, value in params["dummy"].items():
        np.testing.assert_array_equal(params["batch"][key].numpy(), value.numpy(), err_msg=key)


def test_batched_engine_flags_are_checked(capsys) -> None:
    with pytest.raises(SystemExit):
        cli.main(["train", "--env", "Pendulum-v1", "--vec-env", "batch"])
    assert "--vec-env batch runs the tasks of grasp_envs" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["train", "--env", "Grasper3D-v7", "--vec-env", "dummy", "--sim-threads", "2"])
    assert "the physics threads of --vec-env batch or --workers" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["train", "--env", "Pendulum-v1", "--sim-threads", "2"])
    assert "the physics threads of --vec-env batch or --workers" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--env", "Grasper3D-v7"], "batch"),
        (["--env", "Reacher2D-v0", "--sim-threads", "2"], "batch"),
        (["--env", "Grasper3D-v7", "--vec-env", "dummy"], "dummy"),
        (["--env", "Grasper3D-v7", "--vec-env", "subproc"], "subproc"),
        (["--env", "Pendulum-v1"], "dummy"),
    ],
)
def test_the_tasks_of_grasp_envs_train_on_the_batched_engine_by_default(argv, expected, monkeypatch) -> None:
    """What the training env is, seen from inside rl-zoo3's train(): the batched engine for grasp_envs' ids unless
    --vec-env says otherwise, rl-zoo3's own VecEnv for any other id."""
    import rl_zoo3.train

    from sb3_trpo_plus.application.experiment import TRPOPlusExperimentManager
    from sb3_trpo_plus.application.zoo import batch_training_env

    seen: dict[str, object] = {}

    def fake_train() -> None:
        seen["argv_vec_env"] = sys.argv[sys.argv.index("--vec-env") + 1]
        seen["manager"] = rl_zoo3.train.ExperimentManager

    monkeypatch.setattr(rl_zoo3.train, "train", fake_train)
    argv_before, manager_before = list(sys.argv), rl_zoo3.train.ExperimentManager
    cli.main(["train", *argv])
    manager = seen["manager"]
    assert isinstance(manager, type) and issubclass(manager, TRPOPlusExperimentManager)
    training_envs = manager.training_envs
    assert (getattr(training_envs, "func", None) is batch_training_env) is (expected == "batch")
    assert seen["argv_vec_env"] == ("dummy" if expected == "batch" else expected)
    # rl-zoo3's inputs are the caller's again once the command returns
    assert sys.argv == argv_before
    assert rl_zoo3.train.ExperimentManager is manager_before


def test_train_with_rollout_workers_in_processes_trains_as_in_process(tmp_path: Path, monkeypatch) -> None:
    """``--workers process:2``: the recipe's envs split over two worker processes train the parameters that the
    same two workers give in the learner's process; the run saves and its episodes reach the monitor file."""
    monkeypatch.chdir(tmp_path)
    params = {}
    for workers in ("inprocess:2", "process:2"):
        logs = tmp_path / workers.replace(":", "_")
        cli.main(
            [
                "train",
                "--env",
                "Grasper3D-v7",
                "-n",
                "256",
                "--seed",
                "3",
                "-f",
                str(logs),
                "--eval-freq",
                "-1",
                "--workers",
                workers,
                "-params",
                "n_envs:2",
                "n_steps:64",
                "batch_size:64",
                "--num-threads",
                "1",
            ]
        )
        from sb3_trpo_plus import TRPOPlus

        run = logs / "trpo_plus" / "Grasper3D-v7_1"
        params[workers] = TRPOPlus.load(run / "Grasper3D-v7.zip").policy.state_dict()
        assert (run / "workers.monitor.csv").exists() and (run / "Grasper3D-v7" / "vecnormalize.pkl").exists()
    for key, value in params["inprocess:2"].items():
        np.testing.assert_array_equal(params["process:2"][key].numpy(), value.numpy(), err_msg=key)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--workers", "ray"], "expected 'BACKEND:N'"),
        (["--workers", "threads:2"], "expected 'BACKEND:N' with BACKEND one of inprocess, process, ray"),
        (["--workers", "process:0"], "expected 'BACKEND:N'"),
        (["--workers", "process:2", "--vec-env", "batch"], "--vec-env batch does not apply"),
        (["--workers", "process:2", "--algo", "ppo"], "for trpo_plus only"),
    ],
)
def test_workers_flag_is_checked(argv, message, capsys) -> None:
    with pytest.raises(SystemExit):
        cli.main(["train", "--env", "Grasper3D-v7", *argv])
    assert message in capsys.readouterr().err


def test_train_collects_with_the_recipes_rollout_worker(tmp_path: Path, monkeypatch, capsys) -> None:
    """Grasper3D-v7's recipe names one worker process (``rollout_workers: process:1``) that collects the next segment
    while the learner updates: ``trpo-plus train`` runs it so; ``--vec-env`` beside it is refused with the way out."""
    from sb3_trpo_plus import TRPOPlus

    monkeypatch.chdir(tmp_path)
    tiny = ["--seed", "0", "--eval-freq", "-1", "-params", "n_envs:2", "n_steps:16", "batch_size:16", "--num-threads", "1"]
    cli.main(["train", "--env", "Grasper3D-v7", "-n", "96", "-f", str(tmp_path / "logs"), *tiny])
    run = tmp_path / "logs" / "trpo_plus" / "Grasper3D-v7_1"
    assert (run / "workers.monitor.csv").exists()
    model = TRPOPlus.load(run / "Grasper3D-v7.zip")
    assert model.overlap_collection and model.num_timesteps == 96
    with pytest.raises(SystemExit) as error:
        cli.main(["train", "--env", "Grasper3D-v7", "--vec-env", "batch", "-f", str(tmp_path / "other"), *tiny])
    message = capsys.readouterr().err
    assert error.value.code == 2
    assert "collects with rollout workers (rollout_workers: process:1); --vec-env batch does not apply" in message
    assert "--hyperparams rollout_workers:None overlap_collection:False" in message


@pytest.mark.parametrize("env_id", ["Hopper-v5", "HalfCheetah-v5", "Walker2d-v5"])
def test_the_locomotion_recipes_learn_with_andrychowicz_defaults_and_sample_reuse(env_id: str) -> None:
    """The recipe of each MuJoCo locomotion task (docs/results.md (h)): separate 64-64 actor and 256-256 critic, the
    policy's last layer initialised at gain 0.01, std 0.5 at the start, GAE lambda 0.9, generalized sample reuse."""
    import numpy as np
    import torch as th

    from sb3_trpo_plus import make_model

    model = make_model(env_id, seed=0)
    policy = model.policy
    assert [layer.out_features for layer in policy.mlp_extractor.policy_net if isinstance(layer, th.nn.Linear)] == [64, 64]
    assert [layer.out_features for layer in policy.mlp_extractor.value_net if isinstance(layer, th.nn.Linear)] == [256, 256]
    assert np.allclose(policy.log_std.exp().detach().numpy(), 0.5, atol=1e-3)
    # orthogonal at gain 0.01 (SB3's ortho_init, kept by the recipe): every singular value of the action layer is 0.01
    singular = th.linalg.svdvals(policy.action_net.weight.detach())
    assert th.allclose(singular, th.full_like(singular, 0.01), atol=1e-5)
    assert model.gae_lambda == 0.9 and model.sample_reuse == "generalized" and model.reuse_batches == 2
    assert model.n_steps * model.n_envs == 1024
    model.env.close()
