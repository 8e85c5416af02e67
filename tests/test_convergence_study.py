"""The convergence study (python -m benchmarks.convergence): its variants are study.yml's data, its tables agree with
each other and with the envs, its jobs resume and branch, its protocol reads the target as documented."""

import ast
import json
import re
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from torch import nn

import grasp_envs  # noqa: F401  (registers the envs)
from grasp_envs.wrappers import ScriptedStarts

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # benchmarks/ is a package beside the installed ones
from benchmarks import builders, convergence, protocol, report, runner, runs, study  # noqa: E402
from benchmarks.study import VARIANTS, StudyError, Variant  # noqa: E402

SNAPSHOT = ROOT / "benchmarks" / "results" / "convergence" / "variants.json"
# ScriptedStarts' settings -> the names the snapshot gives them: the Grasper3D constructor options of the settings the
# committed runs were trained with
SCRIPTED_START_KWARGS = {
    "probability": "scripted_start_prob",
    "steps": "scripted_start_steps",
    "hold_height": "scripted_start_hold_height",
}


def _as_snapshot(variant: Variant) -> dict:
    """``variant`` in the snapshot's form: its algorithm, every override (a schedule as data), the training envs'
    scripted-start kwargs, and whether it trains with the multi-step class or sb3-contrib's CG started at 0."""
    overrides = {
        key: {"hold_then_shrink": vars(value)}
        if isinstance(value, study.HoldThenShrink)
        else {"times_zoo": vars(value)}
        if isinstance(value, study.TimesZoo)
        else value
        for key, value in variant.hyperparameters.items()
    }
    if variant.env_kwargs is not None:
        overrides["env_kwargs"] = variant.env_kwargs
    train_env_kwargs = {}
    for wrapper in variant.train_wrappers or []:
        ((name, kwargs),) = wrapper.items()
        assert name == "grasp_envs.wrappers.ScriptedStarts"
        train_env_kwargs |= {SCRIPTED_START_KWARGS[key]: value for key, value in kwargs.items()}
    return {
        "label": variant.label,
        "algo": variant.algo,
        "overrides": json.loads(json.dumps(overrides)),
        "train_env_kwargs": train_env_kwargs,
        "multi_step": variant.algo_class == "benchmarks.multistep.MultiStepTRPOPlus",
        "zero_cg_start": variant.zero_cg_start,
    }


def test_the_variants_are_those_the_committed_runs_were_trained_with() -> None:
    """study.yml builds every variant, in the same order, with the settings of the snapshot taken from the Python
    tables that trained the committed runs (variants.json: their scripted starts as the Grasper3D constructor options
    of the settings the committed runs were trained with)."""
    snapshot = json.loads(SNAPSHOT.read_text())
    assert list(VARIANTS) == list(snapshot["variants"])
    for name, variant in VARIANTS.items():
        assert _as_snapshot(variant) == snapshot["variants"][name], name
    assert snapshot["study_variants"] == study.STUDY_VARIANTS
    for env_id, settings in snapshot["envs"].items():  # the envs of the committed runs, which have a success target
        pinned = study.ENVS[env_id].zoo  # the zoo entries study.yml pins (Grasper3D-v7's 2M recipe)
        assert vars(study.ENVS[env_id]) == {**settings, "return_target": None, "zoo": pinned}
        assert set(pinned) <= ({"trpo_plus"} if env_id == "Grasper3D-v7" else set())


def test_every_variant_loads_with_valid_keys_and_types() -> None:
    for name, variant in VARIANTS.items():
        assert variant.name == name and variant.label
        assert variant.algo in study.ALGOS
        assert isinstance(variant.hyperparameters, dict) and isinstance(variant.train_wrappers, list | None)
        assert variant.env_kwargs is None or isinstance(variant.env_kwargs, dict)
        assert isinstance(builders.algorithm_class(name), type)
        for wrapper in variant.train_wrappers or []:
            ((path, kwargs),) = wrapper.items()
            assert path == "grasp_envs.wrappers.ScriptedStarts" and set(kwargs) <= set(SCRIPTED_START_KWARGS)
    assert len(set(study.LABELS.values())) == len(VARIANTS)
    # every env has a success target or, without a success flag (Gymnasium's locomotion), a return target
    assert set(study.TARGETS) | set(study.RETURN_TARGETS) == set(study.BUDGETS)
    assert not set(study.TARGETS) & set(study.RETURN_TARGETS)
    assert set(study.STUDY_VARIANTS) <= set(VARIANTS)
    assert report.LABELS is study.LABELS


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"label": "x", "algo": "trpo_plus", "gamma": 0.9}, "unknown keys"),
        ({"algo": "trpo_plus"}, "needs a label"),
        ({"label": "x", "algo": "a2c"}, "algo must be one of"),
        ({"label": "x", "algo": "trpo_plus", "hyperparameters": {"env_kwargs": {}}}, "cannot set env_kwargs"),
        ({"label": "x", "algo": "trpo_plus", "hyperparameters": {"target_kl": {"shrink": {}}}}, "schedule"),
        ({"label": "x", "algo": "trpo_plus", "hyperparameters": {"target_kl": {"hold_then_shrink": {"a": 1}}}}, "schedule"),
        ({"label": "x", "algo": "trpo_plus", "train_wrappers": [{"ScriptedStarts": {}}]}, "train_wrappers"),
        ({"label": "x", "algo": "trpo_plus", "zero_cg_start": True}, "zero_cg_start"),
    ],
)
def test_a_variant_with_a_wrong_key_or_value_is_refused(tmp_path: Path, entry: dict, message: str) -> None:
    path = tmp_path / "study.yml"
    path.write_text(json.dumps({"envs": {}, "study_variants": [], "variants": {"bad": entry}}))  # JSON is YAML
    with pytest.raises(StudyError, match=message):
        study.load_study(path)


def _locomotion_settings(peer: str, ours: str) -> list[tuple[study.ModelSettings, ...]]:
    """On each locomotion task: the settings of the PPO peer ``peer``, of the TRPOPlus variant ``ours`` it is measured
    against, and of rl-zoo3's PPO."""
    envs = ("HalfCheetah-v5", "Hopper-v5", "Walker2d-v5")
    return [tuple(study.settings(VARIANTS[name], env_id) for name in (peer, ours, "ppo")) for env_id in envs]


def test_the_ppo_peer_takes_the_recipes_envs_networks_and_normalisation_and_keeps_ppos_update() -> None:
    """The PPO peer of the locomotion tasks: n_envs, normalize, gamma, lambda and the policy of the TRPOPlus variant
    it is measured against, with rl-zoo3's PPO update (learning rate, epochs, minibatches, clip range)."""
    for got, recipe, zoo_ppo in _locomotion_settings("ppo_trpo_plus_settings", "generalized_reuse_andrychowicz"):
        assert got.n_envs == recipe.n_envs == 2 and zoo_ppo.n_envs == 1
        assert got.normalize_kwargs == recipe.normalize_kwargs == {"gamma": 0.99}
        for key in ("n_steps", "gamma", "gae_lambda"):
            assert got.kwargs[key] == recipe.kwargs[key], key
        # SB3's default activation is TRPOPlus' (tanh); the peer names it, as rl-zoo3's PPO recipe sets relu
        assert got.kwargs["policy_kwargs"] == {"activation_fn": nn.Tanh, **recipe.kwargs["policy_kwargs"]}
        for key in ("learning_rate", "n_epochs", "batch_size", "clip_range"):
            assert got.kwargs[key] == zoo_ppo.kwargs[key], key


def test_the_ppo_peer_of_generalized_reuse_takes_its_envs_steps_and_sb3s_default_policy() -> None:
    """The PPO peer of generalized reuse on rl-zoo3's TRPO settings: that variant's n_envs, n_steps, gamma, lambda and
    normalisation, the policy SB3 builds without policy_kwargs (as that variant's), rl-zoo3's PPO update."""
    import inspect

    from stable_baselines3.common.policies import ActorCriticPolicy

    defaults = {name: p.default for name, p in inspect.signature(ActorCriticPolicy.__init__).parameters.items()}
    for got, reuse, zoo_ppo in _locomotion_settings("ppo_reuse_settings", "generalized_reuse"):
        assert got.n_envs == reuse.n_envs == 2
        assert got.normalize_kwargs == reuse.normalize_kwargs == {"gamma": 0.99}
        for key in ("n_steps", "gamma", "gae_lambda"):
            assert got.kwargs[key] == reuse.kwargs[key], key
        assert "policy_kwargs" not in reuse.kwargs
        policy = got.kwargs["policy_kwargs"]
        for key in ("log_std_init", "ortho_init", "activation_fn"):
            assert policy[key] == defaults[key], key
        assert defaults["net_arch"] is None and policy["net_arch"] == {"pi": [64, 64], "vf": [64, 64]}  # SB3's default
        for key in ("learning_rate", "n_epochs", "batch_size", "clip_range"):
            assert got.kwargs[key] == zoo_ppo.kwargs[key], key


@pytest.mark.parametrize("env_id", ["Hopper-v5", "HalfCheetah-v5", "Walker2d-v5"])
def test_the_locomotion_recipes_are_the_variant_the_study_measured(env_id: str) -> None:
    """zoo_hyperparams/trpo_plus.yml's locomotion recipes are generalized_reuse_andrychowicz on the study's pinned
    rl-zoo3 TRPO settings, so its runs are the recipe's (docs/results.md (h))."""
    from sb3_trpo_plus.application.zoo import load_hyperparameters

    recipe = load_hyperparameters(ROOT / "zoo_hyperparams" / "trpo_plus.yml", "trpo_plus", [env_id])[env_id]
    assert recipe == study.hyperparameters(VARIANTS["generalized_reuse_andrychowicz"], env_id)


def test_a_target_kl_schedule_is_data() -> None:
    shrink = VARIANTS["warm_scripted25_late_klshrink"].hyperparameters["target_kl"]
    assert shrink == study.HoldThenShrink(0.01, 0.001, 0.4)
    assert shrink(1.0) == shrink(0.6) == 0.01 and shrink(0.0) == pytest.approx(0.001)
    assert shrink(0.3) == pytest.approx(0.01 + (0.001 - 0.01) * 0.3 / 0.6)


def test_the_benchmarks_import_each_other_without_a_circle() -> None:
    """Every import between benchmarks' modules (at the top or in a function) points one way, through the package."""
    modules = {path.stem: path for path in (ROOT / "benchmarks").glob("*.py") if path.stem != "__init__"}
    edges: dict[str, set[str]] = {name: set() for name in modules}
    for name, path in modules.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("benchmarks."):
                edges[name].add(node.module.split(".")[1])
            elif isinstance(node, ast.ImportFrom) and node.module == "benchmarks":
                edges[name] |= {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom | ast.Import):  # no sibling imported as a top-level module
                names = [node.module] if isinstance(node, ast.ImportFrom) else [alias.name for alias in node.names]
                assert not set(names) & set(modules), f"{name} imports a sibling outside the package: {names}"
    done: set[str] = set()

    def visit(name: str, path: tuple[str, ...]) -> None:
        assert name not in path, f"import circle: {' -> '.join((*path, name))}"
        if name not in done:
            for other in sorted(edges[name]):
                visit(other, (*path, name))
            done.add(name)

    for name in modules:
        visit(name, ())


def test_the_runner_imports_no_experiment_script() -> None:
    """A study job needs the study's configuration, builders, protocol and run files, nothing of a diagnostic script."""
    imported = set()
    for node in ast.walk(ast.parse((ROOT / "benchmarks" / "runner.py").read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("benchmarks."):
            imported.add(node.module.split(".")[1])
    assert imported == {"builders", "protocol", "runs", "study"}


def test_every_comparison_names_existing_variants() -> None:
    """study.yml's comparisons (the report's extra P(X > Y) rows) pair two different variants of the study."""
    assert study.COMPARISONS
    for comparison in study.COMPARISONS:
        assert {comparison.variant, comparison.baseline} <= set(VARIANTS) and comparison.variant != comparison.baseline
    pairs = [(comparison.variant, comparison.baseline) for comparison in study.COMPARISONS]
    assert len(set(pairs)) == len(pairs)


@pytest.mark.parametrize(
    ("comparisons", "message"),
    [
        ([{"variant": "plain", "baseline": "nothing"}], "names no variant"),
        ([{"variant": "plain"}], "a comparison is"),
        ([["plain", "plain"]], "a comparison is"),
    ],
)
def test_a_comparison_of_an_unknown_variant_is_refused(tmp_path: Path, comparisons: list, message: str) -> None:
    path = tmp_path / "study.yml"
    variants = {"plain": {"label": "x", "algo": "trpo_plus"}}
    path.write_text(json.dumps({"envs": {}, "study_variants": [], "variants": variants, "comparisons": comparisons}))
    with pytest.raises(StudyError, match=message):
        study.load_study(path)


@pytest.mark.parametrize(
    ("suffix", "gamma", "env_id", "same_settings_as"),
    [
        ("g099", 0.99, "Reacher2D-v1", "Reacher2D-v0"),  # Reacher2D-v1's runs with Reacher2D-v0's settings
        ("g0995", 0.995, "WallReacher3D-v0", "Reacher3D-v0"),  # WallReacher3D-v0's runs with the thesis' 3D settings
    ],
)
@pytest.mark.parametrize("name", study.STUDY_VARIANTS)
def test_discount_variants_are_the_study_variants_with_another_discount(
    name: str, suffix: str, gamma: float, env_id: str, same_settings_as: str
) -> None:
    """<variant>_g099 and <variant>_g0995 set gamma 0.99 or 0.995 where the env's zoo entry sets 0.98, and differ from
    the zoo settings in the discount only: they record the env's runs with that discount."""
    variant, other = VARIANTS[name], VARIANTS[f"{name}_{suffix}"]
    assert (other.algo, other.hyperparameters) == (variant.algo, {**variant.hyperparameters, "gamma": gamma})
    assert study.hyperparameters(other, env_id) == study.hyperparameters(variant, same_settings_as)
    assert study.hyperparameters(variant, env_id)["gamma"] == 0.98


def _wrappers(env: gym.Env) -> list[gym.Env]:
    """``env`` and every wrapper under it, outermost first, down to the unwrapped env (excluded)."""
    found = []
    while isinstance(env, gym.Wrapper):
        found.append(env)
        env = env.env
    return found


@pytest.mark.parametrize("name", study.STUDY_VARIANTS)
def test_scripted_start_variants_change_the_training_envs_only(name: str) -> None:
    """<variant>_scripted25 trains like <variant> on envs whose resets follow the scripted grasp a quarter of the
    time (the ScriptedStarts wrapper); the model and the env kwargs are <variant>'s."""
    scripted = f"{name}_scripted25"
    variant = VARIANTS[name]
    assert (VARIANTS[scripted].algo, VARIANTS[scripted].hyperparameters) == (variant.algo, variant.hyperparameters)
    assert builders.model_settings("Grasper3D-v4", scripted) == builders.model_settings("Grasper3D-v4", name)
    assert VARIANTS[scripted].train_wrappers == [{"grasp_envs.wrappers.ScriptedStarts": {"probability": 0.25}}]
    assert builders.train_wrapper_class("Grasper3D-v4", name) is None


def test_training_envs_are_wrapped_and_evaluation_envs_are_not() -> None:
    """run_job's training envs carry the variant's ScriptedStarts with study.yml's settings; its evaluation env does
    not; the env kwargs (here v6's ready start pose) make both."""
    name = "warm_scripted25_late_ready_cg25_g098"
    training = builders.training_envs("Grasper3D-v6", name, seed=0)
    for env in training.envs:
        wrapper = next(w for w in _wrappers(env) if isinstance(w, ScriptedStarts))
        assert (wrapper.probability, wrapper.steps, wrapper.hold_height) == (0.25, (50, 100), None)
        assert env.unwrapped.spec.kwargs["start_pose"] == "ready"  # type: ignore[union-attr]
    evaluation = builders.evaluation_env("Grasper3D-v6", name, seed=0)
    assert not any(isinstance(w, ScriptedStarts) for w in _wrappers(evaluation.envs[0]))
    assert evaluation.envs[0].unwrapped.spec.kwargs["start_pose"] == "ready"  # type: ignore[union-attr]
    training.close()
    evaluation.close()


RECIPE_STARTS = [{"grasp_envs.wrappers.ScriptedStarts": {"probability": 0.25, "steps": [50, 100]}}]


def test_a_variant_without_train_wrappers_trains_with_the_zoo_entrys_env_wrapper() -> None:
    """On Grasper3D-v7, whose zoo entries start a quarter of the training episodes 50-99 steps along the scripted grasp,
    a variant without train_wrappers trains with those starts and evaluates without them; a variant's own
    train_wrappers replace them, ``[]`` drops them."""
    for name in ("warm", "trpo", "ppo"):
        assert study.train_wrappers(VARIANTS[name], "Grasper3D-v7") == RECIPE_STARTS, name
    own = VARIANTS["warm_scripted25"]
    assert study.train_wrappers(own, "Grasper3D-v7") == own.train_wrappers != RECIPE_STARTS
    assert study.train_wrappers(Variant("none", "none", "trpo_plus", train_wrappers=[]), "Grasper3D-v7") == []
    training = builders.training_envs("Grasper3D-v7", "warm", seed=0)
    for env in training.envs:
        wrapper = next(w for w in _wrappers(env) if isinstance(w, ScriptedStarts))
        assert (wrapper.probability, wrapper.steps) == (0.25, (50, 100))
    evaluation = builders.evaluation_env("Grasper3D-v7", "warm", seed=0)
    assert not any(isinstance(w, ScriptedStarts) for w in _wrappers(evaluation.envs[0]))
    training.close()
    evaluation.close()


def test_the_committed_runs_train_with_their_variants_own_wrappers() -> None:
    """Every committed run trains with the wrappers it was trained with: its variant's train_wrappers, else none,
    except on Grasper3D-v7 (the one env whose zoo entry has an env_wrapper), where it inherits the recipe's starts."""
    folders = sorted(path for path in (ROOT / "benchmarks" / "results" / "convergence").glob("*/*") if path.is_dir())
    assert folders
    for folder in folders:
        env_id, name = folder.parent.name, folder.name
        own = VARIANTS[name].train_wrappers
        inherited = RECIPE_STARTS if env_id == "Grasper3D-v7" else []
        assert study.train_wrappers(VARIANTS[name], env_id) == (own if own is not None else inherited), folder


def test_a_zoo_env_wrapper_that_evaluation_needs_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    """A zoo env_wrapper with a wrapper that is not a training aid would wrap rl-zoo3's evaluation envs too, and the
    study's evaluation envs carry none: a variant that would inherit it is refused, naming it."""
    zoo = study.hyperparameters
    clip = "gymnasium.wrappers.ClipAction"
    monkeypatch.setattr(study, "hyperparameters", lambda variant, env_id: {**zoo(variant, env_id), "env_wrapper": [clip]})
    with pytest.raises(StudyError, match="ClipAction"):
        study.train_wrappers(VARIANTS["warm"], "Grasper3D-v7")
    assert study.train_wrappers(VARIANTS["warm_scripted25"], "Grasper3D-v7") == VARIANTS["warm_scripted25"].train_wrappers


def test_the_headline_variant_trains_with_the_pinned_2m_grasper_recipe() -> None:
    """The runs behind the 2M Grasper3D-v7 result (warm_scripted25_late_ready_cg25_g098 on Grasper3D-v6) train with
    the 2M recipe that study.yml pins for Grasper3D-v7 (its model hyperparameters, envs, VecNormalize, budget and
    scripted starts), on an env whose options are the Grasper3D-v7 preset's; the study's Grasper3D-v7 variants start
    from that entry, not from zoo_hyperparams/trpo_plus.yml's."""
    from grasp_envs.registration import PRESETS
    from sb3_trpo_plus.application.zoo import RUN_KEYS  # what make_model keeps from the constructor

    variant, env_id = VARIANTS["warm_scripted25_late_ready_cg25_g098"], "Grasper3D-v6"
    config, entry = study.settings(variant, env_id), study.ENVS["Grasper3D-v7"].zoo["trpo_plus"]
    reuse = study.settings(VARIANTS["recipe_generalized_reuse"], "Grasper3D-v7")
    assert (reuse.n_envs, reuse.kwargs["n_steps"], reuse.kwargs["sample_reuse"]) == (10, 500, "generalized")
    assert variant.algo == "trpo_plus" and builders.algorithm_class(variant.name).__name__ == "TRPOPlus"
    assert config.kwargs == {key: value for key, value in entry.items() if key not in RUN_KEYS}
    assert (config.n_envs, config.policy, config.normalize_kwargs) == (entry["n_envs"], entry["policy"], {"gamma": 0.98})
    assert entry["normalize"] is True and entry["gamma"] == 0.98
    assert study.BUDGETS[env_id] == entry["n_timesteps"]
    v6, v7 = PRESETS[env_id], PRESETS["Grasper3D-v7"]
    assert v6.kwargs | config.env_kwargs == v7.kwargs | (entry.get("env_kwargs") or {}) == v6.kwargs | {"start_pose": "ready"}
    assert (v6.entry_point, v6.max_episode_steps) == (v7.entry_point, v7.max_episode_steps)
    assert study.train_wrappers(variant, env_id) == entry["env_wrapper"] == RECIPE_STARTS


def test_evaluation_env_kwargs_are_the_variants_own_for_training_and_evaluation() -> None:
    """A variant's env_kwargs (here v6's grip speed, or its cube's joint) make both its evaluation envs and its
    training envs; the diagnostic scripts read them from model_settings."""
    assert builders.model_settings("Grasper3D-v6", "warm_scripted25_late").env_kwargs == {}
    for name, kwargs in (
        ("warm_scripted25_late_speed08", {"max_grip_speed": 0.8}),
        ("warm_scripted25_late_speed08_std05", {"max_grip_speed": 0.8}),
        ("plain_scripted25_late_freecube", {"cube_rotation": "free"}),
    ):
        assert builders.model_settings("Grasper3D-v6", name).env_kwargs == kwargs
        env = gym.make("Grasper3D-v6", **kwargs)
        assert env.unwrapped.max_grip_speed == kwargs.get("max_grip_speed", 0.4)  # type: ignore[attr-defined]
        env.close()


def test_the_zoos_normalize_gives_the_vecnormalize_kwargs_with_the_models_gamma() -> None:
    """``normalize`` as rl-zoo3 takes it: true, false, or a mapping of VecNormalize kwargs; the model's gamma (where
    the zoo sets one) is the reward normalization's discount."""
    assert study.normalize_kwargs(True, {"gamma": 0.98}) == {"gamma": 0.98}
    assert study.normalize_kwargs(True, {}) == {}
    assert study.normalize_kwargs(False, {"gamma": 0.98}) is None
    assert study.normalize_kwargs({"norm_obs": False, "gamma": 0.9}, {"gamma": 0.98}) == {"norm_obs": False, "gamma": 0.98}
    plain = builders.model_settings("Reacher2D-v1", "plain")
    assert plain.normalize and plain.normalize_kwargs == {"gamma": 0.98}


def test_a_normalize_mapping_reaches_the_training_and_the_evaluation_vecnormalize(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A zoo ``normalize: {clip_obs: 5.0, norm_reward: true}`` makes the runner's and the diagnostic scripts'
    training VecNormalize with it; the job's evaluation env, in memory and from the saved statistics, clips the
    observations at 5 and leaves the rewards the env's."""
    from sb3_trpo_plus.application.agents import load_normalization

    zoo = study.hyperparameters
    normalize = {"clip_obs": 5.0, "norm_reward": True}
    monkeypatch.setattr(study, "hyperparameters", lambda variant, env_id: {**zoo(variant, env_id), "normalize": normalize})
    config = builders.model_settings("Reacher2D-v1", "plain")
    assert config.normalize_kwargs == {**normalize, "gamma": config.kwargs["gamma"]}
    training = builders.normalized_training_envs("Reacher2D-v1", "plain", seed=0)
    assert (training.clip_obs, training.norm_reward, training.gamma) == (5.0, True, config.kwargs["gamma"])
    training.close()
    made = []

    def evaluation_env(*args: object) -> object:
        made.append(builders.evaluation_env(*args))  # type: ignore[arg-type]
        return made[-1]

    monkeypatch.setattr(runner, "evaluation_env", evaluation_env)
    monkeypatch.setitem(study.BUDGETS, "Reacher2D-v1", 2048)
    runner.run_job("Reacher2D-v1", "plain", 0, 2048, tmp_path)  # one rollout of 8 x 256
    folder = runs.job_folder(tmp_path, "Reacher2D-v1", "plain", 0)
    saved = load_normalization(folder / "vecnormalize.pkl")
    assert (saved.clip_obs, saved.norm_reward, saved.gamma) == (5.0, True, config.kwargs["gamma"])
    from_file = builders.evaluation_env("Reacher2D-v1", "plain", 0, folder / "vecnormalize.pkl")
    for env in (made[0], from_file):
        assert (env.clip_obs, env.norm_reward, env.training) == (5.0, False, False)
    from_file.close()


@pytest.mark.parametrize("name", sorted(name for name, variant in VARIANTS.items() if variant.train_wrappers))
def test_training_wrappers_are_accepted_by_the_env(name: str) -> None:
    wrap = builders.train_wrapper_class("Grasper3D-v4", name)
    assert wrap is not None
    env = wrap(gym.make("Grasper3D-v4"))
    env.reset(seed=0)
    env.close()


def test_export_skips_a_finished_run_without_its_checkpoint(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    env_id = "Reacher2D-v1"
    folder = runs.job_folder(tmp_path / "out", env_id, "warm", 3)
    folder.mkdir(parents=True)
    budget = study.BUDGETS[env_id]
    (folder / "progress.csv").write_text(f"timesteps,eval_success,eval_return\n{budget},0.9,10.0\n")
    agents = tmp_path / "agents"
    report.export_agents(tmp_path / "out", [env_id], agents)
    printed = capsys.readouterr().out
    assert "warm seed 3 (0.90)" in printed
    assert "no finished TRPOPlus run with a checkpoint" in printed
    assert not agents.exists()


def test_an_export_merges_into_the_agents_entry(capsys: pytest.CaptureFixture[str]) -> None:
    """``agents`` replaces the keys it writes and keeps those added by hand (a held-out evaluation) while it ships the
    same run; for another run it drops them, since they describe the agent it replaces."""
    entry = json.loads((ROOT / "trained_agents" / "agents.json").read_text())["Grasper3D-v7"]
    assert "held_out" in entry
    exported = {key: entry[key] for key in report.EXPORTED_KEYS if key in entry} | {"success_rate": 0.5, "platform": "x"}
    merged = report.merged_entry({**entry, "env_kwargs": {"start_pose": "ready"}}, exported)
    assert merged == {**entry, "success_rate": 0.5, "platform": "x"}
    assert list(merged) == [*entry, "platform"]  # the entry's keys in their places, a new one last
    other = report.merged_entry(entry, {**exported, "seed": entry["seed"] + 1})
    assert set(other) == set(exported) and other["seed"] == entry["seed"] + 1
    assert "dropped its command, held_out, success_rate_100, mean_reward_100" in capsys.readouterr().out
    assert report.merged_entry({}, exported) == exported


def test_the_agents_table_shows_the_100_episode_evaluation_where_the_manifest_has_one(tmp_path: Path) -> None:
    entry = {"variant": "warm", "seed": 1, "timesteps": 1_000_000, "success_rate": 0.95, "mean_reward": 3.0}
    manifest = tmp_path / "agents.json"
    manifest.write_text(json.dumps({"Reacher3D-v1": entry}))
    lines = report.agents_section(manifest)
    assert "re-evaluated on 20 deterministic episodes of an env seeded once with 20000" in lines[2]
    assert lines[4:7] == [
        "| env | env kwargs | variant | seed | steps | success rate (20 episodes) | mean return | video |",
        "|---|---|---|---|---|---|---|---|",
        "| `Reacher3D-v1` | — | TRPOPlus + warm start | 1 | 1,000,000 | 0.95 | 3.00 | — |",
    ]
    manifest.write_text(json.dumps({"Reacher3D-v1": {**entry, "success_rate_100": 0.93}}))
    lines = report.agents_section(manifest)
    assert "re-evaluated on 20 and on 100 deterministic episodes" in lines[2]
    assert lines[6] == "| `Reacher3D-v1` | — | TRPOPlus + warm start | 1 | 1,000,000 | 0.95 | 3.00 | 0.93 | — |"


def test_zero_start_solver_starts_at_zero_and_draws_nothing() -> None:
    import torch as th

    from benchmarks.builders import zero_start_solver

    matrix = th.tensor([[4.0, 1.0], [1.0, 3.0]])
    b = th.tensor([1.0, 2.0])
    th.manual_seed(0)
    solution = zero_start_solver(lambda v: matrix @ v, b, max_iter=1)
    # one CG iteration from 0 is the steepest-descent step (b·b / b·Ab) b, hand-computed: 5 / 20 * b
    th.testing.assert_close(solution, th.tensor([0.25, 0.5]))
    th.manual_seed(0)
    expected = th.randn(1)
    th.manual_seed(0)
    zero_start_solver(lambda v: matrix @ v, b, max_iter=2)
    assert th.equal(th.randn(1), expected), "the solver must not draw from torch's global generator"


def test_zero_cg_start_variants_are_sb3_contrib_trpo() -> None:
    zero_start = [variant for variant in VARIANTS.values() if variant.zero_cg_start]
    assert [variant.name for variant in zero_start] == ["trpo_cg0"] and zero_start[0].algo == "trpo"


def test_complete_runs_are_in_the_order_of_the_seeds(tmp_path: Path) -> None:
    # the 10-seed tables take the first seeds of each variant: seed10 must not come before seed2
    budget = study.BUDGETS["Reacher2D-v1"]
    for seed in (10, 2, 1):
        folder = runs.job_folder(tmp_path, "Reacher2D-v1", "plain", seed)
        folder.mkdir(parents=True)
        (folder / "progress.csv").write_text(f"timesteps,eval_success\n{budget},0.5\n")
    (runs.job_folder(tmp_path, "Reacher2D-v1", "plain", 3)).mkdir()  # unfinished: no CSV
    assert list(report.complete_runs(tmp_path, "Reacher2D-v1", "plain")) == [1, 2, 10]


def test_update_kl_is_per_state_and_matches_trpo_plus_line_search() -> None:
    """benchmarks/update_kl.py: KL summed over action dimensions, measured on the update's own states.

    TRPOPlus logs SB3's KL per action dimension, so on Reacher2D-v1 (2 actions) the measured KL of each
    update must be twice the logged one; reading the rollout buffer after ``train()`` (which reorders its
    arrays in place) would compare the policies on different states and fail this.
    """
    import numpy as np
    import torch as th

    from benchmarks import update_kl

    old = th.distributions.Normal(th.tensor([[0.0, 0.0], [0.0, 0.0]]), th.tensor([[1.0, 1.0], [1.0, 1.0]]))
    new = th.distributions.Normal(th.tensor([[1.0, 0.0], [0.0, 0.0]]), th.tensor([[1.0, 1.0], [1.0, 2.0]]))
    # KL(p || q) = log(s_q / s_p) + (s_p^2 + (m_p - m_q)^2) / (2 s_q^2) - 1/2 per dimension, summed, averaged over states
    # state 1: mean moved by one std, 1/2 either way; state 2: std doubled, log 2 + 1/8 - 1/2 or -log 2 + 2 - 1/2
    assert update_kl.policy_kl(old, new) == pytest.approx((0.5 + np.log(2.0) + 0.125 - 0.5) / 2, rel=1e-6)
    assert update_kl.policy_kl(new, old) == pytest.approx((0.5 - np.log(2.0) + 2.0 - 0.5) / 2, rel=1e-6)

    result = update_kl.measure("Reacher2D-v1", "plain", steps=4096)
    assert len(result["kl"]) == 2
    np.testing.assert_allclose(result["kl"], 2 * np.asarray(result["logged_kl"]), rtol=1e-3)


def test_warm_start_share_against_hand_computed_cg() -> None:
    """benchmarks/warm_start_share.py on A = diag(1, 4), b = (1, 1), previous step x0 = (1, 0).

    x0's line minimiser is x0 itself (x0.b / x0.A x0 = 1). One CG iteration from x0 reaches the solution
    (1, 1/4): the residual (0, 1) is an eigenvector. From zero it reaches 2/5 (1, 1): objective x.A x / 2 - b.x
    -0.4 against -0.625, so the warm start's gain is 0.225 / 0.4; with two iterations both are exact.
    """
    import numpy as np
    import torch as th

    from benchmarks import warm_start_share
    from sb3_trpo_plus.algorithm.natural_gradient import conjugate_gradient

    def fvp(v: th.Tensor) -> th.Tensor:
        return th.tensor([1.0, 4.0], dtype=th.float64) * v

    b, x0 = th.tensor([1.0, 1.0], dtype=th.float64), th.tensor([1.0, 0.0], dtype=th.float64)
    one = conjugate_gradient(fvp, b, x0, max_iter=1, warm_start_rescale=True)
    figures = warm_start_share.compare_starts(fvp, b, x0, one, max_iter=1, rescale=True)
    assert figures["start_gradient_cosine"] == pytest.approx(1 / np.sqrt(2))
    assert figures["start_share"] == pytest.approx(1 / np.sqrt(1 + 1 / 16))
    assert figures["solution_cosine"] == pytest.approx(0.5 / (np.sqrt(1 + 1 / 16) * np.sqrt(0.32)))
    assert figures["objective_gain"] == pytest.approx(0.225 / 0.4)
    two = conjugate_gradient(fvp, b, x0, max_iter=2, warm_start_rescale=True)
    figures = warm_start_share.compare_starts(fvp, b, x0, two, max_iter=2, rescale=True)
    assert figures["solution_cosine"] == pytest.approx(1.0)
    assert figures["objective_gain"] == pytest.approx(0.0, abs=1e-12)
    # unscaled (the thesis' raw previous step): 2 x0 is its own share, not its line minimiser x0
    raw = warm_start_share.compare_starts(fvp, b, 2 * x0, two, max_iter=2, rescale=False)
    assert raw["start_share"] == pytest.approx(2 / np.sqrt(1 + 1 / 16))


def test_warm_start_share_measures_every_warm_started_update_and_restores_the_solver() -> None:
    """Three updates of the plain variant with the warm start switched on: the last two are warm-started."""
    import sb3_trpo_plus.algorithm.update as update_module
    from benchmarks import warm_start_share

    solver = update_module.conjugate_gradient
    result = warm_start_share.measure("Reacher2D-v1", "plain", seed=0, steps=3 * 2048, from_run=False, raw=False)
    assert update_module.conjugate_gradient is solver
    assert len(result["updates"]) == 2
    for row in result["updates"]:
        assert -1.0 <= row["solution_cosine"] <= 1.0 + 1e-6 and row["start_share"] >= 0.0


def test_a_branched_run_takes_its_variants_target_kl_schedule_over_the_budget(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A job that resumes another variant's checkpoint (copied into its folder) trains on with its own target_kl
    schedule, and the schedule reads the progress against the env's study budget, not the chunk being learned."""
    import shutil

    from sb3_trpo_plus import TRPOPlus

    shrink = study.HoldThenShrink(0.01, 0.001, 0.5)
    plain = VARIANTS["plain"].hyperparameters
    monkeypatch.setitem(VARIANTS, "trunk", Variant("trunk", "trunk", "trpo_plus", dict(plain)))
    monkeypatch.setitem(VARIANTS, "branch", Variant("branch", "branch", "trpo_plus", {**plain, "target_kl": shrink}))
    monkeypatch.setitem(study.BUDGETS, "Reacher2D-v1", 4 * 2048)  # one rollout of 2048 samples per chunk
    runner.run_job("Reacher2D-v1", "trunk", 0, 2 * 2048, tmp_path)
    trunk = runs.job_folder(tmp_path, "Reacher2D-v1", "trunk", 0)
    branch = runs.job_folder(tmp_path, "Reacher2D-v1", "branch", 0)
    shutil.copytree(trunk, branch)
    runner.run_job("Reacher2D-v1", "branch", 0, 4 * 2048, tmp_path)
    trunk_model = TRPOPlus.load(trunk / "model.zip")
    branch_model = TRPOPlus.load(branch / "model.zip")
    assert trunk_model.target_kl == 0.01 and trunk_model._current_progress_remaining == pytest.approx(0.5)
    assert branch_model.target_kl == shrink and branch_model._current_progress_remaining == pytest.approx(0.0)
    assert branch_model.current_target_kl == pytest.approx(0.001)  # the last update comes after the last rollout
    rows = runs.read_progress(branch)
    assert [row["timesteps"] for row in rows] == [2048, 4096, 6144, 8192]
    assert all(row["kl_overshoot"] <= 1.0 for row in rows)


def test_a_branched_run_takes_its_variants_batch_and_replay_memory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A job that resumes another variant's checkpoint collects its own variant's batch (n_steps) and keeps its own
    replay memory; the trunk's checkpoint keeps the trunk's. No job leaves SB3's empty log folders in the tempdir."""
    import shutil
    import tempfile

    from sb3_trpo_plus import TRPOPlus

    plain = VARIANTS["plain"].hyperparameters
    monkeypatch.setitem(VARIANTS, "trunk", Variant("trunk", "trunk", "trpo_plus", dict(plain)))
    branch_settings = {**plain, "n_steps": 512, "replay_memory": 2}
    monkeypatch.setitem(VARIANTS, "branch", Variant("branch", "branch", "trpo_plus", branch_settings))
    monkeypatch.setitem(study.BUDGETS, "Reacher2D-v1", 4 * 2048)  # a short study budget for the progress
    temporary = tmp_path / "tempdir"
    temporary.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temporary))  # where SB3's default logger makes its folders
    runner.run_job("Reacher2D-v1", "trunk", 0, 2048, tmp_path)  # 8 envs x 256 steps; a chunk is steps // 25
    trunk = runs.job_folder(tmp_path, "Reacher2D-v1", "trunk", 0)
    branch = runs.job_folder(tmp_path, "Reacher2D-v1", "branch", 0)
    shutil.copytree(trunk, branch)
    runner.run_job("Reacher2D-v1", "branch", 0, 2048 + 2 * 4096, tmp_path)  # two rollouts of 8 x 512
    trunk_model = TRPOPlus.load(trunk / "model.zip")
    branch_model = TRPOPlus.load(branch / "model.zip")
    assert (trunk_model.n_steps, trunk_model.replay_memory) == (256, 0)
    assert (branch_model.n_steps, branch_model.replay_memory) == (512, 2)
    assert len(branch_model.rollout_memory) == 2
    assert [row["timesteps"] for row in runs.read_progress(branch)] == [2048, 6144, 10240]
    assert not list(temporary.glob("SB3-*"))


def test_a_variant_with_a_multiple_of_the_zoos_batch_resumes_its_own_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """generalized_reuse writes n_steps as {times_zoo: {factor: 0.5}}: a resumed job loads its checkpoint with the
    value resolved on the env (the zoo's 256 x 0.5), not with the study.yml object."""
    from sb3_trpo_plus import TRPOPlus

    monkeypatch.setitem(study.BUDGETS, "Reacher2D-v1", 2 * 1024)
    runner.run_job("Reacher2D-v1", "generalized_reuse", 0, 1024, tmp_path)  # one rollout of 8 envs x 128 steps
    runner.run_job("Reacher2D-v1", "generalized_reuse", 0, 2 * 1024, tmp_path)
    folder = runs.job_folder(tmp_path, "Reacher2D-v1", "generalized_reuse", 0)
    rows = runs.read_progress(folder)
    assert [(row["timesteps"], row["resumed"]) for row in rows] == [(1024, 0.0), (2048, 1.0)]
    model = TRPOPlus.load(folder / "model.zip")
    assert (model.n_steps, model.sample_reuse) == (128, "generalized")


def test_kept_checkpoints_are_the_study_as_it_stood_after_each_chunk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--keep-checkpoints``: each chunk's copy holds the CSV up to its row, and its model and VecNormalize
    statistics give that row's evaluation again (what a probe of a past chunk relies on); ``reevaluate`` gives them
    too, on the study's own episodes, and evaluates each checkpoint once per (episodes, reset seed)."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus import TRPOPlus

    monkeypatch.setitem(study.BUDGETS, "Reacher2D-v1", 4 * 2048)
    out, kept = tmp_path / "runs", tmp_path / "kept"
    convergence.main(
        [
            "job",
            "--env",
            "Reacher2D-v1",
            "--variant",
            "plain",
            "--seed",
            "0",
            "--steps",
            "4096",
            "--out",
            str(out),
            "--keep-checkpoints",
            str(kept),
        ]
    )
    job = runs.job_folder(out, "Reacher2D-v1", "plain", 0)
    rows, lines = runs.read_progress(job), (job / "progress.csv").read_text().splitlines()
    assert sorted(int(p.name) for p in kept.iterdir()) == [2048, 4096]
    for count, row in enumerate(rows, start=1):
        folder = runs.job_folder(kept / str(int(row["timesteps"])), "Reacher2D-v1", "plain", 0)
        assert sorted(p.name for p in folder.iterdir()) == ["model.zip", "progress.csv", "vecnormalize.pkl"]
        assert (folder / "progress.csv").read_text().splitlines() == lines[: count + 1]  # the header and its rows
        env = make_vec_env("Reacher2D-v1", n_envs=1, seed=protocol.EVAL_SEED)
        env = VecNormalize.load(str(folder / "vecnormalize.pkl"), env)
        env.training, env.norm_reward = False, False
        model = TRPOPlus.load(folder / "model.zip", device="cpu")
        eval_return, eval_success = protocol.evaluate(model, env, protocol.EVAL_EPISODES)
        assert (round(eval_return, 4), eval_success) == (row["eval_return"], row["eval_success"])
    assert not list(kept.rglob("*.tmp"))
    # evaluated again the study's way, on its own episodes: the rows' evaluations, once, whatever the reruns
    again = [
        "reevaluate",
        "--kept",
        str(kept),
        "--out",
        str(out),
        "--envs",
        "Reacher2D-v1",
        "--variants",
        "plain",
        "--seeds",
        "0",
        "--episodes",
        str(protocol.EVAL_EPISODES),
        "--reset-seed",
        str(protocol.EVAL_SEED),
        "--jobs",
        "1",
    ]
    convergence.main(again)
    convergence.main([*again[:-1], "2"])
    assert "0 checkpoints to evaluate" in capsys.readouterr().out
    reevaluation = runs.read_reevaluation(out, "Reacher2D-v1", "plain", 0)
    assert [(r["timesteps"], r["eval_success"], r["eval_return"]) for r in reevaluation] == [
        (row["timesteps"], row["eval_success"], row["eval_return"]) for row in rows
    ]
    convergence.main([*again, "--after", "2048", "--episodes", "3", "--reset-seed", "7", "--jobs", "2"])  # the 4096 one
    assert [(r["timesteps"], r["episodes"]) for r in runs.read_reevaluation(out, "Reacher2D-v1", "plain", 0)] == [
        (2048, 20),
        (4096, 3),
        (4096, 20),
    ]
    convergence.main([*again, "--timesteps", "2048", "--episodes", "2"])
    assert [r["timesteps"] for r in runs.read_reevaluation(out, "Reacher2D-v1", "plain", 0) if r["episodes"] == 2] == [2048]
    with pytest.raises(FileNotFoundError, match=r"seed 0 at \[6144\]"):
        convergence.main([*again, "--timesteps", "2048", "6144"])
    with pytest.raises(FileNotFoundError, match="no checkpoint of Reacher2D-v1 plain seed 1"):
        convergence.main([*again, "--seeds", "1"])
    with pytest.raises(FileNotFoundError, match="--kept"):
        convergence.main([*again, "--kept", str(tmp_path / "nothing")])
    (kept / "4096" / "Reacher2D-v1" / "plain" / "seed0" / "vecnormalize.pkl").unlink()
    with pytest.raises(FileNotFoundError, match=r"vecnormalize\.pkl is missing"):
        convergence.main([*again, "--timesteps", "4096", "--episodes", "4"])


def test_confirm_runs_the_confirmation_protocol_on_the_checkpoints_it_leaves_undecided(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """``reevaluate --confirm`` (protocol shrunk to 2 episodes, then 3 from each of two seeds; target 0.5): a checkpoint
    already at the target on the first evaluation is not confirmed, one below it is, on both seeds; the verdict is
    ``seed_verdict`` of the rows written; a rerun evaluates nothing; a hand-picked count is refused."""
    monkeypatch.setattr(protocol, "REEVALUATION_EPISODES", 2)
    monkeypatch.setattr(protocol, "CONFIRMATION_EPISODES", 3)
    monkeypatch.setattr(protocol, "CONFIRMATION_SEEDS", (7, 8))
    monkeypatch.setitem(study.TARGETS, "Reacher2D-v1", 0.5)
    out, kept = tmp_path / "runs", tmp_path / "kept"
    convergence.main(
        [
            "job",
            "--env",
            "Reacher2D-v1",
            "--variant",
            "plain",
            "--seed",
            "0",
            "--steps",
            "4096",
            "--out",
            str(out),
            "--keep-checkpoints",
            str(kept),
        ]
    )
    at_target = {"timesteps": 2048, "episodes": 2, "reset_seed": protocol.REEVALUATION_SEED, "eval_success": 0.5}
    runs.write_reevaluation(out, "Reacher2D-v1", "plain", 0, {**at_target, "eval_return": 0.0})
    command = [
        "reevaluate",
        "--kept",
        str(kept),
        "--out",
        str(out),
        "--envs",
        "Reacher2D-v1",
        "--variants",
        "plain",
        "--seeds",
        "0",
        "--jobs",
        "1",
        "--confirm",
    ]
    convergence.main(command)
    rows = runs.read_reevaluation(out, "Reacher2D-v1", "plain", 0)
    first = [r for r in rows if r["timesteps"] == 4096 and r["episodes"] == 2]
    assert len(first) == 1 and first[0]["eval_success"] < 0.5  # a 4096-step Reacher misses the target: confirmed
    assert [(r["timesteps"], r["episodes"], r["reset_seed"]) for r in rows] == [
        (2048, 2, 20_000),
        (4096, 2, 20_000),
        (4096, 3, 7),
        (4096, 3, 8),
    ]
    successes = sum(round(r["eval_success"] * r["episodes"]) for r in rows if r["timesteps"] == 4096)
    assert protocol.pooled_success(protocol.at(rows, 4096)) == successes / 8
    verdict = "pass" if successes >= 4 else "FAIL"
    line = f"Reacher2D-v1 plain seed0: {verdict} (2 checkpoints past 0; below 0.5 on 2 episodes: 1, on 8: 4096: "
    assert line in capsys.readouterr().out
    convergence.main(command)
    printed = capsys.readouterr().out
    assert "0 checkpoints to evaluate" in printed and line in printed  # confirmed earlier: still counted below
    assert runs.read_reevaluation(out, "Reacher2D-v1", "plain", 0) == rows
    with pytest.raises(SystemExit):
        convergence.main([*command, "--episodes", "5"])
    assert "drop --episodes" in capsys.readouterr().err


def test_runs_with_a_schedule_are_not_shipped_as_agents() -> None:
    """``agents`` ships a run whose settings config.yml can hold: env kwargs (enjoy applies them), not a schedule."""
    assert report.not_an_agent("warm_scripted25_late") is None
    assert report.not_an_agent("warm_scripted25_late_ready") is None
    assert "schedule" in str(report.not_an_agent("warm_scripted25_late_klshrink"))


def _rows(*evaluations: tuple[int, float]) -> list[dict[str, float]]:
    return [{"timesteps": float(t), "eval_success": s} for t, s in evaluations]


def test_improvement_over_every_task_pools_success_and_return_tasks_by_hand() -> None:
    """P(X > Y) on each task's own area: on a success task X's five runs all beat Y's (1.00); on a return task X's
    return areas 1..5 against Y's 3 (3 ahead, 1 tie, 1 behind in each seed's comparison with all of Y's: P = 0.5);
    over both tasks the mean, 0.75. Runs of other variants or seeds beyond the fifth are left out."""

    def run(success: float, ret: float) -> list[dict[str, float]]:
        return [{"timesteps": 1.0, "eval_success": success, "eval_return": ret}] * 2

    x_success, y_success = {k: run(0.9, 0.0) for k in range(5)}, {k: run(0.1, 0.0) for k in range(6)}
    x_return, y_return = {k: run(0.0, float(k + 1)) for k in range(5)}, {k: run(0.0, 3.0) for k in range(5)}
    runs = {
        "Reacher2D-v1": {"generalized_reuse": x_success, "plain": y_success},
        "Hopper-v5": {"generalized_reuse": x_return, "plain": y_return},
    }
    lines = report.improvement_section(runs, [("generalized_reuse", "plain")])
    assert "Tasks: Reacher2D-v1, Hopper-v5; 5 seeds per variant" in lines[0]
    assert lines[2] == "| P(X > Y), area | every task | Reacher2D-v1 | Hopper-v5 |"
    estimates = re.findall(r"(\d\.\d\d) \[(\d\.\d\d), (\d\.\d\d)\]", lines[4])
    assert [point for point, _, _ in estimates] == ["0.75", "1.00", "0.50"]
    assert estimates[1] == ("1.00", "1.00", "1.00")
    assert report.improvement_section({"Hopper-v5": {"plain": y_return}}, [("generalized_reuse", "plain")]) == [
        "No env has 5 finished seeds of every variant yet."
    ]


def test_target_table_counts_the_seeds_that_reach_the_target_and_hold_it(tmp_path: Path) -> None:
    """The Grasper's target, by hand: within 2M, then at or above it at every evaluation after 2M, and the same count
    on the re-evaluations of the report's protocol (100 episodes, reset seed 20,000) only."""
    variant = "warm_scripted25_late_ready_cg25_g098"
    finished = {
        "plain": {},  # no finished run: no row
        variant: {
            0: _rows((1_000_000, 0.5), (2_000_000, 0.9), (3_500_000, 0.95), (5_000_000, 1.0)),  # meets both halves
            1: _rows((1_000_000, 0.9), (2_000_000, 0.85), (3_500_000, 0.85), (5_000_000, 0.9)),  # reaches, then a dip
            2: _rows((1_000_000, 0.5), (2_000_000, 0.8), (3_500_000, 0.9), (5_000_000, 0.95)),  # too late, then holds
        },
    }
    for seed, timesteps, episodes, reset_seed, success in [
        (1, 2_000_000, 100, 20_000, 0.5),  # at 2M, not after it: not counted
        (1, 3_500_000, 100, 20_000, 0.93),
        (1, 5_000_000, 100, 20_000, 0.89),
        (1, 5_000_000, 200, 30_000, 0.10),  # another protocol: not counted
        (1, 5_000_000, 200, 40_000, 0.95),  # ... but with it and the 30,000 the 5M checkpoint has 299 of 500: fails
        (2, 3_500_000, 100, 20_000, 0.90),
        (2, 5_000_000, 100, 20_000, 0.97),
    ]:
        runs.job_folder(tmp_path, "Grasper3D-v6", variant, seed).mkdir(parents=True, exist_ok=True)
        row = {"timesteps": timesteps, "episodes": episodes, "reset_seed": reset_seed, "eval_success": success}
        runs.write_reevaluation(tmp_path, "Grasper3D-v6", variant, seed, {**row, "eval_return": 0.0})
    lines = report.target_table("Grasper3D-v6", finished, tmp_path)
    assert lines[0] == (
        "| variant | seeds | ≥ 90% within 2M | ≥ 90% at every evaluation after 2M | both | evaluations after 2M ≥ 90% "
        "| on 100 episodes: checkpoints after 2M ≥ 90% "
        "| every checkpoint after 2M ≥ 90% on 100 episodes, or on 500 where those fall below |"
    )
    assert lines[1] == "|---|---|---|---|---|---|---|---|"
    label = report.LABELS[variant]
    assert lines[2:] == [
        f"| {label} | 3 | 2 of 3 (0, 1) | 2 of 3 (0, 2) | 1 of 3 (0) | 5 of 6 | 3 of 4 (seeds 1, 2; every one: 1 of 2 (2)) "
        "| 1 of 3 (2) pass; fail: 1; not yet decided: 0 |"
    ]


def test_checkpoint_verdict_reads_100_episodes_then_500() -> None:
    """The confirmation protocol at one checkpoint, by hand: 100 episodes from reset seed 20,000 decide at or above 90 %;
    below it, those and 200 from each of 30,000 and 40,000, pooled (seed 4 at 2.8M: 88 + 191 + 187 = 466 of 500)."""

    def rows(*runs: tuple[int, int, float]) -> list[dict[str, float]]:
        return [{"timesteps": 2_800_000, "episodes": e, "reset_seed": r, "eval_success": s} for e, r, s in runs]

    verdict = protocol.checkpoint_verdict
    assert verdict(rows((100, 20_000, 0.90)), 0.9) is True
    assert verdict(rows((100, 20_000, 0.88), (200, 30_000, 0.955), (200, 40_000, 0.935)), 0.9) is True  # 466 of 500
    assert verdict(rows((100, 20_000, 0.88), (200, 30_000, 0.90), (200, 40_000, 0.90)), 0.9) is False  # 448 of 500
    assert verdict(rows((100, 20_000, 0.90), (200, 30_000, 0.90), (200, 40_000, 0.90)), 0.9) is True  # 450: at it
    assert verdict(rows((100, 20_000, 0.88), (200, 30_000, 0.955)), 0.9) is None  # the 40,000 not yet run
    assert verdict(rows((100, 20_000, 0.88), (100, 30_000, 1.0), (200, 40_000, 1.0)), 0.9) is None  # 100, not 200
    assert verdict(rows((20, 20_000, 1.0), (200, 30_000, 1.0), (200, 40_000, 1.0)), 0.9) is None  # no 100 from 20,000
    assert verdict([], 0.9) is None


def test_target_table_counts_a_budgets_last_evaluation_past_it_as_within() -> None:
    """A chunk ends on a whole rollout: Reacher2D-v1's 300k budget ends at 301,056 steps, and that evaluation counts."""
    finished = {"plain": {0: _rows((294_912, 0.85), (301_056, 0.95)), 1: _rows((294_912, 0.85), (301_056, 0.85))}}
    assert report.target_table("Reacher2D-v1", finished, Path("/nonexistent")) == [
        "| variant | seeds | ≥ 90% within 300k |",
        "|---|---|---|",
        "| TRPOPlus plain | 2 | 1 of 2 (0) |",
    ]
    assert report._evaluations_within(_rows((1, 0.0), (2, 0.0), (3, 0.0)), 2) == 2  # one at the mark
    assert report._evaluations_within(_rows((1, 0.0), (3, 0.0), (4, 0.0)), 2) == 2  # the first past it


def test_the_results_page_shows_the_shipped_agents_as_the_report_writes_them() -> None:
    """docs/results.md's agents section is ``report.agents_section`` of trained_agents/agents.json, word for word."""
    text = (report.ROOT / "docs" / "results.md").read_text()
    shown = text[text.index("## Trained agents") : text.index(report.END)].rstrip("\n").split("\n")
    assert shown == report.agents_section(report.ROOT / "trained_agents" / "agents.json")[:-1]


def test_the_generated_tables_page_says_so_and_the_results_page_links_each_of_its_sections() -> None:
    """docs/results-tables.md opens with the report's header (generated, by which command); every link of the
    results page's generated index names a heading of that page."""
    docs = report.ROOT / "docs"
    tables = (docs / report.TABLES_PAGE).read_text()
    assert tables.startswith("\n".join(report.tables_header()) + "\n")
    anchors = {report.anchor(line.lstrip("#").strip()) for line in tables.split("\n") if line.startswith("#")}
    text = (docs / "results.md").read_text()
    block = text[text.index(report.BEGIN) : text.index(report.END)]
    links = re.findall(rf"\]\({re.escape(report.TABLES_PAGE)}#([^)]+)\)", block)
    assert len(links) > len(report.BUDGETS) and set(links) <= anchors


def test_the_anchors_are_those_the_docs_give_the_headings() -> None:
    toc = pytest.importorskip("markdown.extensions.toc")
    for heading in ("Reacher2D-v0", "Aggregate (rliable)", "Reacher2D-v1, 10 seeds", "Grasper3D-v6 (ready pose)"):
        assert report.anchor(heading) == toc.slugify(heading, "-")


@pytest.mark.filterwarnings("ignore:Mean of empty slice")  # no diagnostics columns in these rows
def test_the_report_writes_the_tables_page_whole_and_only_the_block_of_the_results_page(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The generated tables go to results-tables.md (header, per env, aggregates); results.md keeps its findings and
    gets the index of that page and the agents section between its markers."""
    out, docs = tmp_path / "runs", tmp_path / "docs"
    folder = out / "Reacher2D-v0" / "plain" / "seed3"
    folder.mkdir(parents=True)
    columns = ["timesteps", "train_seconds", "eval_success", "eval_return"]
    rows = [",".join(columns), "150000,20.0,0.5,-5.0", "300000,40.0,0.95,-4.0"]
    (folder / "progress.csv").write_text("\n".join(rows) + "\n")
    docs.mkdir()
    findings = docs / "results.md"
    findings.write_text(f"# Results\n\nA finding.\n\n{report.BEGIN}\nold\n{report.END}\n\nAfter.\n")
    monkeypatch.setattr(report, "BUDGETS", {"Reacher2D-v0": 300_000, "Reacher3D-v0": 1_000_000})
    monkeypatch.setattr(report, "rliable_section", lambda *args, **kwargs: ["(aggregates)"])
    monkeypatch.setattr(report, "improvement_section", lambda *args, **kwargs: ["(improvement)"])
    monkeypatch.setattr(report, "BUDGET_COMPARISONS", [])
    monkeypatch.setattr(report, "ROOT", tmp_path)  # no trained_agents/: no agents section
    report.write_report(out, findings)
    tables = (docs / "results-tables.md").read_text()
    assert tables.startswith("\n".join(report.tables_header()))
    assert "## Reacher2D-v0\n\nBudget 300,000 env steps; seeds 3;" in tables
    assert "| TRPOPlus plain | 1 | 0.95 ± 0.00 | 0.95 ± 0.00 | -4.00 ± 0.00 | 0.30M (1/1) | 40s (1/1) | 40 ± 0 s |" in tables
    assert "![Reacher2D-v0 learning curves](images/results_Reacher2D-v0.png)" in tables
    assert "## Reacher3D-v0\n\nNo finished runs yet (budget 1,000,000 steps)." in tables
    assert "## Aggregate (rliable)\n\n(aggregates)\n" in tables
    assert "## Generalized sample reuse\n\n(aggregates)\n" in tables
    assert "## Generalized sample reuse, every task\n\n(improvement)\n" in tables
    assert (docs / "images" / "results_Reacher2D-v0.png").exists()
    assert findings.read_text() == (
        f"# Results\n\nA finding.\n\n{report.BEGIN}\n| env | budget (env steps) | seeds |\n|---|---|---|\n"
        "| [Reacher2D-v0](results-tables.md#reacher2d-v0) | 300,000 | 3 |\n"
        "| [Reacher3D-v0](results-tables.md#reacher3d-v0) | 1,000,000 | no run to the budget yet |\n\n"
        "rliable aggregates: [over the envs with 5 finished seeds of every variant]"
        "(results-tables.md#aggregate-rliable); [generalized sample reuse against plain TRPOPlus, TRPO and PPO]"
        "(results-tables.md#generalized-sample-reuse); [generalized sample reuse on every task, success or return]"
        "(results-tables.md#generalized-sample-reuse-every-task).\n\n"
        f"{report.END}\n\nAfter.\n"
    )


def test_seed_ranges() -> None:
    assert report._seed_ranges([3, 0, 1, 2, 7, 9, 10]) == "0-3, 7, 9-10"
    assert report._seed_ranges([5]) == "5"


def test_a_task_without_a_success_flag_is_tabled_by_its_return() -> None:
    """Hopper-v5 has a return target: its table shows returns, the area under the return curve and the steps to the
    target return, and it joins no success aggregate."""
    assert report.target_of("Hopper-v5") == ("eval_return", study.RETURN_TARGETS["Hopper-v5"])
    assert report.target_of("Reacher2D-v1") == ("eval_success", study.TARGETS["Reacher2D-v1"])
    target = study.RETURN_TARGETS["Hopper-v5"]

    def rows(returns: list[float]) -> list[dict[str, float]]:
        return [
            {"timesteps": 40_000.0 * (i + 1), "train_seconds": 10.0 * (i + 1), "eval_return": r, "eval_success": 0.0}
            for i, r in enumerate(returns)
        ]

    runs = {"trpo": {0: rows([100.0, target + 1, 900.0]), 1: rows([100.0, 200.0, 300.0])}, "ppo": {}}
    lines = report.tables("Hopper-v5", runs)
    assert lines[0].startswith(f"| variant | seeds | final return | best return | return area | steps to {target:g} |")
    best, area = _mean_std(target + 1, 300.0), _mean_std((1000 + target + 1) / 3, 200.0)
    assert lines[2] == f"| {study.LABELS['trpo']} | 2 | 600 ± 300 | {best} | {area} | 0.08M (1/2) | 20s (1/2) | 30 ± 0 s |"


def _mean_std(a: float, b: float) -> str:
    return f"{np.mean([a, b]):.0f} ± {np.std([a, b]):.0f}"


def _write_run(out: Path, env_id: str, variant: str, seed: int, evaluations: list[tuple[int, float, float]]) -> None:
    """A run's progress.csv: (timesteps, training seconds, evaluation success) per evaluation."""
    folder = runs.job_folder(out, env_id, variant, seed)
    folder.mkdir(parents=True)
    lines = ["timesteps,train_seconds,eval_success,eval_return", *(f"{t},{s},{x},0.0" for t, s, x in evaluations)]
    (folder / "progress.csv").write_text("\n".join(lines) + "\n")


def test_a_budget_comparison_cuts_both_sides_at_its_budget_by_hand(tmp_path: Path) -> None:
    """study.yml's budget comparison, by hand: runs cut at 2M (a 5M run's later evaluations left out, a run short of
    2M not counted), the table's medians over the seeds that reached 90 % and the ratio's over every seed, a seed
    that never reached it counting as never (1.5M against median(never, 2M, 1M) = 2M: 0.75 times), and P(X > Y) on
    the success area over the first two seeds of each (the baseline's third left out)."""
    comparison = study.BudgetComparison(
        "recipe_generalized_reuse", "Grasper3D-v7", "warm_scripted25_late_ready_cg25_g098", "Grasper3D-v6", 2_000_000
    )
    reuse, recipe = comparison.variant, comparison.baseline
    _write_run(tmp_path, "Grasper3D-v7", reuse, 0, [(1_000_000, 50, 0.9), (2_000_000, 100, 1.0)])  # area 0.95
    _write_run(tmp_path, "Grasper3D-v7", reuse, 1, [(1_000_000, 50, 0.5), (2_000_000, 100, 0.9)])  # 0.7
    _write_run(tmp_path, "Grasper3D-v7", reuse, 2, [(1_000_000, 50, 1.0)])  # short of 2M: left out
    _write_run(tmp_path, "Grasper3D-v6", recipe, 0, [(1_000_000, 60, 0.3), (2_000_000, 120, 0.5), (5_000_000, 300, 1.0)])
    _write_run(tmp_path, "Grasper3D-v6", recipe, 1, [(1_000_000, 60, 0.2), (2_000_000, 120, 0.9)])  # 0.55
    _write_run(tmp_path, "Grasper3D-v6", recipe, 2, [(1_000_000, 60, 1.0), (2_000_000, 120, 1.0)])  # third: not in P
    image = tmp_path / "docs" / "images" / "comparison.png"
    lines = report.budget_comparison_section(tmp_path, comparison, image, tmp_path / "docs" / "tables.md")
    assert image.exists() and lines[2] == "![learning curves to 2M](images/comparison.png)"
    reuse_label, recipe_label = (f"{report.LABELS[reuse]} on Grasper3D-v7", f"{report.LABELS[recipe]} on Grasper3D-v6")
    assert lines[6:8] == [
        f"| {reuse_label} | 0-1 | 0.95 ± 0.05 | 0.82 ± 0.12 | 1.50M (2/2) | 75s (2/2) |",
        f"| {recipe_label} | 0-2 | 0.80 ± 0.22 | 0.65 ± 0.25 | 1.50M (2/3) | 90s (2/3) |",  # of those that reached it
    ]
    assert lines[-1] == (
        "Median steps to 90% over every seed (a seed that never reached it counts as never): 1.50M against 2.00M, "
        "0.75 times the baseline's. P(the first > the second), success area to 2M, over the first 2 seeds of each: "
        + lines[-1].split("each: ")[1]
    )
    assert re.search(r"each: 1\.00 \[1\.00, 1\.00\] \(rliable", lines[-1])  # 0.95, 0.7 against 0.4, 0.55: all ahead
    (tmp_path / "Grasper3D-v7" / reuse / "seed0" / "progress.csv").unlink()
    (tmp_path / "Grasper3D-v7" / reuse / "seed1" / "progress.csv").unlink()
    assert report.budget_comparison_section(tmp_path, comparison, image, tmp_path / "tables.md") == [
        f"No run to 2M yet of {reuse_label}."
    ]


def test_the_budget_comparisons_compare_one_task() -> None:
    """Each of study.yml's budget comparisons trains and evaluates both sides on the same task: the same env class,
    episode length and options (the registered preset's with the variant's env_kwargs) and the same success target."""
    from grasp_envs.registration import PRESETS

    assert study.BUDGET_COMPARISONS
    for comparison in study.BUDGET_COMPARISONS:
        tasks = []
        for env_id, name in ((comparison.env, comparison.variant), (comparison.baseline_env, comparison.baseline)):
            preset, config = PRESETS[env_id], study.settings(VARIANTS[name], env_id)
            tasks.append((preset.entry_point, preset.max_episode_steps, preset.kwargs | config.env_kwargs))
        assert tasks[0] == tasks[1], comparison
        assert study.TARGETS[comparison.env] == study.TARGETS[comparison.baseline_env]


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"variant": {"env": "Grasper3D-v7", "name": "plain"}, "budget": 10}, "a budget comparison is"),
        (
            {"variant": {"env": "Grasper3D-v7"}, "baseline": {"env": "Grasper3D-v6", "name": "plain"}, "budget": 10},
            "a budget comparison is",
        ),
        (
            {
                "variant": {"env": "Grasper3D-v7", "name": "nope"},
                "baseline": {"env": "Grasper3D-v6", "name": "plain"},
                "budget": 10,
            },
            "names no variant 'nope'",
        ),
        (
            {
                "variant": {"env": "Hopper-v5", "name": "plain"},
                "baseline": {"env": "Grasper3D-v6", "name": "plain"},
                "budget": 10,
            },
            "'Hopper-v5' is no study env with a success target",
        ),
        (
            {
                "variant": {"env": "Reacher2D-v0", "name": "plain"},
                "baseline": {"env": "Reacher2D-v1", "name": "plain"},
                "budget": 400_000,
            },
            "budget must be an int within Reacher2D-v0's budget",
        ),
        (
            {
                "variant": {"env": "Reacher2D-v0", "name": "plain"},
                "baseline": {"env": "Reacher2D-v1", "name": "plain"},
                "budget": 1e5,
            },
            "budget must be an int",
        ),
        (
            {
                "variant": {"env": "Reacher2D-v0", "name": "plain"},
                "baseline": {"env": "Reacher2D-v1", "name": "plain"},
                "budget": True,
            },
            "budget must be an int",
        ),
        (
            {
                "variant": {"env": "Reacher2D-v0", "name": "plain"},
                "baseline": {"env": "WallReacher3D-v0", "name": "plain"},
                "budget": 100,
            },
            "the two envs' success targets differ",
        ),
    ],
)
def test_a_malformed_budget_comparison_is_refused_naming_the_problem(tmp_path: Path, entry: dict, message: str) -> None:
    import yaml

    data = yaml.safe_load(study.STUDY_FILE.read_text())
    data["budget_comparisons"] = [entry]
    path = tmp_path / "study.yml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(StudyError, match=re.escape(message)):
        study.load_study(path)


def test_a_variants_policy_kwargs_are_read_as_the_zoos() -> None:
    """An activation named in a variant's policy_kwargs becomes the class, as in the zoo files."""
    import torch as th

    params = study.hyperparameters(study.VARIANTS["generalized_reuse_ppo_policy"], "HalfCheetah-v5")
    assert params["policy_kwargs"]["activation_fn"] is th.nn.ReLU
    assert params["policy_kwargs"]["net_arch"] == {"pi": [256, 256], "vf": [256, 256]}
