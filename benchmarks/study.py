"""The convergence study's configuration: its envs, variants and comparisons, read from benchmarks/study.yml.

A variant is the zoo hyperparameters of its algorithm (zoo_hyperparams/<algo>.yml) on an env with the variant's
overrides on top; ``settings`` and ``train_wrappers`` resolve them, ``load_study`` reads and checks the YAML. Nothing
here depends on the other modules of the study.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
STUDY_FILE = Path(__file__).resolve().with_name("study.yml")
ALGOS = ("trpo_plus", "trpo", "ppo")
VARIANT_KEYS = {"label", "algo", "hyperparameters", "env_kwargs", "train_wrappers", "algo_class", "zero_cg_start"}
ENV_KEYS = {"budget", "target", "target_within", "target_held", "return_target", "zoo"}


@dataclass(frozen=True)
class HoldThenShrink:
    """A ``target_kl`` schedule: ``start`` until ``hold`` of the run is done, then linear to ``end`` at its end."""

    start: float
    end: float
    hold: float

    def __call__(self, progress_remaining: float) -> float:
        done = 1.0 - progress_remaining
        if done <= self.hold:
            return self.start
        return self.start + (self.end - self.start) * (done - self.hold) / (1.0 - self.hold)


@dataclass(frozen=True)
class TimesZoo:
    """A hyperparameter as a multiple of the zoo's value on each env (``n_steps: {times_zoo: {factor: 0.5}}``),
    rounded to an integer where the zoo's is one."""

    factor: float

    def of(self, zoo_value: Any) -> Any:
        value = zoo_value * self.factor
        return max(round(value), 1) if isinstance(zoo_value, int) else float(value)


# a hyperparameter written {<name>: {kwargs}}: a schedule of the remaining progress, or a multiple of the zoo's value
SCHEDULES: dict[str, type] = {"hold_then_shrink": HoldThenShrink, "times_zoo": TimesZoo}


@dataclass(frozen=True)
class EnvSettings:
    """An env of the study: its budget (env steps), and the success rate to reach within ``target_within`` steps
    (held at every evaluation after that, with ``target_held``). A task without a success flag (Gymnasium's
    locomotion) has no ``target`` and a ``return_target``: the evaluation return whose first crossing counts the
    samples to threshold."""

    budget: int
    target: float | None
    target_within: int
    target_held: bool = False
    return_target: float | None = None
    zoo: dict[str, dict[str, Any]] = field(default_factory=dict)  # algo -> the zoo entry the study pins for this env


@dataclass(frozen=True)
class Variant:
    """One variant of the study: what it changes against the zoo settings of ``algo`` (study.yml's keys)."""

    name: str
    label: str
    algo: str
    hyperparameters: dict[str, Any] = field(default_factory=dict)
    env_kwargs: dict[str, Any] | None = None
    train_wrappers: list[dict[str, dict[str, Any]]] | None = None  # None: the zoo entry's env_wrapper
    algo_class: str | None = None
    zero_cg_start: bool = False


@dataclass(frozen=True)
class Comparison:
    """A probability of improvement the report shows beside the study variants': P(``variant`` > ``baseline``)."""

    variant: str
    baseline: str


@dataclass(frozen=True)
class BudgetComparison:
    """P(``variant`` on ``env`` > ``baseline`` on ``baseline_env``) by the success area over the first ``budget`` env
    steps of each run: two variants of one task whose runs are filed under different env ids (or budgets)."""

    variant: str
    env: str
    baseline: str
    baseline_env: str
    budget: int


@dataclass(frozen=True)
class Study:
    envs: dict[str, EnvSettings]
    variants: dict[str, Variant]
    study_variants: list[str]
    comparisons: list[Comparison] = field(default_factory=list)
    budget_comparisons: list[BudgetComparison] = field(default_factory=list)


class StudyError(ValueError):
    """A study file that cannot be used; the message names the variant (or env) and the key."""


def load_study(path: str | Path = STUDY_FILE) -> Study:
    """Read and check the study file: every env's settings, every variant's keys and their types."""
    data = yaml.safe_load(Path(path).read_text())
    envs = {env_id: _env_settings(env_id, settings) for env_id, settings in data["envs"].items()}
    variants = {name: _variant(name, copy.deepcopy(entry)) for name, entry in data["variants"].items()}
    study_variants = list(data["study_variants"])
    if unknown := [name for name in study_variants if name not in variants]:
        raise StudyError(f"{path}: study_variants names no variant {unknown}")
    comparisons = [_comparison(entry, variants, path) for entry in data.get("comparisons") or []]
    budget_comparisons = [_budget_comparison(entry, envs, variants, path) for entry in data.get("budget_comparisons") or []]
    return Study(envs, variants, study_variants, comparisons, budget_comparisons)


def _comparison(entry: Any, variants: Mapping[str, Variant], path: str | Path) -> Comparison:
    if not isinstance(entry, Mapping) or set(entry) != {"variant", "baseline"}:
        raise StudyError(f"{path}: a comparison is {{variant: <name>, baseline: <name>}}, got {entry!r}")
    if unknown := [name for name in (entry["variant"], entry["baseline"]) if name not in variants]:
        raise StudyError(f"{path}: comparison {entry!r} names no variant {unknown}")
    return Comparison(entry["variant"], entry["baseline"])


def _budget_comparison(
    entry: Any, envs: Mapping[str, EnvSettings], variants: Mapping[str, Variant], path: str | Path
) -> BudgetComparison:
    form = "{variant: {env: <id>, name: <variant>}, baseline: {env: <id>, name: <variant>}, budget: <env steps>}"
    sides = ("variant", "baseline")
    if (
        not isinstance(entry, Mapping)
        or set(entry) != {*sides, "budget"}
        or not all(isinstance(entry[side], Mapping) and set(entry[side]) == {"env", "name"} for side in sides)
    ):
        raise StudyError(f"{path}: a budget comparison is {form}, got {entry!r}")
    budget = entry["budget"]
    for side in sides:
        env_id, name = entry[side]["env"], entry[side]["name"]
        if name not in variants:
            raise StudyError(f"{path}: budget comparison {entry!r} names no variant {name!r}")
        if env_id not in envs or envs[env_id].target is None:
            raise StudyError(f"{path}: budget comparison {entry!r}: {env_id!r} is no study env with a success target")
        if isinstance(budget, bool) or not isinstance(budget, int) or not 0 < budget <= envs[env_id].budget:
            raise StudyError(f"{path}: budget comparison {entry!r}: budget must be an int within {env_id}'s budget")
    if envs[entry["variant"]["env"]].target != envs[entry["baseline"]["env"]].target:
        raise StudyError(f"{path}: budget comparison {entry!r}: the two envs' success targets differ")
    return BudgetComparison(
        entry["variant"]["name"], entry["variant"]["env"], entry["baseline"]["name"], entry["baseline"]["env"], budget
    )


def _env_settings(env_id: str, settings: Mapping[str, Any]) -> EnvSettings:
    if unknown := set(settings) - ENV_KEYS:
        raise StudyError(f"env {env_id}: unknown keys {sorted(unknown)} (known: {sorted(ENV_KEYS)})")
    budget = int(settings["budget"])
    if ("target" in settings) == ("return_target" in settings):
        raise StudyError(f"env {env_id}: give either a success target or a return_target, not both or neither")
    return EnvSettings(
        budget=budget,
        target=float(settings["target"]) if "target" in settings else None,
        target_within=int(settings.get("target_within", budget)),
        target_held=bool(settings.get("target_held", False)),
        return_target=float(settings["return_target"]) if "return_target" in settings else None,
        zoo=_pinned_zoo(env_id, settings.get("zoo") or {}),
    )


def _pinned_zoo(env_id: str, entries: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """study.yml's ``zoo: {algo: {entry}}`` of an env: the zoo entries the study keeps for it, each checked as the
    zoo files' entries are (``load_hyperparameters``)."""
    import tempfile

    from sb3_trpo_plus.application.zoo import load_hyperparameters

    pinned = {}
    for algo, entry in entries.items():
        if algo not in ALGOS or not isinstance(entry, Mapping):
            raise StudyError(f"env {env_id}: zoo maps an algo of {ALGOS} to its entry, got {algo!r}: {entry!r}")
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / f"{algo}.yml"
            path.write_text(yaml.safe_dump({env_id: dict(entry)}))
            pinned[algo] = dict(load_hyperparameters(path, algo, [env_id])[env_id])
    return pinned


def _variant(name: str, entry: Mapping[str, Any]) -> Variant:
    def fail(message: str) -> StudyError:
        return StudyError(f"variant {name}: {message}")

    if not isinstance(entry, Mapping):
        raise fail(f"must be a mapping, got {entry!r}")
    if unknown := set(entry) - VARIANT_KEYS:
        raise fail(f"unknown keys {sorted(unknown)} (known: {sorted(VARIANT_KEYS)})")
    if not isinstance(entry.get("label"), str) or not entry["label"]:
        raise fail("needs a label (a string)")
    if entry.get("algo") not in ALGOS:
        raise fail(f"algo must be one of {ALGOS}, got {entry.get('algo')!r}")
    hyperparameters = dict(entry.get("hyperparameters") or {})
    for key, where in (("env_kwargs", "env_kwargs"), ("env_wrapper", "train_wrappers"), ("policy", "")):
        if key in hyperparameters:
            raise fail(f"hyperparameters cannot set {key}" + (f" (a variant sets {where})" if where else ""))
    if not isinstance(hyperparameters.get("policy_kwargs", {}), dict):
        raise fail("policy_kwargs must be a mapping (it adds to the zoo's)")
    for key, value in hyperparameters.items():
        if isinstance(value, dict) and key != "policy_kwargs":
            hyperparameters[key] = _schedule(value, fail)
    env_kwargs = entry.get("env_kwargs")
    if env_kwargs is not None and not isinstance(env_kwargs, dict):
        raise fail(f"env_kwargs must be a mapping, got {env_kwargs!r}")
    wrappers = entry.get("train_wrappers")  # absent: the zoo entry's env_wrapper; [] for none
    if wrappers is not None and (not isinstance(wrappers, list) or not all(_is_wrapper_entry(w) for w in wrappers)):
        raise fail(f"train_wrappers must be a list of {{module.Class: {{kwargs}}}}, got {wrappers!r}")
    algo_class = entry.get("algo_class")
    if algo_class is not None and (not isinstance(algo_class, str) or "." not in algo_class):
        raise fail(f"algo_class must be a dotted path module.Class, got {algo_class!r}")
    zero_cg_start = entry.get("zero_cg_start", False)
    if not isinstance(zero_cg_start, bool) or (zero_cg_start and entry["algo"] != "trpo"):
        raise fail("zero_cg_start is true or false, and true only for algo trpo (sb3-contrib's CG)")
    return Variant(name, entry["label"], entry["algo"], hyperparameters, env_kwargs, wrappers, algo_class, zero_cg_start)


def _schedule(value: dict[str, Any], fail: Any) -> Any:
    """``{hold_then_shrink: {start: 0.01, end: 0.001, hold: 0.4}}`` -> ``HoldThenShrink(0.01, 0.001, 0.4)``."""
    if len(value) != 1 or next(iter(value)) not in SCHEDULES or not isinstance(next(iter(value.values())), dict):
        raise fail(f"a mapping-valued hyperparameter is a schedule {{name: {{kwargs}}}} of {sorted(SCHEDULES)}, got {value}")
    ((name, kwargs),) = value.items()
    try:
        return SCHEDULES[name](**kwargs)
    except TypeError as error:
        raise fail(f"schedule {name}: {error}") from None


def _is_wrapper_entry(entry: Any) -> bool:
    if isinstance(entry, str):
        return "." in entry
    return (
        isinstance(entry, dict)
        and len(entry) == 1
        and "." in next(iter(entry))
        and isinstance(next(iter(entry.values())) or {}, dict)
    )


STUDY = load_study()
ENVS = STUDY.envs
VARIANTS = STUDY.variants
STUDY_VARIANTS = STUDY.study_variants
BUDGETS = {env_id: env.budget for env_id, env in ENVS.items()}
TARGETS = {env_id: env.target for env_id, env in ENVS.items() if env.target is not None}
RETURN_TARGETS = {env_id: env.return_target for env_id, env in ENVS.items() if env.return_target is not None}
TARGET_WITHIN = {env_id: env.target_within for env_id, env in ENVS.items()}
TARGET_HELD = {env_id for env_id, env in ENVS.items() if env.target_held}
LABELS = {name: variant.label for name, variant in VARIANTS.items()}
COMPARISONS = STUDY.comparisons
BUDGET_COMPARISONS = STUDY.budget_comparisons


# ---------------------------------------------------------------------------------------------- settings
def hyperparameters(variant: Variant, env_id: str) -> dict[str, Any]:
    """The zoo hyperparameters of ``variant.algo`` on ``env_id`` with the variant's on top (its policy_kwargs add to
    the zoo's net_arch, activation, ...; its env_kwargs replace the zoo's)."""
    from sb3_trpo_plus.application.zoo import load_hyperparameters, parse_policy_kwargs

    pinned = ENVS[env_id].zoo.get(variant.algo) if env_id in ENVS else None
    if pinned is not None:  # the zoo entry the study keeps for this env (study.yml's zoo)
        params = dict(pinned)
    else:
        params = dict(load_hyperparameters(ROOT / "zoo_hyperparams" / f"{variant.algo}.yml", variant.algo, [env_id])[env_id])
    for key, value in variant.hyperparameters.items():
        if isinstance(value, TimesZoo):
            if key not in params:
                raise StudyError(f"variant {variant.name}: {key} is a multiple of the zoo's, and {env_id}'s has none")
            params[key] = value.of(params[key])
        else:
            if key == "policy_kwargs":  # names (activation_fn: relu) read as the zoo's are
                value = {**params.get(key, {}), **parse_policy_kwargs(value, f"variant {variant.name}")}
            params[key] = value
    if variant.env_kwargs is not None:
        params["env_kwargs"] = dict(variant.env_kwargs)
    return params


@dataclass(frozen=True)
class ModelSettings:
    """What builds a variant's model on an env: constructor kwargs, envs, VecNormalize, policy, env kwargs."""

    kwargs: dict[str, Any]
    n_envs: int
    normalize_kwargs: dict[str, Any] | None  # the training VecNormalize's kwargs; None: no VecNormalize
    policy: str
    env_kwargs: dict[str, Any]

    @property
    def normalize(self) -> bool:
        """Whether the training envs are wrapped in a VecNormalize."""
        return self.normalize_kwargs is not None


def settings(variant: Variant, env_id: str) -> ModelSettings:
    """The zoo settings of ``variant`` on ``env_id``, split as the study builds its envs and model."""
    from sb3_trpo_plus.application.zoo import Recipe

    chosen = Recipe.of(env_id, variant.algo, hyperparameters(variant, env_id))
    kwargs = dict(chosen.constructor)
    env_kwargs = dict(chosen.env_kwargs or {})  # the evaluation envs' (and, under the wrappers, training)
    return ModelSettings(kwargs, chosen.n_envs, normalize_kwargs(chosen.normalize, kwargs), chosen.policy, env_kwargs)


def train_wrappers(variant: Variant, env_id: str) -> list[Any]:
    """The Gymnasium wrappers of ``variant``'s training envs on ``env_id``, in rl-zoo's ``env_wrapper`` form: the
    variant's ``train_wrappers`` where it sets them (``[]``: none), else the zoo entry's ``env_wrapper`` (the recipe's
    training aids, such as ``Grasper3D-v7``'s scripted starts), refused where it holds a wrapper that is not a training
    aid: rl-zoo3 would wrap the evaluation envs with that one too, and the study's evaluation envs carry none."""
    if variant.train_wrappers is not None:
        return list(variant.train_wrappers)
    from sb3_trpo_plus.application.zoo import evaluation_wrappers

    inherited = list(hyperparameters(variant, env_id).get("env_wrapper") or [])
    if evaluated := evaluation_wrappers(inherited):  # the study's evaluation envs carry no wrapper
        raise StudyError(
            f"variant {variant.name} on {env_id}: the zoo's env_wrapper {evaluated} would wrap evaluation envs too; "
            "set the variant's train_wrappers"
        )
    return inherited


def normalize_kwargs(normalize: bool | dict[str, Any], params: Mapping[str, Any]) -> dict[str, Any] | None:
    """VecNormalize's kwargs for the zoo's ``normalize`` (true, false or a mapping of VecNormalize kwargs such as
    ``{norm_obs: false, norm_reward: true}``), as rl-zoo3 makes them: the model's ``gamma`` (where it sets one) is the
    discount of the reward normalization; None without VecNormalize."""
    if isinstance(normalize, Mapping):
        kwargs = dict(normalize)
    elif normalize:
        kwargs = {}
    else:
        return None
    if "gamma" in params:
        kwargs["gamma"] = params["gamma"]
    return kwargs
