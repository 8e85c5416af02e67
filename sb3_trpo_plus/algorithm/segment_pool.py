"""What :class:`~sb3_trpo_plus.TRPOPlus` collects from when rollout workers step its envs: a :class:`SegmentPool` (a
VecEnv whose workers collect whole segments; :class:`sb3_trpo_plus.rollouts.RolloutWorkers` implements it), found under
at most one ``VecNormalize`` (:func:`rollout_workers`), and its segment handed to SB3 step by step.

The learner receives a whole segment at once; SB3's ``collect_rollouts`` would have seen it one step at a time.
:func:`step_through_segment` replays those steps for what watches them: the ``VecNormalize`` statistics see every raw
observation and reward, a step hook (the learner's callback) sees SB3's locals, and the pool records the episodes that
ended.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper, VecNormalize

from sb3_trpo_plus.algorithm.normalization import NormalizationStats
from sb3_trpo_plus.algorithm.segment import Segment
from sb3_trpo_plus.common.arguments import Rule, check_arguments


class SegmentPool(VecEnv):
    """A VecEnv of ``num_workers * envs_per_worker`` envs stepped by workers that each collect whole segments with a
    copy of the policy. :class:`~sb3_trpo_plus.TRPOPlus` orders segments from it instead of stepping its envs;
    stepped one step at a time it is an ordinary VecEnv. The rollout workers of :mod:`sb3_trpo_plus.rollouts` are the
    implementation; the algorithm needs only this face of them."""

    num_workers: int
    envs_per_worker: int
    restarts: list[int]
    """How often each worker was restarted."""
    last_timings: dict[str, Any]
    """The last collection's seconds: ``worker_s`` (per worker), ``broadcast_s``, ``transfer_s``, ``wait_s``,
    ``collect_s``."""

    @abc.abstractmethod
    def collect_segments(
        self, policy: ActorCriticPolicy, n_steps: int, gamma: float, normalizer: NormalizationStats | None
    ) -> list[Segment]:
        """One segment of ``n_steps`` from every worker, in worker order."""

    @abc.abstractmethod
    def submit_segments(
        self, policy: ActorCriticPolicy, n_steps: int, gamma: float, normalizer: NormalizationStats | None
    ) -> None:
        """Order one segment of ``n_steps`` from every worker and return at once (:meth:`gather_segments` returns
        them)."""

    @abc.abstractmethod
    def gather_segments(self) -> list[Segment]:
        """The segments :meth:`submit_segments` ordered, in worker order."""

    @property
    @abc.abstractmethod
    def collecting(self) -> bool:
        """Whether segments were ordered and not gathered yet."""

    @abc.abstractmethod
    def record_episodes(self, ended: Sequence[tuple[int, dict[str, Any]]]) -> None:
        """Record the episodes that ended at one step (``(env index, info)`` pairs)."""


POOL_LOOKUP_RULES: dict[str, Rule] = {"env": Rule(lambda value: isinstance(value, VecEnv), "a VecEnv")}
"""The argument of :func:`rollout_workers` and :func:`buried_rollout_workers`."""


def buried_rollout_workers(env: VecEnv) -> bool:
    """Whether a :class:`SegmentPool` lies under ``env``'s wrappers where :func:`rollout_workers` does not find it
    (under wrappers other than one ``VecNormalize``)."""
    check_arguments("buried_rollout_workers", POOL_LOOKUP_RULES, {"env": env})
    while isinstance(env, VecEnvWrapper):
        env = env.venv
    return isinstance(env, SegmentPool)


def rollout_workers(env: VecEnv) -> tuple[SegmentPool, VecNormalize | None] | None:
    """``(pool, vec_normalize)`` when ``env`` is a :class:`SegmentPool`, bare or under one ``VecNormalize``."""
    check_arguments("rollout_workers", POOL_LOOKUP_RULES, {"env": env})
    if isinstance(env, SegmentPool):
        return env, None
    if isinstance(env, VecNormalize) and isinstance(env.venv, SegmentPool):
        return env.venv, env
    return None


# a step's SB3 locals (``new_obs``, ``rewards``, ``dones``, ``infos``, ``actions``, ``values``, ``log_probs``,
# ``n_steps``), its infos and its dones -> whether to go on (False: the callback stopped training)
StepHook = Callable[[dict[str, Any], list[dict[str, Any]], np.ndarray], bool]


def step_through_segment(segment: Segment, pool: SegmentPool, vec_normalize: VecNormalize | None, on_step: StepHook) -> bool:
    """Step by step, as SB3's ``collect_rollouts`` would have: the ``VecNormalize`` statistics see the raw
    observations and rewards (and the reset of the envs the workers restarted), ``on_step`` sees SB3's locals
    (``infos`` hold the dicts of the episodes that ended, their terminal observations normalised as ``VecNormalize``
    gives them, and ``{}`` for the others), and the pool records the episodes that ended.

    :return: False if ``on_step`` stopped it (the steps after that are not replayed)
    """
    normalizer = NormalizationStats.of(vec_normalize)
    n_envs, n_steps = pool.num_envs, segment.n_steps
    raw_observations, observations = segment.raw_observations, segment.observations
    assert isinstance(raw_observations, np.ndarray) and isinstance(observations, np.ndarray)
    restarted = segment.restarted if segment.restarted is not None else np.zeros(n_envs, dtype=bool)
    if vec_normalize is not None and restarted.any():  # what VecNormalize.reset does for the reset envs
        if vec_normalize.training and vec_normalize.norm_obs:
            vec_normalize.obs_rms.update(raw_observations[0][restarted])
        vec_normalize.returns[restarted] = 0
    for t in range(n_steps):
        dones = segment.dones[t]
        infos: list[dict[str, Any]] = [{} for _ in range(n_envs)]
        for idx, info in segment.ended[t]:
            terminal = info.get("terminal_observation")
            if normalizer is not None and terminal is not None:  # as VecNormalize gives it to SB3
                info = {**info, "terminal_observation": normalizer.normalize_obs(terminal)}
            infos[idx] = info
        if vec_normalize is not None:
            update_statistics(vec_normalize, raw_observations[t + 1], segment.raw_rewards[t], dones)
        step_locals = {
            "new_obs": observations[t + 1] if t + 1 < n_steps else segment.last_observation,
            "rewards": segment.rewards[t],
            "dones": dones,
            "infos": infos,
            "actions": segment.actions[t],
            "values": th.as_tensor(segment.values[t]),
            "log_probs": th.as_tensor(segment.log_probs[t]),
            "n_steps": t,
        }
        if not on_step(step_locals, infos, dones):
            return False
        pool.record_episodes(segment.ended[t])
    return True


def update_statistics(vec_normalize: VecNormalize, raw_obs: np.ndarray, raw_rewards: np.ndarray, dones: np.ndarray) -> None:
    """What ``VecNormalize.step_wait`` does to its statistics for one step of raw observations and rewards."""
    vec_normalize.old_obs, vec_normalize.old_reward = raw_obs, raw_rewards
    if vec_normalize.training:
        if vec_normalize.norm_obs:
            vec_normalize.obs_rms.update(raw_obs)
        vec_normalize._update_reward(raw_rewards)
    vec_normalize.returns[dones] = 0


def record_worker_timings(record: Callable[..., None], pool: SegmentPool, n_steps: int) -> None:
    """Per-worker throughput, weight broadcast, segment transfer, the learner's wait and the restarts of the last
    collection, under ``workers/``."""
    timings = pool.last_timings
    for worker, seconds in enumerate(timings["worker_s"]):
        record(f"workers/worker_{worker}_steps_per_s", n_steps * pool.envs_per_worker / max(seconds, 1e-9))
    record("workers/broadcast_ms", 1e3 * timings["broadcast_s"])
    record("workers/transfer_ms", 1e3 * timings["transfer_s"])
    record("workers/wait_ms", 1e3 * timings["wait_s"])
    record("workers/collect_steps_per_s", n_steps * pool.num_envs / max(timings["collect_s"], 1e-9))
    record("workers/restarts", sum(pool.restarts))
