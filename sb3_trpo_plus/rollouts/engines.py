"""The batched engine (``grasp_envs.make_batch_env``) as ``sb3_trpo_plus`` builds training envs on it: which env ids
have one, and their envs with the recipe's seeds, options, scripted starts and episode records.

The one module of ``sb3_trpo_plus`` that builds ``grasp_envs``' envs: ``make_model``, ``trpo-plus train`` and the
rollout workers call it; the algorithm never does.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from stable_baselines3.common.vec_env import VecEnv


def has_batch_engine(env_id: str) -> bool:
    """Whether ``env_id`` is a task of ``grasp_envs``, which the batched engine steps."""
    import grasp_envs

    return grasp_envs.has_batch_engine(env_id)


def batch_engine_ids() -> tuple[str, ...]:
    """The env ids the batched engine steps (``grasp_envs.ENV_IDS``), for error messages that list them."""
    import grasp_envs

    return tuple(grasp_envs.ENV_IDS)


def scripted_starts_options(wrapper_class: Any, flag: str) -> dict[str, Any] | None:
    """The ``ScriptedStarts`` options in rl-zoo3's ``env_wrapper`` (a class, or the function that applies a YAML list
    of them), None without one; any other wrapper raises ``TypeError`` naming it and ``flag``."""
    import inspect

    from grasp_envs.wrappers import ScriptedStarts

    wrappers: list[tuple[Any, dict[str, Any]]] = []
    if isinstance(wrapper_class, type):
        wrappers = [(wrapper_class, {})]
    elif wrapper_class is not None:  # rl_zoo3.utils.get_wrapper_class's wrap_env(env)
        cells = inspect.getclosurevars(wrapper_class).nonlocals
        wrappers = list(zip(cells.get("wrapper_classes", []), cells.get("wrapper_kwargs", []), strict=True))
        if not wrappers:
            raise TypeError(f"{flag} cannot read the env_wrapper {wrapper_class!r}")
    others = [getattr(cls, "__name__", str(cls)) for cls, _ in wrappers if cls is not ScriptedStarts]
    if others or len(wrappers) > 1:
        raise TypeError(
            f"{flag} runs no per-env Gymnasium wrappers but ScriptedStarts (once); the env_wrapper has "
            f"{', '.join(others) or 'ScriptedStarts twice'}: use --vec-env dummy"
        )
    return dict(wrappers[0][1]) if wrappers else None


def batch_envs(
    env_id: str,
    n_envs: int,
    *,
    seed: int | None = None,
    n_threads: int = 1,
    env_kwargs: dict[str, Any] | None = None,
    scripted_starts: dict[str, Any] | None = None,
    info_keywords: Sequence[str] = ("is_success",),
    monitor_file: str | os.PathLike[str] | None = None,
) -> VecEnv:
    """``n_envs`` monitored simulations of ``env_id`` on the batched engine (env ``i`` seeded ``seed + i``), physics on
    ``n_threads`` threads, with ``env_kwargs`` and, for training, ``grasp_envs.wrappers.ScriptedStarts`` with the
    options ``scripted_starts`` (None: none)."""
    from grasp_envs import make_batch_env
    from grasp_envs.wrappers import ScriptedStarts

    return make_batch_env(
        env_id,
        n_envs,
        seed=seed,
        n_threads=n_threads,
        monitor=True,
        monitor_file=monitor_file,
        info_keywords=tuple(info_keywords),
        wrapper_class=ScriptedStarts if scripted_starts is not None else None,
        wrapper_kwargs=scripted_starts,
        **(env_kwargs or {}),
    )
