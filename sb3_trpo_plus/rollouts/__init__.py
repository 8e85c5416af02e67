"""Rollout workers: whole rollout segments collected by workers that each own a group of envs and a policy copy.

The thesis' parallel sampler (section 6.3): each worker holds environments and a copy of the policy, samples whole
trajectories, and receives new weights after each update. Here a worker owns one batched VecEnv
(``grasp_envs.make_batch_env`` for the tasks of ``grasp_envs``, a ``DummyVecEnv`` of ``gym.make`` for any other id)
and a CPU copy of the policy. Per iteration :class:`~sb3_trpo_plus.TRPOPlus` sends every worker one *order* (the
policy's weights and the frozen ``VecNormalize`` statistics, put once), each worker steps its envs ``n_steps`` times
and returns its :class:`Segment`, and the learner fills the rollout buffer and updates the ``VecNormalize``
statistics with the segments' raw observations and rewards, as SB3 would have step by step.

The pools are SB3 ``VecEnv`` s, so everything that takes a VecEnv takes them (``VecNormalize``, ``EvalCallback``'s
``sync_envs_normalization``, PPO, ``evaluate_policy``); stepped one step at a time they forward each step to the
workers. :class:`~sb3_trpo_plus.TRPOPlus` alone collects whole segments. Three backends, one worker code:

* :class:`InProcessRollouts`: the workers live in the learner's process and collect one after the other;
* :class:`ProcessRollouts`: one local process per worker;
* :class:`RayRollouts`: one Ray actor per worker, spread over the nodes of a Ray cluster (``pip install
  sb3-trpo-plus[ray]``).

With the same ``seed``, ``num_workers`` and ``envs_per_worker``, the three give the same segments: each worker samples
its actions from its own torch generator (seeded from ``seed`` and the worker's index) and its env ``j`` is seeded
``seed + worker * envs_per_worker + j``, as ``make_vec_env`` seeds env ``i`` with ``seed + i``.

During a segment the observations and rewards are normalised with the statistics of the iteration's start (SB3
updates them after every step); the statistics see every raw observation and reward of the segment afterwards.
"""

from sb3_trpo_plus.algorithm.segment import Segment
from sb3_trpo_plus.algorithm.segment_pool import SegmentPool, buried_rollout_workers, rollout_workers
from sb3_trpo_plus.algorithm.worker_failures import RolloutWorkerError
from sb3_trpo_plus.rollouts.backends import RemoteTraceback
from sb3_trpo_plus.rollouts.pool import (
    POOLS,
    InProcessRollouts,
    ProcessRollouts,
    RayRollouts,
    RolloutWorkers,
    split_pool,
)
from sb3_trpo_plus.rollouts.rules import POOL_ARGUMENT_RULES, WORKER_ENVS_RULES
from sb3_trpo_plus.rollouts.worker import WORKER_ARGUMENT_RULES, RolloutWorker, SegmentOrder, WorkerEnvs

__all__ = [
    "POOLS",
    "POOL_ARGUMENT_RULES",
    "WORKER_ARGUMENT_RULES",
    "WORKER_ENVS_RULES",
    "InProcessRollouts",
    "ProcessRollouts",
    "RayRollouts",
    "RemoteTraceback",
    "RolloutWorker",
    "RolloutWorkerError",
    "RolloutWorkers",
    "Segment",
    "SegmentOrder",
    "SegmentPool",
    "WorkerEnvs",
    "buried_rollout_workers",
    "rollout_workers",
    "split_pool",
]
