"""A study variant's envs and model on an env: what the runner, the protocol and the diagnostic scripts build.

Training envs: the variant's env kwargs, wrapped in its training wrappers (``study.train_wrappers``: the variant's
``train_wrappers``, else the zoo entry's ``env_wrapper``), VecNormalize where the zoo settings ask for it. Evaluation
envs: the same env kwargs and never the training wrappers. Model: the variant's class and zoo settings; a
``zero_cg_start`` variant's sb3-contrib TRPO starts its conjugate gradient at 0 (``zero_start_solver``).
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from benchmarks.study import VARIANTS, ModelSettings, Variant, settings, train_wrappers

if TYPE_CHECKING:
    import torch as th


def model_settings(env_id: str, variant: str) -> ModelSettings:
    """The zoo settings of ``variant`` on ``env_id`` (study.yml's overrides on top)."""
    return settings(VARIANTS[variant], env_id)


def train_wrapper_class(env_id: str, variant: str) -> Callable[[Any], Any] | None:
    """One callable that wraps a training env of ``env_id`` in the variant's training wrappers (``study.train_wrappers``),
    in their order (rl-zoo's ``get_wrapper_class`` of an ``env_wrapper`` list); None without any."""
    wrappers = train_wrappers(VARIANTS[variant], env_id)
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
        n_envs=config.n_envs,
        seed=seed,
        env_kwargs=config.env_kwargs,
        wrapper_class=train_wrapper_class(env_id, variant),
        monitor_kwargs=monitor_kwargs,
    )
    if vec_env == "batch":
        from sb3_trpo_plus.application.zoo import batch_training_env

        return batch_training_env(env_id, n_threads=1, **kwargs)
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
    ``normalization`` (a vecnormalize.pkl path, or the training VecNormalize: ``sb3_trpo_plus.application.evaluation``'s forms)
    a VecNormalize with the run's settings that neither updates the statistics nor scales rewards."""
    import grasp_envs  # noqa: F401
    from sb3_trpo_plus.application.evaluation import evaluation_env as make_evaluation_env

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
    from sb3_trpo_plus.application.zoo import algorithms

    return algorithms()[variant.algo]


def zero_start_solver(
    matrix_vector_dot_fn: Callable[[th.Tensor], th.Tensor], b: th.Tensor, max_iter: int = 10, residual_tol: float = 1e-10
) -> th.Tensor:
    """sb3-contrib's conjugate gradient solver started at 0 instead of 1e-4 * randn (no draw from torch's generator)."""
    import torch as th
    from sb3_contrib.common.utils import conjugate_gradient_solver

    randn_like = th.randn_like
    th.randn_like = th.zeros_like  # type: ignore[assignment]
    try:
        return conjugate_gradient_solver(matrix_vector_dot_fn, b, max_iter=max_iter, residual_tol=residual_tol)
    finally:
        th.randn_like = randn_like


def use_zero_start_in_sb3_contrib_trpo() -> None:
    """Make sb3-contrib's TRPO (in this process) start its conjugate gradient at 0 (variants with ``zero_cg_start``)."""
    import sb3_contrib.trpo.trpo as sb3_contrib_trpo

    sb3_contrib_trpo.conjugate_gradient_solver = zero_start_solver


def add_run_arguments(parser: argparse.ArgumentParser, env_id: str, variant: str) -> None:
    """``--env``, ``--variant`` and ``--seed``: the study run a diagnostic script looks at."""
    parser.add_argument("--env", default=env_id)
    parser.add_argument("--variant", default=variant, choices=list(VARIANTS))
    parser.add_argument("--seed", type=int, default=0)
