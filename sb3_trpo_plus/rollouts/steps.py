"""A segment collected by rollout workers, handed to SB3 step by step, and the pool's timings in the logger.

The learner receives a whole segment at once; SB3's ``collect_rollouts`` would have seen it one step at a time. This
module replays those steps for what watches them: the ``VecNormalize`` statistics see every raw observation and
reward, a step hook (the learner's callback) sees SB3's locals, and the pool records the episodes that ended.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from stable_baselines3.common.vec_env import VecNormalize

from sb3_trpo_plus.normalization import NormalizationStats
from sb3_trpo_plus.segment import Segment

if TYPE_CHECKING:
    from sb3_trpo_plus.rollouts.pool import RolloutWorkers

# a step's SB3 locals (``new_obs``, ``rewards``, ``dones``, ``infos``, ``actions``, ``values``, ``log_probs``,
# ``n_steps``), its infos and its dones -> whether to go on (False: the callback stopped training)
StepHook = Callable[[dict[str, Any], list[dict[str, Any]], np.ndarray], bool]


def step_through_segment(
    segment: Segment, pool: RolloutWorkers, vec_normalize: VecNormalize | None, on_step: StepHook
) -> bool:
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


def record_worker_timings(record: Callable[..., None], pool: RolloutWorkers, n_steps: int) -> None:
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
