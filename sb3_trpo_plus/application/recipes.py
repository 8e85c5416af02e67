"""The rl-zoo YAML recipes in Python: the model that ``trpo-plus train --env ID --algo ALGO`` would train.

>>> from sb3_trpo_plus import make_model
>>> model = make_model("Grasper3D-v7", seed=0)  # doctest: +SKIP
>>> model.learn(2_000_000)                      # doctest: +SKIP

TRPOPlus with 64 envs under VecNormalize in one rollout worker process, scripted training starts; the recipe
collects while the learner updates, so a script guards its entry point with ``if __name__ == "__main__":``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from sb3_trpo_plus.application.zoo import (
    ALGO_FILES,
    ZOO_DIR,
    HyperparameterError,
    Recipe,
    algorithms,
    check_wrappers,
    load_recipes,
    parse_policy_kwargs,
)

if TYPE_CHECKING:
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm


def recipe(env_id: str, algo: str = "trpo_plus") -> Recipe:
    """The checked recipe of ``env_id`` in ``zoo_hyperparams/<algo>.yml``: a :class:`Recipe` record, which reads as
    the YAML entry too (``recipe(env_id)["n_timesteps"]``)."""
    if algo not in ALGO_FILES:
        raise ValueError(f"algo must be one of {sorted(ALGO_FILES)}, got {algo!r}")
    recipes = load_recipes(ZOO_DIR / ALGO_FILES[algo], algo)
    if env_id not in recipes:
        raise HyperparameterError(f"{ZOO_DIR / ALGO_FILES[algo]} has no recipe for {env_id!r} (it has {sorted(recipes)})")
    return recipes[env_id]


def make_model(
    env_id: str,
    algo: str = "trpo_plus",
    seed: int | None = None,
    *,
    vec_env: str = "auto",
    sim_threads: int = 1,
    workers: str | None = None,
    **overrides: Any,
) -> OnPolicyAlgorithm:
    """The model of ``env_id``'s recipe, as ``trpo-plus train`` builds it: ``n_envs`` seeded envs with the recipe's
    ``env_kwargs`` and ``env_wrapper`` (training aids included: these are training envs), Monitor with the success
    flag, ``VecNormalize`` with the algorithm's discount where the recipe normalises, and the algorithm with the
    recipe's hyperparameters (``lin_<x>`` schedules as linear schedules from ``x``).

    The envs: ``vec_env="auto"`` (the default) steps the tasks of ``grasp_envs`` on the batched engine
    (``grasp_envs.make_batch_env``, physics on ``sim_threads`` threads: the transitions of ``DummyVecEnv``, faster)
    and any other id in SB3's ``DummyVecEnv``; ``"batch"`` or ``"dummy"`` choose one. ``workers="BACKEND:N"``
    (``inprocess``, ``process`` or ``ray``, as ``trpo-plus train --workers``) collects with ``N`` rollout workers
    instead (``sb3_trpo_plus.rollouts``), the recipe's ``n_envs`` split over them, each worker's physics on
    ``sim_threads`` threads. A recipe with ``rollout_workers: BACKEND:N`` collects so unless ``workers`` says
    otherwise (Grasper3D-v7's recipe: one worker process collecting the next segment while the learner updates,
    ``overlap_collection``; a script that trains it guards its entry point with ``if __name__ == "__main__":``, as
    for SB3's ``SubprocVecEnv``); such a recipe on one process' envs is ``rollout_workers=None,
    overlap_collection=False`` with ``vec_env``.

    ``overrides`` replace any key of the recipe, run keys (``n_envs``, ``env_kwargs``, ``normalize``, ...) and
    constructor arguments alike (e.g. ``tensorboard_log="runs"``). Train for the recipe's budget with
    ``model.learn(recipe(env_id, algo)["n_timesteps"])``; the command also logs each reward term
    (``sb3_trpo_plus.application.callbacks.RewardTermsCallback``, pass it to ``learn`` to do the same).
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    from sb3_trpo_plus.rollouts.engines import batch_engine_ids, batch_envs, has_batch_engine

    if vec_env not in ("auto", "batch", "dummy"):
        raise ValueError(f"vec_env must be 'auto', 'batch' or 'dummy', got {vec_env!r}")
    if vec_env == "batch" and not has_batch_engine(env_id):
        raise ValueError(f"vec_env='batch' runs the tasks of grasp_envs ({', '.join(batch_engine_ids())}), got {env_id!r}")
    chosen = recipe(env_id, algo)
    if "policy_kwargs" in overrides:  # as the YAML's: checked keys, activation names ("tanh") as classes
        overrides = {**overrides, "policy_kwargs": parse_policy_kwargs(overrides["policy_kwargs"], f"make_model({env_id!r})")}
    chosen = chosen.replace(**overrides)
    if workers is None and chosen.rollout_workers is not None:
        if vec_env != "auto":
            raise ValueError(
                f"the recipe of {env_id} collects with rollout workers (rollout_workers={chosen.rollout_workers!r}); "
                f"vec_env={vec_env!r} needs rollout_workers=None and overlap_collection=False"
            )
        workers = chosen.rollout_workers
    env: Any
    if workers is not None:
        env = _rollout_workers(chosen, workers, seed, sim_threads, vec_env)
    elif vec_env == "batch" or (vec_env == "auto" and has_batch_engine(env_id)):
        env = batch_envs(
            env_id,
            chosen.n_envs,
            seed=seed,
            n_threads=sim_threads,
            env_kwargs=chosen.env_kwargs,
            scripted_starts=chosen.scripted_starts,
            info_keywords=chosen.info_keywords or (),
        )
    else:
        env = make_vec_env(
            env_id,
            n_envs=chosen.n_envs,
            seed=seed,
            env_kwargs=chosen.env_kwargs,
            wrapper_class=_wrapper_chain(chosen.env_wrapper, "env_wrapper"),
            monitor_kwargs=chosen.monitor_kwargs,
        )
    vec_wrapper = _wrapper_chain(chosen.vec_env_wrapper, "vec_env_wrapper")
    if vec_wrapper is not None:
        env = vec_wrapper(env)
    constructor = chosen.constructor_arguments()
    if chosen.normalize:
        kwargs = dict(chosen.normalize) if isinstance(chosen.normalize, dict) else {}
        if "gamma" in constructor:
            kwargs["gamma"] = constructor["gamma"]  # as rl-zoo3: the returns are normalised with the agent's discount
        env = VecNormalize(env, **kwargs)
    if chosen.frame_stack:
        env = VecFrameStack(env, int(chosen.frame_stack))
    return algorithms()[algo](chosen.policy, env, seed=seed, **constructor)


def _rollout_workers(chosen: Recipe, workers: str, seed: int | None, sim_threads: int, vec_env: str) -> Any:
    """The recipe's training envs as a pool of rollout workers (``workers="BACKEND:N"``)."""
    from sb3_trpo_plus import rollouts
    from sb3_trpo_plus.application.zoo import parse_workers

    try:
        backend, count = parse_workers(workers)
    except ValueError as error:
        raise ValueError(f"workers: {error}") from None
    if chosen.algo != "trpo_plus":
        raise ValueError(f"workers collect whole segments for algo='trpo_plus' only, got algo={chosen.algo!r}")
    if vec_env != "auto":
        raise ValueError(f"workers collect with their own envs; vec_env={vec_env!r} does not apply")
    return rollouts.split_pool(
        backend,
        chosen.env_id,
        chosen.n_envs,
        count,
        seed=seed,
        sim_threads=sim_threads,
        env_kwargs=chosen.env_kwargs,
        scripted_starts=chosen.scripted_starts,
        info_keywords=chosen.info_keywords,
    )


def _wrapper_chain(value: Any, key: str) -> Callable[[Any], Any] | None:
    """rl-zoo's ``env_wrapper`` / ``vec_env_wrapper`` list as one callable, each name checked
    (:func:`sb3_trpo_plus.application.zoo.check_wrappers`) before it is imported (rl-zoo3 need not be installed)."""
    if value is None:
        return None
    wrappers = []
    for entry in check_wrappers(value, key, base=key):
        name, kwargs = next(iter(entry.items())) if isinstance(entry, dict) else (entry, {})
        module_name, _, class_name = name.rpartition(".")
        wrappers.append((getattr(importlib.import_module(module_name), class_name), kwargs))

    def wrap(env: Any) -> Any:
        for wrapper, kwargs in wrappers:
            env = wrapper(env, **kwargs)
        return env

    return wrap
