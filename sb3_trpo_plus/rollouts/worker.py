"""A rollout worker: a group of envs and a policy copy that collects segments
(:func:`~sb3_trpo_plus.algorithm.segment.collect_segment`).

:class:`WorkerEnvs` says how it builds its envs and :class:`SegmentOrder` is what the learner sends it per iteration;
both are plain data that travel to worker processes and Ray nodes.
"""

from __future__ import annotations

import contextlib
import os
import socket
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import cloudpickle
import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from sb3_trpo_plus.algorithm.normalization import NormalizationStats
from sb3_trpo_plus.algorithm.segment import LoopState, Segment, collect_segment
from sb3_trpo_plus.common.arguments import Rule, check_arguments, integer
from sb3_trpo_plus.rollouts.rules import WORKER_ENVS_RULES

WORKER_ARGUMENT_RULES: dict[str, Rule] = {
    "index": integer(0),
    "envs": Rule(lambda value: isinstance(value, WorkerEnvs), "a WorkerEnvs"),
    "torch_seed": integer(0, optional=True),
}
"""Every constructor argument of :class:`RolloutWorker` and what it accepts."""


@dataclass(frozen=True)
class WorkerEnvs:
    """How a worker builds its envs (plain data: it travels to worker processes and Ray nodes).

    :param env_id: a registered Gymnasium id; the tasks of ``grasp_envs`` run on the batched engine
    :param n_envs: envs of this worker
    :param sim_threads: threads of the batched engine's physics (``grasp_envs`` ids only)
    :param env_kwargs: the env's constructor options
    :param scripted_starts: ``grasp_envs.wrappers.ScriptedStarts`` options for training resets, or None
    :param info_keywords: info keys recorded in ``info["episode"]`` at each episode's end (as SB3's ``Monitor``)
    """

    env_id: str
    n_envs: int
    sim_threads: int = 1
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    scripted_starts: dict[str, Any] | None = None
    info_keywords: tuple[str, ...] = ("is_success",)

    def __post_init__(self) -> None:
        check_arguments(type(self).__name__, WORKER_ENVS_RULES, {name: getattr(self, name) for name in WORKER_ENVS_RULES})
        object.__setattr__(self, "info_keywords", tuple(self.info_keywords))  # a list is stored as a tuple

    def build(self) -> VecEnv:
        from sb3_trpo_plus.rollouts import engines

        if engines.has_batch_engine(self.env_id):
            return engines.batch_envs(
                self.env_id,
                self.n_envs,
                n_threads=self.sim_threads,
                env_kwargs=self.env_kwargs,
                scripted_starts=self.scripted_starts,
                info_keywords=self.info_keywords,
            )
        if self.scripted_starts is not None:
            raise ValueError(f"scripted starts run on the tasks of grasp_envs only, not on {self.env_id!r}")
        from stable_baselines3.common.env_util import make_vec_env

        return make_vec_env(
            self.env_id, self.n_envs, env_kwargs=self.env_kwargs, monitor_kwargs={"info_keywords": self.info_keywords}
        )


@dataclass(frozen=True)
class SegmentOrder:
    """What the learner sends every worker once per iteration.

    :param n_steps: steps to collect
    :param gamma: discount, for bootstrapping time-limit truncations with the value function (as SB3)
    :param weights: the policy's ``state_dict`` (CPU tensors)
    :param normalizer: the ``VecNormalize`` statistics of the iteration's start, or None
    """

    n_steps: int
    gamma: float
    weights: dict[str, th.Tensor]
    normalizer: NormalizationStats | None


class RolloutWorker:
    """A group of envs and a CPU copy of the policy; runs in the learner, a worker process or a Ray actor.

    :param index: the worker's index in its pool
    :param envs: how to build its envs
    :param torch_seed: seed of the generator its actions are sampled from (None: from the operating system)
    """

    def __init__(self, index: int, envs: WorkerEnvs, torch_seed: int | None):
        check_arguments(type(self).__name__, WORKER_ARGUMENT_RULES, {"index": index, "envs": envs, "torch_seed": torch_seed})
        self.index = int(index)
        self.envs = envs
        self.env = envs.build()
        self.policy: ActorCriticPolicy | None = None
        generator = th.Generator()
        if torch_seed is None:
            generator.seed()
        else:
            generator.manual_seed(int(torch_seed))
        self._rng_state = generator.get_state()
        n = self.env.num_envs
        self._raw_obs: np.ndarray | None = None
        self._episode_starts = np.ones(n, dtype=bool)
        self._timesteps = np.zeros(n, dtype=np.int64)

    @contextlib.contextmanager
    def _own_generator(self) -> Iterator[None]:
        """Sample from this worker's generator (SB3's policies draw from torch's global one); the caller's is kept."""
        caller = th.get_rng_state()
        th.set_rng_state(self._rng_state)
        try:
            yield
        finally:
            self._rng_state = th.get_rng_state()
            th.set_rng_state(caller)

    # -- set-up and the per-step VecEnv face
    def describe(self) -> dict[str, Any]:
        """The worker's spaces, process and place (its Ray node id inside a Ray cluster, else None)."""
        env = self.env
        ray = sys.modules.get("ray")  # imported in a Ray worker; never imported here for the other backends
        node = ray.get_runtime_context().get_node_id() if ray is not None and ray.is_initialized() else None
        return {
            "node": node,
            "observation_space": env.observation_space,
            "action_space": env.action_space,
            "render_mode": env.render_mode,
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "n_envs": env.num_envs,
        }

    def set_policy(self, blueprint: bytes) -> None:
        """The policy to sample from, as ``cloudpickle`` bytes of a CPU copy (sent once; weights come with orders)."""
        self.policy = cloudpickle.loads(blueprint)
        assert self.policy is not None
        self.policy.set_training_mode(False)

    def reset(self, seeds: Sequence[int | None] | None, options: Sequence[dict[str, Any]] | None) -> tuple[np.ndarray, list]:
        if seeds is not None:
            self.env._seeds = list(seeds)
        if options is not None:
            self.env._options = list(options)
        obs = self.env.reset()
        assert isinstance(obs, np.ndarray)
        self._raw_obs = obs
        self._episode_starts[:] = True
        self._timesteps[:] = 0
        return obs, list(self.env.reset_infos)

    def step(self, actions: np.ndarray) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.env.step(actions)
        self._advance(obs, dones)
        return obs, rewards, dones, infos

    def _advance(self, obs: Any, dones: np.ndarray) -> None:
        self._raw_obs = obs
        self._timesteps += 1
        self._timesteps[dones] = 0
        self._episode_starts = np.asarray(dones, dtype=bool).copy()

    def call(self, method: str, args: tuple[Any, ...] = (), kwargs: dict[str, Any] | None = None) -> Any:
        """One of the VecEnv's ``get_attr``, ``set_attr``, ``env_method``, ``env_is_wrapped``, ``get_images``."""
        if method not in {"get_attr", "set_attr", "env_method", "env_is_wrapped", "get_images"}:
            raise ValueError(f"rollout worker: {method!r} is no VecEnv query")
        return getattr(self.env, method)(*args, **(kwargs or {}))

    def close(self) -> None:
        self.env.close()

    # -- whole segments
    def collect(self, order: SegmentOrder) -> Segment:
        """Step every env ``order.n_steps`` times with the order's policy weights (:func:`collect_segment`)."""
        if self.policy is None:
            raise RuntimeError(f"rollout worker {self.index}: collect before set_policy")
        if self._raw_obs is None:
            raise RuntimeError(f"rollout worker {self.index}: collect before reset")
        policy = self.policy
        policy.load_state_dict(order.weights)
        norm = order.normalizer
        raw = self._raw_obs
        state = LoopState(norm.normalize_obs(raw) if norm is not None else raw, raw, self._episode_starts, self._timesteps)
        with self._own_generator():
            segment = collect_segment(
                policy,
                self.env,
                order.n_steps,
                state,
                gamma=order.gamma,
                normalizer=norm,
                source=f"rollout worker {self.index}",
            )
        assert segment is not None and isinstance(state.raw_observation, np.ndarray)
        self._raw_obs, self._episode_starts, self._timesteps = (
            state.raw_observation,
            state.episode_starts,
            state.episode_timesteps,
        )
        return segment
