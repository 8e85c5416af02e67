"""rl-zoo3 integration: validated YAML hyperparameters, algorithm registration, an Optuna sampler."""

from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml
from gymnasium.envs.registration import registry
from torch import nn

from sb3_trpo_plus.common.arguments import ArgumentError, got

if TYPE_CHECKING:
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

# An installed wheel carries the recipes as package data; a source checkout (or editable install) has the top-level folder
_PACKAGE = Path(__file__).resolve().parents[1]
_PACKAGED_ZOO_DIR = _PACKAGE / "zoo_hyperparams"
ZOO_DIR = _PACKAGED_ZOO_DIR if _PACKAGED_ZOO_DIR.is_dir() else _PACKAGE.parent / "zoo_hyperparams"
ALGO_FILES = {"trpo_plus": "trpo_plus.yml", "trpo": "trpo.yml", "ppo": "ppo.yml"}

ACTIVATIONS: dict[str, type[nn.Module]] = {
    "tanh": nn.Tanh,
    "relu": nn.ReLU,
    "elu": nn.ELU,
    "leaky_relu": nn.LeakyReLU,
    "gelu": nn.GELU,
    "silu": nn.SiLU,
}
# Keys rl-zoo3 consumes itself (the others go to the algorithm's constructor)
ZOO_KEYS: dict[str, tuple[type, ...]] = {
    "n_envs": (int,),
    "n_timesteps": (int, float),
    "policy": (str,),
    "normalize": (bool, str, dict),  # text is parsed as a literal dict(...), never evaluated
    "env_wrapper": (str, list, dict),
    "vec_env_wrapper": (str, list, dict),
    "callback": (str, list, dict),
    "frame_stack": (int,),
    "monitor_kwargs": (dict, str),
    "env_kwargs": (dict,),
    "policy_kwargs": (dict, str),
}
# Keys of a TRPOPlus recipe that ``trpo-plus train`` and ``make_model`` consume (not rl-zoo3, not the constructor)
WORKER_KEYS: dict[str, tuple[type, ...]] = {
    "rollout_workers": (str, type(None)),  # "BACKEND:N": collect with N rollout workers (parse_workers)
}
# packages whose wrapper classes a YAML file may name (rl-zoo3 imports and calls what env_wrapper names)
WRAPPER_PACKAGES = (
    "grasp_envs.",
    "gymnasium.wrappers.",
    "stable_baselines3.",
    "sb3_contrib.",
    "rl_zoo3.wrappers.",
    "sb3_trpo_plus.",
)
SCHEDULE_KEYS = {"learning_rate", "clip_range", "clip_range_vf"}  # may be rl-zoo schedules such as "lin_3e-4"
SCHEDULE_PATTERN = re.compile(r"^lin_[0-9.eE+-]+$")
POLICY_KWARGS_KEYS = {
    "net_arch",
    "activation_fn",
    "log_std_init",
    "ortho_init",
    "squash_output",
    "full_std",
    "use_expln",
    "share_features_extractor",
    "optimizer_kwargs",
}


class HyperparameterError(ArgumentError):
    """A hyperparameter file that cannot be used; the message names the file, the env and the key."""


def algorithms() -> dict[str, type[OnPolicyAlgorithm]]:
    from sb3_contrib import TRPO
    from stable_baselines3 import PPO

    from sb3_trpo_plus.algorithm.trpo_plus import TRPOPlus

    return {"trpo_plus": TRPOPlus, "trpo": TRPO, "ppo": PPO}


def _constructor_types(algo_class: type) -> dict[str, tuple[type, ...]]:
    """Accepted types of every constructor argument, from its default value: an int default takes an int only (never
    a float such as ``64.0``), a float default an int or a float, a bool default a bool only."""
    accepted: dict[str, tuple[type, ...]] = {}
    for name, parameter in inspect.signature(algo_class).parameters.items():
        if name in {"self", "policy", "env", "_init_setup_model", "kwargs"}:
            continue
        default = parameter.default
        if isinstance(default, bool):
            accepted[name] = (bool,)
        elif isinstance(default, int):
            accepted[name] = (int,)
        elif isinstance(default, float):
            accepted[name] = (int, float, str) if name in SCHEDULE_KEYS else (int, float)
        elif isinstance(default, str):
            accepted[name] = (str,)
        else:  # None or objects: several types make sense
            accepted[name] = (int, float, str, bool, dict, list, type(None))
    return accepted


def dict_text(value: str, where: str, key: str, activations: bool = False) -> dict[str, Any]:
    """rl-zoo's ``"dict(key=value, ...)"`` text as a mapping, parsed *without* ``eval``: literals only, and
    ``nn.<Activation>`` names where ``activations``."""
    try:
        tree = ast.parse(value.strip(), mode="eval").body
    except SyntaxError as error:
        raise HyperparameterError(f"{where}: {key} is not valid: {error}") from None
    if not (isinstance(tree, ast.Call) and isinstance(tree.func, ast.Name) and tree.func.id == "dict" and not tree.args):
        raise HyperparameterError(f"{where}: {key} must be text of the form dict(key=value, ...)")
    mapping: dict[str, Any] = {}
    for keyword in tree.keywords:
        if keyword.arg is None:
            raise HyperparameterError(f"{where}: {key} must name each key (dict(key=value, ...)), got **")
        node = keyword.value
        if activations and isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "nn":
            mapping[str(keyword.arg)] = node.attr
            continue
        try:
            mapping[str(keyword.arg)] = ast.literal_eval(node)
        except ValueError:
            allowed = "a literal or nn.<Activation>" if activations else "a literal"
            raise HyperparameterError(f"{where}: {key} value of {keyword.arg!r} must be {allowed}") from None
    return mapping


def parse_policy_kwargs(value: Any, where: str) -> dict[str, Any]:
    """``policy_kwargs`` as a mapping, or rl-zoo's ``"dict(...)"`` text parsed *without* ``eval``."""
    if isinstance(value, str):
        value = dict_text(value, where, "policy_kwargs", activations=True)
    if not isinstance(value, dict):
        raise HyperparameterError(f"{where}: policy_kwargs must be a mapping, got {type(value).__name__}")
    result = dict(value)
    for key in result:
        if key not in POLICY_KWARGS_KEYS:
            raise HyperparameterError(f"{where}: unknown policy_kwargs key {key!r} (known: {sorted(POLICY_KWARGS_KEYS)})")
    activation = result.get("activation_fn")
    if isinstance(activation, str):
        name = activation.lower()
        by_class_name = {cls.__name__.lower(): cls for cls in ACTIVATIONS.values()}
        if name not in ACTIVATIONS and name not in by_class_name:
            raise HyperparameterError(f"{where}: unknown activation_fn {activation!r} (known: {sorted(ACTIVATIONS)})")
        result["activation_fn"] = ACTIVATIONS.get(name) or by_class_name[name]
    return result


def load_hyperparameters(path: str | Path, algo: str, env_ids: Iterable[str] | None = None) -> dict[str, dict[str, Any]]:
    """Load and validate an rl-zoo YAML file for ``algo``; return ``{env_id: hyperparameters}``.

    Unknown keys, wrong types, unknown env ids and malformed YAML raise :class:`HyperparameterError`
    naming the file, the env and the key. ``policy_kwargs`` comes back as a dict with activation classes.
    """
    path = Path(path)
    algos = algorithms()
    if algo not in algos:
        raise HyperparameterError(f"unknown algorithm {algo!r} (known: {sorted(algos)})")
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as error:
        raise HyperparameterError(f"{path}: cannot read: {error.strerror or error}") from None
    except yaml.YAMLError as error:
        raise HyperparameterError(f"{path}: malformed YAML: {error}") from None
    if not isinstance(data, dict):
        raise HyperparameterError(f"{path}: expected a mapping of env ids to hyperparameters")
    accepted = {**_constructor_types(algos[algo]), **ZOO_KEYS, **(WORKER_KEYS if algo == "trpo_plus" else {})}
    wanted = None if env_ids is None else set(env_ids)
    result: dict[str, dict[str, Any]] = {}
    for env_id, params in data.items():
        if wanted is not None and env_id not in wanted:
            continue
        if env_id not in registry:
            raise HyperparameterError(f"{path}: unknown env id {env_id!r}")
        if not isinstance(params, dict):
            raise HyperparameterError(f"{path}: {env_id}: expected a mapping of hyperparameters")
        checked: dict[str, Any] = {}
        for key, value in params.items():
            where = f"{path}: {env_id}: {key}"
            if key not in accepted:
                raise HyperparameterError(f"{where}: unknown hyperparameter for {algo}")
            types_ok = accepted[key]
            if not isinstance(value, types_ok) or (isinstance(value, bool) and bool not in types_ok):
                names = "/".join(t.__name__ for t in types_ok)
                raise HyperparameterError(f"{where}: expected {names}, {got(value, with_type=True)}")
            if key in SCHEDULE_KEYS and isinstance(value, str) and not SCHEDULE_PATTERN.match(value):
                raise HyperparameterError(
                    f"{where}: expected a number or a schedule 'lin_<value>', {got(value, with_type=True)}"
                )
            if key == "policy":
                value = check_policy(value, where)
            elif key == "policy_kwargs":
                value = parse_policy_kwargs(value, f"{path}: {env_id}")
            elif key in {"normalize", "monitor_kwargs"} and isinstance(value, str):
                value = dict_text(value, f"{path}: {env_id}", key)  # rl-zoo3 would eval the text
            elif key == "callback":
                value = check_wrappers(value, where, base="callback")
            elif key in {"env_wrapper", "vec_env_wrapper"}:
                value = check_wrappers(value, where, base=key)
            elif key == "rollout_workers" and value is not None:
                try:
                    parse_workers(value)
                except ValueError as error:
                    raise HyperparameterError(f"{where}: {error}") from None
            checked[key] = value
        if "n_timesteps" not in checked or "policy" not in checked:
            raise HyperparameterError(f"{path}: {env_id}: n_timesteps and policy are required")
        if env_id in _our_env_ids():
            # so that the monitor CSV and rollout/success_rate carry the success flag
            checked.setdefault("monitor_kwargs", {"info_keywords": ("is_success",)})
            checked.setdefault("callback", "sb3_trpo_plus.application.callbacks.RewardTermsCallback")
        result[env_id] = checked
    return result


@dataclass(frozen=True)
class Recipe(Mapping[str, Any]):
    """One env's entry of a recipe file, checked (:func:`load_hyperparameters`) and split once: the keys that build
    the run (its envs, wrappers, normalisation, workers, budget) as fields, the algorithm's constructor arguments in
    :attr:`constructor`. As a mapping it is the entry itself (``recipe["n_timesteps"]``), as rl-zoo3 reads it."""

    env_id: str
    algo: str
    n_timesteps: int | float
    policy: str
    n_envs: int = 1
    normalize: bool | dict[str, Any] = False
    env_kwargs: dict[str, Any] | None = None
    env_wrapper: Any = None
    vec_env_wrapper: Any = None
    callback: Any = None
    frame_stack: int | None = None
    monitor_kwargs: dict[str, Any] | None = None
    rollout_workers: str | None = None
    constructor: dict[str, Any] = dataclasses.field(default_factory=dict)
    """The algorithm's constructor arguments (``policy_kwargs`` included), ``lin_<x>`` schedules as their text."""

    @classmethod
    def of(cls, env_id: str, algo: str, entry: Mapping[str, Any]) -> Recipe:
        """Split a checked entry (or one with overrides on top) into the run's keys and the constructor's."""
        run = {key: value for key, value in entry.items() if key in RUN_KEYS}
        return cls(env_id, algo, **run, constructor={k: v for k, v in entry.items() if k not in RUN_KEYS})

    def replace(self, **overrides: Any) -> Recipe:
        """This recipe with ``overrides`` on top (run keys and constructor arguments alike)."""
        return Recipe.of(self.env_id, self.algo, {**self, **overrides})

    def constructor_arguments(self) -> dict[str, Any]:
        """:attr:`constructor` with rl-zoo's ``lin_<x>`` texts as SB3's ``LinearSchedule`` from ``x`` to 0."""
        from stable_baselines3.common.utils import LinearSchedule

        return {
            key: LinearSchedule(float(value.removeprefix("lin_")), 0.0, 1.0)
            if key in SCHEDULE_KEYS and isinstance(value, str)
            else value
            for key, value in self.constructor.items()
        }

    @property
    def info_keywords(self) -> tuple[str, ...] | None:
        """The info keys the envs' monitor records (``monitor_kwargs``' ``info_keywords``)."""
        keywords = (self.monitor_kwargs or {}).get("info_keywords")
        return None if keywords is None else tuple(keywords)

    @property
    def scripted_starts(self) -> dict[str, Any] | None:
        """The ``ScriptedStarts`` options of ``env_wrapper`` (None without one); the batched engine and the rollout
        workers run no other per-env wrapper, so any other raises ``ValueError`` naming it."""
        if self.env_wrapper is None:
            return None
        entries = check_wrappers(self.env_wrapper, "env_wrapper", base="env_wrapper")
        names = [next(iter(entry)) if isinstance(entry, dict) else entry for entry in entries]
        if names != ["grasp_envs.wrappers.ScriptedStarts"]:
            raise ValueError(
                f"the batched engine runs no per-env wrapper but grasp_envs.wrappers.ScriptedStarts (once); this "
                f"recipe's env_wrapper is {names}: use vec_env='dummy'"
            )
        entry = entries[0]
        return dict(next(iter(entry.values())) or {}) if isinstance(entry, dict) else {}

    def _entry(self) -> dict[str, Any]:
        """The entry: every run key that is set (``n_envs`` and ``normalize`` always), then the constructor's."""
        run = {key: getattr(self, key) for key in RUN_KEYS}
        return {**{key: value for key, value in run.items() if value is not None}, **self.constructor}

    def __getitem__(self, key: str) -> Any:
        return self._entry()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._entry())

    def __len__(self) -> int:
        return len(self._entry())


RUN_KEYS = (*(key for key in ZOO_KEYS if key != "policy_kwargs"), *WORKER_KEYS)
"""A recipe's keys that build the run, not the algorithm: :class:`Recipe`'s fields."""


def load_recipes(path: str | Path, algo: str, env_ids: Iterable[str] | None = None) -> dict[str, Recipe]:
    """:func:`load_hyperparameters` as :class:`Recipe` records."""
    return {env_id: Recipe.of(env_id, algo, entry) for env_id, entry in load_hyperparameters(path, algo, env_ids).items()}


def check_wrappers(value: Any, where: str, base: str = "env_wrapper") -> list[str | dict[str, dict[str, Any]]]:
    """rl-zoo's ``env_wrapper``, ``vec_env_wrapper`` or ``callback`` value (``base``) as a list of ``name`` or
    ``{name: kwargs}``, each name a class of that kind in a known package (``WRAPPER_PACKAGES``): rl-zoo3 imports the
    named module and calls the named object with the kwargs, so a name from elsewhere would run arbitrary code."""
    import gymnasium as gym
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecEnvWrapper

    bases: dict[str, type] = {"env_wrapper": gym.Wrapper, "vec_env_wrapper": VecEnvWrapper, "callback": BaseCallback}

    entries = value if isinstance(value, list) else [value]
    checked: list[str | dict[str, dict[str, Any]]] = []
    for entry in entries:
        if isinstance(entry, dict):
            if len(entry) != 1:
                raise HyperparameterError(f"{where}: a class with arguments is {{name: {{argument: value}}}}, got {entry!r}")
            ((name, kwargs),) = entry.items()
            if not isinstance(kwargs, dict) or not all(isinstance(k, str) for k in kwargs):
                raise HyperparameterError(f"{where}: the arguments of {name!r} must be a mapping, got {kwargs!r}")
        else:
            name, kwargs = entry, None
        if not isinstance(name, str) or not name.startswith(WRAPPER_PACKAGES):
            raise HyperparameterError(f"{where}: {name!r} is not a class of {', '.join(WRAPPER_PACKAGES)}")
        module_name, _, class_name = name.rpartition(".")
        try:
            wrapper = getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError):
            raise HyperparameterError(f"{where}: no class {name!r}") from None
        if not (isinstance(wrapper, type) and issubclass(wrapper, bases[base])):
            raise HyperparameterError(f"{where}: {name!r} is not a {bases[base].__name__} subclass")
        checked.append(name if kwargs is None else {name: dict(kwargs)})
    return checked


def check_policy(value: Any, where: str) -> str:
    """A policy name that rl-zoo3 resolves without importing anything: one of the algorithms' aliases
    (``MlpPolicy``, ``CnnPolicy``, ``MultiInputPolicy``); rl-zoo3 imports a dotted name's module."""
    aliases = sorted({alias for algo in algorithms().values() for alias in algo.policy_aliases})
    if not isinstance(value, str) or value not in aliases:
        raise HyperparameterError(f"{where}: policy must be one of {aliases}, got {value!r}")
    return value


def evaluation_wrappers(value: Any) -> list[Any] | None:
    """``env_wrapper``'s entries without the training aids (wrapper classes with ``training_only = True``, such as
    ``grasp_envs.wrappers.ScriptedStarts``): what evaluation and enjoy envs are wrapped with. Each name is checked
    (:func:`check_wrappers`) before it is imported."""
    if value is None:
        return None
    kept = []
    for entry in check_wrappers(value, "env_wrapper"):
        name = next(iter(entry)) if isinstance(entry, dict) else entry
        if isinstance(name, str):
            module_name, _, class_name = name.rpartition(".")
            wrapper = getattr(importlib.import_module(module_name), class_name, None)
        else:
            wrapper = name
        if not getattr(wrapper, "training_only", False):
            kept.append(entry)
    return kept or None


def _our_env_ids() -> tuple[str, ...]:
    from sb3_trpo_plus.rollouts.engines import batch_engine_ids

    return batch_engine_ids()


def check_constructor_values(entry: dict[str, Any], where: str) -> None:
    """The values of a TRPOPlus recipe's constructor arguments as the constructor checks them, before anything is
    built: each in its range (:data:`~sb3_trpo_plus.algorithm.hyperparameters.HYPERPARAMETER_RULES`; ``lin_<x>`` schedules
    as ``x``) and together (:func:`~sb3_trpo_plus.algorithm.hyperparameters.check_combinations`, the constructor's defaults
    for the arguments the recipe leaves out). :class:`HyperparameterError` names ``where`` (the file and the env)
    and the key."""
    from sb3_trpo_plus.algorithm.hyperparameters import HYPERPARAMETER_RULES, check_combinations
    from sb3_trpo_plus.algorithm.trpo_plus import TRPOPlus

    for key, value in entry.items():
        rule = HYPERPARAMETER_RULES.get(key)
        if key in {"policy", "policy_kwargs"} or rule is None:  # checked by load_hyperparameters, or no argument
            continue
        if key in SCHEDULE_KEYS and isinstance(value, str):
            try:
                value = float(value.removeprefix("lin_"))
            except ValueError:
                raise HyperparameterError(f"{where}: {key}: expected a schedule 'lin_<number>', got {value!r}") from None
        if not rule.accepts(value):
            raise HyperparameterError(f"{where}: {key}: must be {rule.requirement}, {got(entry[key])}")
    defaults = {name: parameter.default for name, parameter in inspect.signature(TRPOPlus).parameters.items()}
    try:
        check_combinations({**defaults, **entry})
    except ArgumentError as error:
        raise HyperparameterError(f"{where}: {error}") from None


def batch_training_env(
    env_id: str,
    *,
    n_envs: int = 1,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    monitor_dir: str | None = None,
    wrapper_class: Any = None,
    monitor_kwargs: dict[str, Any] | None = None,
    n_threads: int = 1,
) -> Any:
    """The training envs of an rl-zoo3 run (:data:`sb3_trpo_plus.application.experiment.TrainingEnvs`) on the batched engine.

    ``wrapper_class`` is rl-zoo3's ``env_wrapper``: only ``grasp_envs.wrappers.ScriptedStarts`` can be run batched,
    any other raises ``TypeError`` naming it.
    """
    import os

    from sb3_trpo_plus.rollouts.engines import batch_envs, scripted_starts_options

    return batch_envs(
        env_id,
        n_envs,
        seed=seed,
        n_threads=n_threads,
        env_kwargs=env_kwargs,
        scripted_starts=scripted_starts_options(wrapper_class, "--vec-env batch"),
        info_keywords=(monitor_kwargs or {}).get("info_keywords", ()),
        monitor_file=None if monitor_dir is None else os.path.join(monitor_dir, "batch"),
    )


WORKER_BACKENDS = ("inprocess", "process", "ray")


def parse_workers(value: Any) -> tuple[str, int]:
    """``"BACKEND:N"`` (``trpo-plus train --workers``, ``make_model(workers=...)``, a recipe's ``rollout_workers``)
    as ``(backend, N)``; anything else raises ``ValueError`` naming the value."""
    backend, _, count = value.partition(":") if isinstance(value, str) else ("", "", "")
    if backend not in WORKER_BACKENDS or not count.isdigit() or int(count) < 1:
        raise ValueError(f"expected 'BACKEND:N' with BACKEND one of {', '.join(WORKER_BACKENDS)} and N >= 1, got {value!r}")
    return backend, int(count)


def workers_training_env(
    env_id: str,
    *,
    n_envs: int = 1,
    seed: int | None = None,
    env_kwargs: dict[str, Any] | None = None,
    monitor_dir: str | None = None,
    wrapper_class: Any = None,
    monitor_kwargs: dict[str, Any] | None = None,
    backend: str,
    num_workers: int,
    n_threads: int = 1,
) -> Any:
    """The training envs of an rl-zoo3 run (:data:`sb3_trpo_plus.application.experiment.TrainingEnvs`) as a pool of
    rollout workers (``sb3_trpo_plus.rollouts``): the recipe's ``n_envs`` split evenly over ``num_workers`` workers of
    ``backend`` (``inprocess``, ``process`` or ``ray``), the same seeds (env ``i``: ``seed + i``), ``env_kwargs`` and
    scripted starts; episodes in ``<run>/workers.monitor.csv``.
    """
    import os

    from sb3_trpo_plus import rollouts
    from sb3_trpo_plus.rollouts.engines import scripted_starts_options

    return rollouts.split_pool(
        backend,
        env_id,
        n_envs,
        num_workers,
        seed=seed,
        sim_threads=n_threads,
        env_kwargs=env_kwargs,
        scripted_starts=scripted_starts_options(wrapper_class, f"--workers {backend}"),
        info_keywords=(monitor_kwargs or {}).get("info_keywords", ()),
        monitor_file=None if monitor_dir is None else os.path.join(monitor_dir, "workers"),
    )
