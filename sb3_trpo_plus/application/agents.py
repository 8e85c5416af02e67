"""Load trained agents from rl-zoo3 run folders without running code from the files.

A run folder (``logs/<algo>/<ENV>_<n>/``) holds the model zip ``<ENV>.zip``, and in ``<ENV>/`` the
``config.yml`` and ``args.yml`` rl-zoo3 wrote and the ``vecnormalize.pkl`` statistics. SB3's
``load`` unpickles parts of the zip, rl-zoo3 reads the YAML files with ``yaml.UnsafeLoader`` and
``eval``s some strings in them, and ``VecNormalize.load`` unpickles the statistics: each can run
arbitrary code from a downloaded run. This module reads them as data only:

- YAML with :class:`RunConfigLoader`: plain YAML plus exactly the one tag rl-zoo3 writes,
  ``!!python/object/apply:collections.OrderedDict``; any other tag is refused;
- rl-zoo3's ``"dict(...)"`` strings parsed as literals, never evaluated;
- the policy rebuilt from its class alias and keyword arguments (the plain JSON fields of the zip's
  ``data`` entry) and its weights read from ``policy.pth`` with ``torch.load(weights_only=True)``;
- the VecNormalize statistics read by :class:`StatisticsUnpickler`, which builds numpy arrays and
  records every other object as inert data (only VecNormalize, RunningMeanStd, Gymnasium spaces and
  numpy random-generator states may appear; any other global is refused).

``trust_pickle=True`` loads with SB3's own ``load`` instead (needed to continue training).
See ``docs/security.md``.
"""

from __future__ import annotations

import ast
import io
import json
import pickle
import re
import zipfile
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import torch as th
import yaml
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sb3_trpo_plus.algorithm.normalization import NormalizationStats, StatisticsMismatchError
from sb3_trpo_plus.application.run_files import (  # noqa: F401  (RunFileError, load_normalization: this module's names too)
    RunFileError,
    StatisticsUnpickler,
    load_normalization,
)

T = TypeVar("T")
ORDERED_DICT_TAG = "tag:yaml.org,2002:python/object/apply:collections.OrderedDict"


# ---------------------------------------------------------------------------------------------- YAML
class RunConfigLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` that also reads the three Python tags rl-zoo3 writes, as data.

    ``!!python/object/apply:collections.OrderedDict`` (``config.yml`` and ``args.yml`` are ordered dicts) builds an
    ``OrderedDict`` from its list of ``[key, value]`` pairs; ``!!python/tuple`` a tuple (``info_keywords``);
    ``!!python/name:`` one of a fixed set of classes (activation functions such as
    ``torch.nn.modules.activation.Tanh``, SB3's feature extractors, torch optimizers), looked up, never imported
    by name. Every other Python tag stays refused, as in ``SafeLoader``.
    """


def _construct_ordered_dict(loader: RunConfigLoader, node: yaml.Node) -> OrderedDict:
    if not isinstance(node, yaml.SequenceNode):
        raise yaml.constructor.ConstructorError(None, None, "OrderedDict: expected a list of arguments", node.start_mark)
    args = loader.construct_sequence(node, deep=True)
    pairs = args[0] if len(args) == 1 else None
    if not isinstance(pairs, list) or not all(isinstance(p, list) and len(p) == 2 for p in pairs):
        raise yaml.constructor.ConstructorError(
            None, None, "OrderedDict: expected one argument, a list of [key, value] pairs", node.start_mark
        )
    return OrderedDict((key, value) for key, value in pairs)


def _construct_tuple(loader: RunConfigLoader, node: yaml.Node) -> tuple:
    if not isinstance(node, yaml.SequenceNode):
        raise yaml.constructor.ConstructorError(None, None, "tuple: expected a list", node.start_mark)
    return tuple(loader.construct_sequence(node, deep=True))


def _construct_known_class(loader: RunConfigLoader, suffix: str, node: yaml.Node) -> type:
    known = _known_classes()
    if suffix not in known:
        raise yaml.constructor.ConstructorError(
            None, None, f"python/name:{suffix} is none of the classes a config may name", node.start_mark
        )
    return known[suffix]


RunConfigLoader.add_constructor(ORDERED_DICT_TAG, _construct_ordered_dict)
RunConfigLoader.add_constructor("tag:yaml.org,2002:python/tuple", _construct_tuple)
RunConfigLoader.add_multi_constructor("tag:yaml.org,2002:python/name:", _construct_known_class)


def load_run_yaml(path: str | Path) -> Any:
    """Read one of a run's YAML files as plain data; :class:`RunFileError` names the file on any problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as error:
        raise RunFileError(f"{path}: cannot read: {error}") from None
    try:
        return yaml.load(text, Loader=RunConfigLoader)  # a SafeLoader subclass
    except yaml.constructor.ConstructorError as error:
        raise RunFileError(
            f"{path}: refused: {error.problem} (read: plain YAML, rl-zoo3's OrderedDict and tuples, known classes)"
        ) from None
    except yaml.YAMLError as error:
        raise RunFileError(f"{path}: malformed YAML: {error}") from None


def parse_dict_text(text: str, where: str) -> dict[str, Any]:
    """rl-zoo3's ``"dict(key=value, ...)"`` text as a dict of literals, without evaluating it
    (:func:`sb3_trpo_plus.application.zoo.dict_text`)."""
    from sb3_trpo_plus.application.zoo import HyperparameterError, dict_text

    try:
        return dict_text(text, where, "it")
    except HyperparameterError as error:
        reason = str(error).removeprefix(f"{where}: ")
        raise RunFileError(f"{where}: refused {text!r}: {reason}, which is read, not run") from None


@dataclass(frozen=True)
class RunConfig:
    """What a run folder says about making its env, as plain data."""

    env_id: str
    algo: str
    hyperparams: dict[str, Any]
    env_kwargs: dict[str, Any]
    normalize_kwargs: dict[str, Any] | None  # None: no VecNormalize
    stats_dir: Path  # <run>/<ENV>/


def read_run_config(run_folder: str | Path, env_id: str | None = None, algo: str | None = None) -> RunConfig:
    """Read ``<run>/<ENV>/config.yml`` and ``args.yml`` safely, as rl-zoo3's enjoy interprets them.

    The config's ``env_kwargs`` are replaced by those of the command line that trained the run (``args.yml``).
    A ``normalize`` or ``policy_kwargs`` string is parsed as a literal ``dict(...)``, never evaluated.
    """
    run_folder = Path(run_folder)
    env_id = env_id or _env_id_of(run_folder)
    algo = algo or run_folder.parent.name
    stats_dir = run_folder / _env_folder_name(env_id)
    config_path, args_path = stats_dir / "config.yml", stats_dir / "args.yml"
    hyperparams: dict[str, Any] = {}
    if config_path.is_file():
        loaded = load_run_yaml(config_path)
        if not isinstance(loaded, dict):
            raise RunFileError(f"{config_path}: expected a mapping of hyperparameters, got {type(loaded).__name__}")
        hyperparams = dict(loaded)
    env_kwargs = _mapping(hyperparams.pop("env_kwargs", None), config_path, "env_kwargs")
    if args_path.is_file():
        args = load_run_yaml(args_path)
        if not isinstance(args, dict):
            raise RunFileError(f"{args_path}: expected a mapping of command-line arguments, got {type(args).__name__}")
        if args.get("env_kwargs") is not None:
            env_kwargs = _mapping(args["env_kwargs"], args_path, "env_kwargs")
    normalize = hyperparams.get("normalize", False)
    normalize_kwargs: dict[str, Any] | None
    if isinstance(normalize, str):
        normalize_kwargs = parse_dict_text(normalize, f"{config_path}: normalize")
    elif isinstance(normalize, dict):
        normalize_kwargs = dict(normalize)
    elif isinstance(normalize, bool):
        normalize_kwargs = {"norm_obs": True, "norm_reward": False} if normalize else None
    else:
        raise RunFileError(f"{config_path}: normalize must be a bool, a mapping or dict(...) text, got {normalize!r}")
    for key in ("policy_kwargs", "monitor_kwargs"):
        if isinstance(hyperparams.get(key), str):
            hyperparams[key] = _parse_kwargs_text(hyperparams[key], f"{config_path}: {key}", key)
    _check_named_classes(hyperparams, config_path)
    return RunConfig(env_id, algo, hyperparams, env_kwargs, normalize_kwargs, stats_dir)


def _check_named_classes(hyperparams: dict[str, Any], path: Path) -> None:
    """Refuse a config whose ``env_wrapper``, ``vec_env_wrapper``, ``callback`` or ``policy`` names anything but a
    class of that kind from a known package: rl-zoo3 imports and calls what these name."""
    from sb3_trpo_plus.application.zoo import HyperparameterError, check_policy, check_wrappers

    try:
        for key in ("env_wrapper", "vec_env_wrapper", "callback"):
            if hyperparams.get(key) is not None:
                check_wrappers(hyperparams[key], f"{path}: {key}", base=key)
        if "policy" in hyperparams:
            check_policy(hyperparams["policy"], f"{path}: policy")
    except HyperparameterError as error:
        raise RunFileError(f"{error} (refused)") from None


def validate_run_files(run_folder: str | Path, env_id: str | None = None) -> None:
    """Refuse (:class:`RunFileError`) a run whose YAML files carry code, before a tool that trusts them reads them."""
    read_run_config(run_folder, env_id)


def _parse_kwargs_text(text: str, where: str, key: str) -> dict[str, Any]:
    if key == "policy_kwargs":
        from sb3_trpo_plus.application.zoo import HyperparameterError, parse_policy_kwargs

        try:
            return parse_policy_kwargs(text, where)
        except HyperparameterError as error:
            raise RunFileError(f"refused: {error}") from None
    return parse_dict_text(text, where)


def _mapping(value: Any, path: Path, key: str) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise RunFileError(f"{path}: {key} must be a mapping, got {type(value).__name__}")
    return dict(value)


def _env_id_of(run_folder: Path) -> str:
    match = re.fullmatch(r"(.+)_\d+", run_folder.name)
    if match is None:
        raise RunFileError(f"{run_folder}: cannot tell the env id from the folder name (expected <ENV>_<n>); pass env_id")
    return match.group(1)


def _env_folder_name(env_id: str) -> str:
    from huggingface_sb3 import EnvironmentName

    return str(EnvironmentName(env_id))


# ---------------------------------------------------------------------------------------------- model zip
def read_model_data(model_path: str | Path) -> dict[str, Any]:
    """The zip's ``data`` entry as JSON, its cloudpickled fields left undecoded (never unpickled)."""
    model_path = Path(model_path)
    raw = _read_zip_member(model_path, "data")
    try:
        data = json.loads(raw)
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise RunFileError(f"{model_path}: the 'data' entry is not valid JSON (corrupted?): {error}") from None
    if not isinstance(data, dict):
        raise RunFileError(f"{model_path}: the 'data' entry is not a JSON object")
    return data


def _read_zip_member(model_path: Path, name: str) -> bytes:
    if not model_path.is_file():
        raise RunFileError(f"{model_path}: no such model file")
    try:
        with zipfile.ZipFile(model_path) as archive:
            if name not in archive.namelist():
                raise RunFileError(f"{model_path}: the model zip has no '{name}' entry (not an SB3 model?)")
            return archive.read(name)
    except zipfile.BadZipFile as error:
        raise RunFileError(f"{model_path}: not a valid zip archive (truncated or corrupted): {error}") from None
    except (OSError, EOFError, zipfile.LargeZipFile) as error:
        raise RunFileError(f"{model_path}: cannot read the '{name}' entry (truncated or corrupted): {error}") from None


def _plain_field(data: dict[str, Any], key: str, model_path: Path) -> Any:
    """A field of SB3's JSON: plain JSON as is; a serialized object as the literals of its repr'd attributes."""
    value = data.get(key)
    if not (isinstance(value, dict) and ":serialized:" in value):
        return value
    result = {}
    for name, text in value.items():
        if name.startswith(":"):
            continue
        result[name] = _literal_or_class(text, f"{model_path}: {key}.{name}")
    return result


_CLASS_REPR = re.compile(r"^<class '([\w.]+)'>$")


def _known_classes() -> dict[str, type]:
    from stable_baselines3.common import torch_layers

    from sb3_trpo_plus.application.zoo import ACTIVATIONS

    classes: list[type] = [*ACTIVATIONS.values(), th.nn.Identity]
    classes += [torch_layers.FlattenExtractor, torch_layers.NatureCNN, torch_layers.CombinedExtractor]
    classes += [th.optim.Adam, th.optim.AdamW, th.optim.SGD, th.optim.RMSprop]
    return {f"{cls.__module__}.{cls.__qualname__}": cls for cls in classes}


def _literal_or_class(text: Any, where: str) -> Any:
    if not isinstance(text, str):
        return text
    match = _CLASS_REPR.match(text)
    if match:
        known = _known_classes()
        if match.group(1) not in known:
            raise RunFileError(f"{where}: the class {match.group(1)} cannot be rebuilt from data; load with trust_pickle=True")
        return known[match.group(1)]
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        raise RunFileError(f"{where}: {text[:80]!r} cannot be rebuilt from data; load with trust_pickle=True") from None


def _policy_class(algo: str, data: dict[str, Any], config: dict[str, Any], model_path: Path) -> type[BasePolicy]:
    """The policy class: by its qualified name in the zip (plain fields), else the config's alias; never imported by name."""
    from sb3_trpo_plus.application.zoo import algorithms

    algos = algorithms()
    if algo not in algos:
        raise RunFileError(f"{model_path}: the weights-only path knows the algorithms {sorted(algos)}, not {algo!r}")
    aliases: dict[str, type[BasePolicy]] = algos[algo].policy_aliases
    by_name = {f"{cls.__module__}.{cls.__qualname__}": cls for cls in aliases.values()}
    fields = data.get("policy_class")
    if isinstance(fields, dict):
        module = fields.get("__module__")
        names = {m.group(1) for v in fields.values() if isinstance(v, str) for m in [re.match(r"<function (\w+)\.", v)] if m}
        found = [by_name[f"{module}.{name}"] for name in names if f"{module}.{name}" in by_name]
        if len(found) == 1:
            return found[0]
    alias = config.get("policy")
    if isinstance(alias, str) and alias in aliases:
        return aliases[alias]
    raise RunFileError(
        f"{model_path}: cannot tell the policy class from the model's plain fields or the config's policy "
        f"{alias!r} (known: {sorted(aliases)}); load with trust_pickle=True"
    )


def load_policy(
    model_path: str | Path,
    observation_space: spaces.Space,
    action_space: spaces.Space,
    algo: str = "trpo_plus",
    config: dict[str, Any] | None = None,
    device: th.device | str = "cpu",
) -> BasePolicy:
    """Rebuild a model zip's policy from plain data and load its weights with ``torch.load(weights_only=True)``.

    :param model_path: an SB3 model zip
    :param observation_space: the env's observation space (as the policy sees it, after wrappers)
    :param action_space: the env's action space
    :param algo: ``trpo_plus``, ``trpo`` or ``ppo``: where the policy alias is looked up
    :param config: the run's hyperparameters (``policy`` alias and ``policy_kwargs``), used where the zip's plain
        fields do not say
    :param device: where the policy lives
    """
    model_path = Path(model_path)
    config = config or {}
    data = read_model_data(model_path)
    policy_class = _policy_class(algo, data, config, model_path)
    policy_kwargs = _plain_field(data, "policy_kwargs", model_path)
    if policy_kwargs is None:
        policy_kwargs = config.get("policy_kwargs") or {}
    if not isinstance(policy_kwargs, dict):
        raise RunFileError(f"{model_path}: policy_kwargs is not a mapping: {policy_kwargs!r}")
    use_sde = bool(data.get("use_sde", False))
    try:
        policy = policy_class(observation_space, action_space, lambda _: 0.0, use_sde=use_sde, **policy_kwargs)
    except (TypeError, ValueError) as error:
        raise RunFileError(f"{model_path}: cannot rebuild {policy_class.__name__} with {policy_kwargs}: {error}") from None
    raw = _read_zip_member(model_path, "policy.pth")
    try:
        state_dict = th.load(io.BytesIO(raw), map_location=device, weights_only=True)
    except Exception as error:  # torch raises several types for a damaged or refused file
        raise RunFileError(f"{model_path}: policy.pth cannot be read as plain weights: {error}") from None
    try:
        policy.load_state_dict(state_dict)
    except (RuntimeError, TypeError, AttributeError) as error:
        raise RunFileError(f"{model_path}: policy.pth does not fit {policy_class.__name__}: {error}") from None
    policy.to(device)
    policy.set_training_mode(False)
    return policy


# ---------------------------------------------------------------------------------------------- environments
def _wrapper_class(hyperparams: dict[str, Any], key: str, where: Path) -> Callable | None:
    """rl-zoo3's ``env_wrapper`` / ``vec_env_wrapper`` of a run, each name checked to be a wrapper class of a known
    package (:func:`sb3_trpo_plus.application.zoo.check_wrappers`), the training aids left out (evaluation envs never
    get them)."""
    from rl_zoo3.utils import get_wrapper_class

    from sb3_trpo_plus.application.zoo import HyperparameterError, check_wrappers, evaluation_wrappers

    value = hyperparams.get(key)
    if value is None:
        return None
    try:
        checked = check_wrappers(value, f"{where}: {key}", base=key)
    except HyperparameterError as error:
        raise RunFileError(f"{error} (refused)") from None
    return get_wrapper_class({key: evaluation_wrappers(checked) if key == "env_wrapper" else checked}, key)


def make_eval_env(
    config: RunConfig,
    normalization: NormalizationStats | VecNormalize | None = None,
    n_envs: int = 1,
    seed: int = 0,
    render_mode: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    norm_reward: bool = False,
) -> VecEnv:
    """The run's test env, as rl-zoo3's ``create_test_env`` makes it, without unpickling anything: the evaluation env
    (:func:`sb3_trpo_plus.application.evaluation.evaluation_env`) of the run's env id, ``env_kwargs`` (updated by
    ``env_kwargs``), env wrappers without training aids, VecEnv wrapper and frame stacking, with the VecNormalize
    statistics frozen (``normalization``: read by :func:`load_normalization`, or a VecNormalize unpickled by the
    trusted path).
    """
    from sb3_trpo_plus.application.evaluation import evaluation_env

    where = config.stats_dir / "config.yml"
    if config.normalize_kwargs is not None and normalization is None:
        raise RunFileError(f"{config.stats_dir}: the run normalises observations but has no vecnormalize.pkl")
    try:
        return evaluation_env(
            config.env_id,
            {**config.env_kwargs, **(env_kwargs or {})},
            normalization if config.normalize_kwargs is not None else None,
            seed,
            _wrapper_class(config.hyperparams, "env_wrapper", where),
            n_envs=n_envs,
            render_mode=render_mode,
            vec_env_wrapper=_wrapper_class(config.hyperparams, "vec_env_wrapper", where),
            frame_stack=config.hyperparams.get("frame_stack"),
            norm_reward=norm_reward,
        )
    except StatisticsMismatchError as error:
        raise RunFileError(f"{config.stats_dir}: {error}") from None


def load_agent(
    run_folder: str | Path,
    env_id: str | None = None,
    *,
    model_path: str | Path | None = None,
    trust_pickle: bool = False,
    device: th.device | str = "cpu",
) -> tuple[Any, NormalizationStats | VecNormalize | None, dict[str, Any]]:
    """Load a trained agent of an rl-zoo3 run folder (``<logs>/<algo>/<ENV>_<n>``).

    :param run_folder: the run folder; its parent's name is the algorithm (``trpo_plus``, ``trpo``, ``ppo``)
    :param env_id: the env id (default: the folder name without ``_<n>``)
    :param model_path: the model zip (default: ``<run>/<ENV>.zip``; e.g. ``best_model.zip`` or a checkpoint)
    :param trust_pickle: load with SB3's ``load`` and ``VecNormalize.load`` (unpickles the files: only for runs
        you trust; gives the full algorithm, e.g. to continue training). Default: the weights-only path.
    :param device: where the policy lives
    :return: ``(policy_or_model, statistics, env_kwargs)``: a policy (weights-only) or the algorithm (trusted), both
        with ``predict``; :class:`NormalizationStats` (weights-only) or a ``VecNormalize`` (trusted, without a
        venv: call ``set_venv``) or None; the env kwargs the run was trained with. The YAML files are always
        read safely, so a run whose YAML carries code is refused either way.
    """
    run_folder = Path(run_folder)
    config = read_run_config(run_folder, env_id)
    model_path = Path(model_path) if model_path is not None else run_folder / f"{_env_folder_name(config.env_id)}.zip"
    stats_path = config.stats_dir / "vecnormalize.pkl"
    has_stats = config.normalize_kwargs is not None and stats_path.is_file()
    if trust_pickle:
        from sb3_trpo_plus.application.zoo import algorithms

        model = load_trusted_file(
            lambda: algorithms()[config.algo].load(
                model_path, device=device, custom_objects={"learning_rate": 0.0, "lr_schedule": lambda _: 0.0}
            ),
            model_path,
        )
        vec_normalize = load_trusted_file(lambda: _load_vec_normalize_unbound(stats_path), stats_path) if has_stats else None
        return model, vec_normalize, config.env_kwargs
    normalization = load_normalization(stats_path) if has_stats else None
    probe = make_eval_env(config, normalization)
    try:
        policy = load_policy(model_path, probe.observation_space, probe.action_space, config.algo, config.hyperparams, device)
    finally:
        probe.close()
    return policy, normalization, config.env_kwargs


def load_trusted_file(load: Callable[[], T], path: str | Path) -> T:
    """``load()``, which unpickles ``path`` (a file the user trusts); any failure is a :class:`RunFileError` naming
    the file. Unpickling damaged bytes runs whatever classes and arguments they spell, so any exception may come."""
    try:
        return load()
    except RunFileError:
        raise
    except Exception as error:
        if str(error).startswith(f"{path}: "):  # already names the file (TRPOPlus.load does)
            raise RunFileError(str(error)) from error
        raise RunFileError(f"{path}: cannot be loaded (truncated or corrupted?): {type(error).__name__}: {error}") from error


def _load_vec_normalize_unbound(path: Path) -> VecNormalize:
    with path.open("rb") as file:
        vec_normalize = pickle.load(file)  # trust_pickle=True: the user trusts this run
    if not isinstance(vec_normalize, VecNormalize):
        raise RunFileError(f"{path}: does not hold a VecNormalize")
    return vec_normalize


def load_eval_agent(
    run_folder: str | Path,
    env_id: str | None = None,
    *,
    model_path: str | Path | None = None,
    trust_pickle: bool = False,
    seed: int = 0,
    n_envs: int = 1,
    render_mode: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    norm_reward: bool = False,
    device: th.device | str = "cpu",
) -> tuple[Any, VecEnv]:
    """A run's agent and its test env (VecNormalize statistics frozen, raw rewards), ready for ``predict`` / ``step``."""
    config = read_run_config(run_folder, env_id)
    agent, statistics, _ = load_agent(run_folder, env_id, model_path=model_path, trust_pickle=trust_pickle, device=device)
    return agent, make_eval_env(config, statistics, n_envs, seed, render_mode, env_kwargs, norm_reward)
