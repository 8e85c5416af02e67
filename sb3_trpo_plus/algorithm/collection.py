"""TRPOPlus' rollouts: SB3's ``collect_rollouts`` as one collected segment, from the learner's own VecEnv or from a
pool of rollout workers (:mod:`sb3_trpo_plus.rollouts`), with ``overlap_collection``'s segment ordered for the next
rollout while the learner updates."""

from __future__ import annotations

import dataclasses
import warnings
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sb3_trpo_plus.algorithm.normalization import NormalizationStats
from sb3_trpo_plus.algorithm.segment import (
    LoopState,
    Segment,
    SegmentDictRolloutBuffer,
    SegmentRolloutBuffer,
    StepLocals,
    collect_segment,
)
from sb3_trpo_plus.algorithm.segment_pool import (
    SegmentPool,
    buried_rollout_workers,
    record_worker_timings,
    rollout_workers,
    step_through_segment,
)

if TYPE_CHECKING:
    from sb3_contrib import TRPO

    _Algorithm = TRPO
else:
    _Algorithm = object


class SegmentCollection(_Algorithm):
    """The collection half of :class:`~sb3_trpo_plus.TRPOPlus` (a mixin before sb3-contrib's ``TRPO``): it sets
    ``_last_obs``, ``_last_episode_starts`` and ``_last_episode_timesteps`` from each segment and fills the
    ``SegmentRolloutBuffer`` that the update reads the segment from."""

    overlap_collection: bool
    _overlap_ordered: bool
    _last_episode_timesteps: np.ndarray | None

    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
    ) -> bool:
        """SB3's ``collect_rollouts``: one segment collected (:func:`~sb3_trpo_plus.algorithm.segment.collect_segment`), the
        callback's ``on_step`` fired at every step with SB3's locals, the rollout buffer filled from the segment
        (which it keeps for the update and the replay memory).

        On a pool of rollout workers (``sb3_trpo_plus.rollouts``, bare or under one ``VecNormalize``) the workers
        collect the segment with the same loop, and the callback's steps follow once it arrived
        (:meth:`_segment_from_workers`).
        """
        assert self._last_obs is not None, "No previous observation was provided"
        if not isinstance(rollout_buffer, SegmentRolloutBuffer | SegmentDictRolloutBuffer):
            raise TypeError(f"TRPOPlus fills a SegmentRolloutBuffer from its segments, got {type(rollout_buffer).__name__}")
        pool = rollout_workers(env)
        if pool is None and buried_rollout_workers(env):  # shown once per program by Python's default warning filter
            warnings.warn(
                f"the rollout workers are wrapped by {type(env).__name__}: TRPOPlus steps them one step at a time "
                "(no segments, no restarts); wrap them with one VecNormalize at most to collect whole segments",
                stacklevel=2,
            )
        if pool is not None and self.use_sde:
            raise ValueError("rollout workers sample without gSDE: use_sde=True needs a VecEnv stepped by the learner")
        self.policy.set_training_mode(False)
        rollout_buffer.reset()
        if self.use_sde:
            self.policy.reset_noise(env.num_envs)
        callback.on_rollout_start()
        if pool is not None:
            segment = self._segment_from_workers(pool[0], pool[1], callback, n_rollout_steps)
        else:
            segment = self._segment_from_env(env, callback, rollout_buffer, n_rollout_steps)
        if segment is None:  # the callback stopped training: the partial rollout is dropped, as in SB3
            return False
        self._last_obs = segment.last_observation
        self._last_episode_starts = segment.dones[-1]
        self._last_episode_timesteps = segment.episode_timesteps[-1].copy()
        rollout_buffer.fill(segment)
        callback.update_locals(
            {
                "new_obs": segment.last_observation,
                "dones": segment.dones[-1],
                "rollout_buffer": rollout_buffer,
                "values": th.as_tensor(segment.last_values),
            }
        )
        callback.on_rollout_end()
        return True

    def _segment_from_env(
        self, env: VecEnv, callback: BaseCallback, rollout_buffer: RolloutBuffer, n_rollout_steps: int
    ) -> Segment | None:
        """The learner steps ``env`` itself; the callback fires after each ``env.step`` (None: it stopped training)."""
        vec_normalize = self.get_vec_normalize_env()
        assert self._last_episode_timesteps is not None
        state = LoopState(
            observation=self._last_obs,  # type: ignore[arg-type]
            raw_observation=vec_normalize.get_original_obs() if vec_normalize is not None else self._last_obs,  # type: ignore[arg-type]
            episode_starts=np.asarray(self._last_episode_starts, dtype=bool),
            episode_timesteps=self._last_episode_timesteps,
        )
        own = {
            "self": self,
            "env": env,
            "callback": callback,
            "rollout_buffer": rollout_buffer,
            "n_rollout_steps": n_rollout_steps,
        }

        def on_step(step: StepLocals) -> bool:  # what SB3 does between env.step and storing the step
            self.num_timesteps += env.num_envs
            callback.update_locals({**own, **{f.name: getattr(step, f.name) for f in dataclasses.fields(step)}})
            if not callback.on_step():
                return False
            self._update_info_buffer(step.infos, step.dones)
            return True

        return collect_segment(
            self.policy,
            env,
            n_rollout_steps,
            state,
            gamma=self.gamma,
            on_step=on_step,
            sde_sample_freq=self.sde_sample_freq if self.use_sde else None,
        )

    def _segment_from_workers(
        self, pool: SegmentPool, vec_normalize: VecNormalize | None, callback: BaseCallback, n_rollout_steps: int
    ) -> Segment | None:
        """Every worker collects ``n_rollout_steps`` steps with the current weights (or the segment ordered during the
        last update arrives); then its steps go to the ``VecNormalize`` statistics, the callback (SB3's locals; its
        ``on_step`` fires once per step) and the episode statistics, as SB3's ``collect_rollouts`` would have sent them
        (:func:`~sb3_trpo_plus.algorithm.segment_pool.step_through_segment`). None: the callback stopped training.
        """
        if self.overlap_collection and pool.collecting:  # ordered before the last update
            segments = pool.gather_segments()
        else:
            if self._overlap_ordered:  # shown once per program by Python's default warning filter
                warnings.warn(
                    "TRPOPlus: the segment ordered during the last update was dropped: something used the rollout "
                    "workers between two rollouts (reset, env_method, get_attr or set_attr, e.g. in a callback); "
                    "this rollout is collected while the learner waits",
                    stacklevel=2,
                )
            segments = pool.collect_segments(self.policy, n_rollout_steps, self.gamma, NormalizationStats.of(vec_normalize))
        self._overlap_ordered = False
        segment = Segment.concatenate(segments)
        n_envs = pool.num_envs

        def on_step(step_locals: dict[str, Any], infos: list[dict[str, Any]], dones: np.ndarray) -> bool:
            self.num_timesteps += n_envs
            callback.update_locals({**step_locals, "env": self.env})
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            return True

        if not step_through_segment(segment, pool, vec_normalize, on_step):
            return None
        record_worker_timings(self.logger.record, pool, n_rollout_steps)
        if self.overlap_collection:  # the next segment, with these weights and statistics, while train() updates
            pool.submit_segments(self.policy, n_rollout_steps, self.gamma, NormalizationStats.of(vec_normalize))
            self._overlap_ordered = True
        return segment
