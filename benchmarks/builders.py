"""A study variant's envs and model on an env: what the runner, the protocol and the diagnostic scripts build.

Training envs: the variant's env kwargs, wrapped in its ``train_wrappers`` (rl-zoo's env_wrapper form), VecNormalize
where the zoo settings ask for it. Evaluation envs: the same env kwargs and never the training wrappers.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from typing import Any

from benchmarks.study import VARIANTS, ModelSettings, Variant, settings


def model_settings(env_id: str, variant: str) -> ModelSettings:
    """The zoo settings of ``variant`` on ``env_id`` (study.yml's overrides on top)."""
    return settings(VARIANTS[variant], env_id)


def train_wrapper_class(variant: str) -> Callable[[Any], Any] | None:
    """One callable that wraps a training env in the variant's ``train_wrappers``, in their order (rl-zoo's
    ``get_wrapper_class`` of an ``env_wrapper`` list); None without any."""
    wrappers = VARIANTS[variant].train_wrappers
    if not wrappers:
        return None
    from rl_zoo3.utils import get_wrapper_class

    return get_wrapper_class({"env_wrapper": wrappers})


def training_envs(
    env_id: str, variant: str, seed: int, monitor_kwargs: dict[str, Any] | None = None, vec_env: str = "dummy"
) -> Any:
    """New training envs of ``variant`` (monitored, wrapped in its training wrappers) seeded with ``seed``, without
    VecNormalize: the runner adds or loads it. ``vec_env="batch"``: the batched engine (``grasp_envs.make_batch_env``,
    one physics thread), whose transitions are DummyVecEnv's."""
    from stable_baselines3.common.env_util import make_vec_env

    import grasp_envs  # noqa: F401  (registers the envs)

    config = model_settings(env_id, variant)
    kwargs: dict[str, Any] = dict(
        n_envs=config.n_envs, seed=seed, env_kwargs=config.env_kwargs, wrapper_class=train_wrapper_class(variant),
        monitor_kwargs=monitor_kwargs,
    )  # fmt: skip
    if vec_env == "batch":
        from sb3_trpo_plus.zoo import batch_training_env

        return batch_training_env(env_id, None, n_threads=1, **kwargs)
    if vec_env != "dummy":
        raise ValueError(f"vec_env must be 'dummy' or 'batch', got {vec_env!r}")
    return make_vec_env(env_id, **kwargs)


def normalized_training_envs(env_id: str, variant: str, seed: int) -> Any:
    """``training_envs`` with a new VecNormalize where the zoo settings ask for it (the diagnostic scripts' envs)."""
    from stable_baselines3.common.vec_env import VecNormalize

    config = model_settings(env_id, variant)
    env = training_envs(env_id, variant, seed)
    return VecNormalize(env, **config.normalize_kwargs) if config.normalize_kwargs is not None else env


def evaluation_env(env_id: str, variant: str, seed: int, normalization: Any = None) -> Any:
    """One monitored evaluation env of ``variant`` seeded with ``seed``: its env kwargs, no training wrappers; with
    ``normalization`` (a vecnormalize.pkl path, or the training VecNormalize: ``sb3_trpo_plus.evaluation``'s forms)
    a VecNormalize with the run's settings that neither updates the statistics nor scales rewards."""
    import grasp_envs  # noqa: F401
    from sb3_trpo_plus.evaluation import evaluation_env as make_evaluation_env

    return make_evaluation_env(env_id, model_settings(env_id, variant).env_kwargs, normalization, seed)


def new_model(env_id: str, variant: str, seed: int, env: Any = None) -> Any:
    """A new model of ``variant`` on ``env``, or on ``normalized_training_envs``."""
    config = model_settings(env_id, variant)
    env = normalized_training_envs(env_id, variant, seed) if env is None else env
    return algorithm_class(variant)(config.policy, env, seed=seed, device="cpu", **config.kwargs)


def algorithm_class(variant: str) -> Any:
    """The class that trains ``variant``: its ``algo_class`` where it names one, else its zoo algorithm's."""
    return _algorithm_class(VARIANTS[variant])


def _algorithm_class(variant: Variant) -> Any:
    if variant.algo_class is not None:
        module, _, name = variant.algo_class.rpartition(".")
        return getattr(importlib.import_module(module), name)
    from sb3_trpo_plus.zoo import algorithms

    return algorithms()[variant.algo]


def add_run_arguments(parser: argparse.ArgumentParser, env_id: str, variant: str) -> None:
    """``--env``, ``--variant`` and ``--seed``: the study run a diagnostic script looks at."""
    parser.add_argument("--env", default=env_id)
    parser.add_argument("--variant", default=variant, choices=list(VARIANTS))
    parser.add_argument("--seed", type=int, default=0)
