"""The one collection loop: ``collect_segment`` steps a VecEnv ``n_steps`` times with a policy and returns a
:class:`Segment`, the one record of collected transitions.

The learner collects with it (``TRPOPlus.collect_rollouts``, its callbacks firing at every step), so does every
rollout worker (``sb3_trpo_plus.rollouts``, in-process, in a process or on Ray); a segment fills the rollout buffer
(:class:`SegmentRolloutBuffer`) and is what the replay memory keeps. The loop is SB3's ``collect_rollouts``: the
same draws from the policy, action clipping or unscaling, time-limit truncations bootstrapped with the value of
the terminal observation, the value of the last observation; with gSDE, the same noise resets.

It is a fork of SB3 2.9.2's ``OnPolicyAlgorithm.collect_rollouts`` (``stable_baselines3/common/on_policy_algorithm.py``,
lines 162-269), reshaped to return the whole segment; :data:`FORKED_FROM` pins that source, and
``tests/test_sb3_fork.py`` runs both on the installed SB3 (same buffer, same callback calls).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictRolloutBuffer, RolloutBuffer
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.common.utils import obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv, unwrap_vec_normalize

from sb3_trpo_plus.algorithm.normalization import NormalizationStats

FORKED_FROM = (
    "2.9.2",
    "stable_baselines3.common.on_policy_algorithm.OnPolicyAlgorithm.collect_rollouts",
    "07f9eed35d9d7392f6ce287dc9d55aede83d8b0f93d34cb5d643410cdf11e3b7",
)
"""The SB3 version and function :func:`collect_segment` follows, and the SHA-256 of that function's source."""

Observation = np.ndarray | dict[str, np.ndarray]


# ---------------------------------------------------------------------------------------------------- checks
@contextlib.contextmanager
def unvalidated_distributions() -> Iterator[None]:
    """``torch.distributions`` without argument checks while it lasts: the checks are a third of a small policy's
    forward pass per step. Collection checks the policy's inputs instead (``check_finite_observations``), and the
    update keeps the weights finite, so the checks would never fire."""
    previous = th.distributions.Distribution._validate_args
    th.distributions.Distribution.set_default_validate_args(False)
    try:
        yield
    finally:
        th.distributions.Distribution.set_default_validate_args(previous)


def check_finite_observations(observations: Any, source: str) -> None:
    """Raise ``ValueError`` naming the first env whose observation holds a NaN or an infinity."""
    arrays = observations.values() if isinstance(observations, dict) else [observations]
    for array in arrays:
        finite = np.isfinite(np.asarray(array, dtype=np.float64).reshape(len(array), -1)).all(axis=1)
        if not finite.all():
            index = int(np.flatnonzero(~finite)[0])
            raise ValueError(f"{source}: env {index} returned a non-finite observation: {np.asarray(array)[index]}")


PolicyForward = Callable[[Any], tuple[th.Tensor, th.Tensor, th.Tensor]]
"""Observations (a tensor or a dict of them) -> sampled actions, values and the actions' log probabilities
(``ActorCriticPolicy.forward``)."""


def sampling_forward(policy: ActorCriticPolicy) -> PolicyForward:
    """``policy``'s forward pass for collection: ``policy(obs)``; for SB3's MLP policy with diagonal Gaussian actions
    on a Box observation space (its ``MlpPolicy`` with a ``FlattenExtractor``, shared or not, no gSDE), the same
    tensor operations in the same order without the module and distribution objects around them (two thirds of
    the time per call for the Grasper recipe's 100-100 policy on 64 envs). Either way the same draws from torch's
    generator and bit-identical outputs."""
    extractor = policy.features_extractor
    plain = (
        type(policy) is ActorCriticPolicy
        and type(policy.action_dist) is DiagGaussianDistribution
        and type(extractor) is FlattenExtractor
        and type(policy.observation_space) is spaces.Box
        and len(policy.observation_space.shape) == 1
        and not policy.squash_output
    )
    if not plain:
        return policy
    actor, critic = policy.mlp_extractor.policy_net, policy.mlp_extractor.value_net
    log_std = policy.log_std
    half_log_two_pi = math.log(math.sqrt(2 * math.pi))

    def forward(obs: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        features = obs.float()  # SB3's preprocess_obs of a Box; the FlattenExtractor keeps a batch of vectors
        values = policy.value_net(critic(features))
        mean = policy.action_net(actor(features))
        std = th.ones_like(mean) * log_std.exp()  # DiagGaussianDistribution.proba_distribution
        actions = th.normal(mean, std)  # Normal.sample, under collection's no-grad or inference mode
        # Normal.log_prob, summed over the action's dimensions as SB3's sum_independent_dims
        log_prob = (-((actions - mean) ** 2) / (2 * std**2) - std.log() - half_log_two_pi).sum(dim=1)
        return actions, values, log_prob

    return forward


# ---------------------------------------------------------------------------------------------------- records
@dataclass
class Segment:
    """``n_steps`` x ``n_envs`` transitions of one policy; arrays are indexed ``[step, env]``.

    What the rollout buffer takes (:meth:`SegmentRolloutBuffer.fill`), what the callbacks of a segment collected
    elsewhere are shown (``ended``), and what the replay memory needs to evaluate it again under later statistics
    and value functions (the ``raw_*`` fields, ``episode_timesteps`` and the truncations).

    :param observations: the policy's inputs (as ``VecNormalize`` gave them, or normalised with frozen ``NormalizationStats``)
    :param raw_observations: the envs' own observations, ``n_steps + 1`` of them (the last: after the last step)
    :param last_observation: the policy's input after the last step
    :param actions: the policy's actions (as sampled, before clipping to the action space)
    :param rewards: the rewards as ``VecNormalize`` gives them (the env's without one)
    :param buffer_rewards: ``rewards`` plus ``gamma * V(terminal observation)`` at time-limit truncations, as SB3's
        ``collect_rollouts`` adds them: what the rollout buffer takes
    :param raw_rewards: the envs' own rewards
    :param episode_starts: whether each step's observation starts an episode
    :param dones: whether each step ended an episode
    :param episode_timesteps: each step's index inside its episode, ``n_steps + 1`` rows
    :param values: the value estimates of ``observations``
    :param log_probs: the log-probabilities of ``actions`` under the policy that collected them
    :param last_values: the value estimates of ``last_observation``
    :param ended: per step, ``(env, info)`` of each episode that ended (``terminal_observation`` as the env gave it)
    :param truncated_steps: ``(step, env)`` of each episode cut by a time limit, ``(k, 2)``
    :param terminal_observations: their raw terminal observations, ``(k, *obs_shape)``
    :param terminal_timesteps: the episode step index of each terminal observation, ``(k,)``
    :param seconds: the wall time of the collection
    :param restarted: per env, whether a restart of its rollout worker reset it since the previous segment
    """

    observations: Observation
    raw_observations: Observation
    last_observation: Observation
    actions: np.ndarray
    rewards: np.ndarray
    buffer_rewards: np.ndarray
    raw_rewards: np.ndarray
    episode_starts: np.ndarray
    dones: np.ndarray
    episode_timesteps: np.ndarray
    values: np.ndarray
    log_probs: np.ndarray
    last_values: np.ndarray
    ended: list[list[tuple[int, dict[str, Any]]]]
    truncated_steps: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    terminal_observations: Observation | None = None
    terminal_timesteps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    seconds: float = 0.0
    restarted: np.ndarray | None = None

    @property
    def n_steps(self) -> int:
        return int(self.dones.shape[0])

    @property
    def n_envs(self) -> int:
        return int(self.dones.shape[1])

    @property
    def n_samples(self) -> int:
        return int(self.dones.size)

    @classmethod
    def concatenate(cls, segments: Sequence[Segment]) -> Segment:
        """The segments of workers ``0, 1, ...`` side by side: one segment over all their envs."""
        offsets = np.cumsum([0] + [segment.n_envs for segment in segments])
        n_steps = segments[0].n_steps

        def cat(name: str) -> Any:
            return _concatenate([getattr(segment, name) for segment in segments], axis=1)

        def flat(name: str) -> Any:
            return _concatenate([getattr(segment, name) for segment in segments], axis=0)

        starts = [int(offset) for offset in offsets[:-1]]
        ended = [
            [(start + env, info) for segment, start in zip(segments, starts, strict=True) for env, info in segment.ended[t]]
            for t in range(n_steps)
        ]
        truncated = [segment.truncated_steps + np.array([0, start]) for segment, start in zip(segments, starts, strict=True)]
        terminals = [segment.terminal_observations for segment in segments if segment.terminal_observations is not None]
        terminal_observations = _concatenate(terminals, axis=0) if terminals else None
        restarted = [s.restarted if s.restarted is not None else np.zeros(s.n_envs, bool) for s in segments]
        return cls(
            observations=cat("observations"),
            raw_observations=cat("raw_observations"),
            last_observation=flat("last_observation"),
            actions=cat("actions"),
            rewards=cat("rewards"),
            buffer_rewards=cat("buffer_rewards"),
            raw_rewards=cat("raw_rewards"),
            episode_starts=cat("episode_starts"),
            dones=cat("dones"),
            episode_timesteps=cat("episode_timesteps"),
            values=cat("values"),
            log_probs=cat("log_probs"),
            last_values=flat("last_values"),
            ended=ended,
            truncated_steps=np.concatenate(truncated),
            terminal_observations=terminal_observations,
            terminal_timesteps=np.concatenate([segment.terminal_timesteps for segment in segments]),
            seconds=max(s.seconds for s in segments),
            restarted=np.concatenate(restarted),
        )


def _concatenate(parts: Sequence[Observation], axis: int) -> Observation:
    if isinstance(parts[0], dict):
        return {key: np.concatenate([part[key] for part in parts], axis=axis) for key in parts[0]}
    return np.concatenate([np.asarray(part) for part in parts], axis=axis)


def _stack(rows: Sequence[Observation], like: Observation) -> Observation:
    """``rows`` stacked along a new first axis, in the dtype of ``like`` (arrays, or dicts of arrays)."""
    if isinstance(like, dict):
        return {key: np.stack([row[key] for row in rows]).astype(like[key].dtype) for key in like}
    return np.stack([np.asarray(row) for row in rows]).astype(np.asarray(like).dtype)


def _at(observation: Observation, index: Any) -> Observation:
    if isinstance(observation, dict):
        return {key: value[index] for key, value in observation.items()}
    return observation[index]


def _copy(observation: Observation) -> Observation:
    if isinstance(observation, dict):
        return {key: np.array(value) for key, value in observation.items()}
    return np.array(observation)


class _Rows:
    """``n`` rows of arrays (or of dicts of arrays), allocated at the first row's shape and dtype."""

    def __init__(self, n: int):
        self.n = n
        self.data: Observation | None = None

    def __setitem__(self, index: int, row: Observation) -> None:
        if self.data is None:
            if isinstance(row, dict):
                self.data = {key: np.zeros((self.n, *np.shape(v)), np.asarray(v).dtype) for key, v in row.items()}
            else:
                self.data = np.zeros((self.n, *np.shape(row)), np.asarray(row).dtype)
        if isinstance(self.data, dict):
            assert isinstance(row, dict)
            for key, value in row.items():
                self.data[key][index] = value
        else:
            self.data[index] = row

    def result(self) -> Observation:
        assert self.data is not None
        return self.data

    def array(self) -> np.ndarray:
        """The rows of arrays (not dicts)."""
        assert isinstance(self.data, np.ndarray)
        return self.data


# ---------------------------------------------------------------------------------------------------- the loop
@dataclass
class LoopState:
    """Where a VecEnv's episodes stand between segments: what ``collect_segment`` starts from and updates.

    :param observation: the policy's input (``VecNormalize``'s output, or the raw observation without one)
    :param raw_observation: the envs' own last observation
    :param episode_starts: whether ``observation`` starts an episode, per env
    :param episode_timesteps: the step index of ``observation`` inside its episode, per env
    """

    observation: Observation
    raw_observation: Observation
    episode_starts: np.ndarray
    episode_timesteps: np.ndarray


@dataclass(frozen=True)
class StepLocals:
    """One step of the loop as SB3's ``collect_rollouts`` shows it to callbacks (the names of its local variables).

    :param n_steps: the step's index in the segment
    """

    n_steps: int
    obs_tensor: Any
    actions: np.ndarray
    values: th.Tensor
    log_probs: th.Tensor
    clipped_actions: np.ndarray
    new_obs: Observation
    rewards: np.ndarray
    dones: np.ndarray
    infos: list[dict[str, Any]]


def collect_segment(
    policy: ActorCriticPolicy,
    env: VecEnv,
    n_steps: int,
    state: LoopState,
    *,
    gamma: float,
    normalizer: NormalizationStats | None = None,
    on_step: Callable[[StepLocals], bool] | None = None,
    sde_sample_freq: int | None = None,
    source: str | None = None,
) -> Segment | None:
    """Step ``env`` ``n_steps`` times with ``policy``, starting from ``state`` (updated in place), as SB3's
    ``collect_rollouts`` does; return the :class:`Segment`, or None when ``on_step`` stopped the loop.

    :param policy: the policy to sample from (in evaluation mode for the segment)
    :param env: the VecEnv; a ``VecNormalize`` in it (the learner's) normalises and updates its statistics at every
        step, and the segment's raw observations and rewards are its originals
    :param gamma: the discount of the time-limit bootstraps
    :param normalizer: frozen statistics (``NormalizationStats.of(vec_normalize)``) to normalise the raw observations
        and rewards of a bare ``env`` with (rollout workers); None: the policy sees what ``env`` returns
    :param on_step: called after each ``env.step`` with the step's locals, before anything is stored; returning
        False stops the loop (SB3's ``callback.on_step``)
    :param sde_sample_freq: with gSDE, the policy's noise is drawn again every that many steps (SB3's
        ``sde_sample_freq`` when positive); None without gSDE
    :param source: how errors name the collector (default: the env's class)
    """
    vec_normalize = unwrap_vec_normalize(env)
    if normalizer is not None and vec_normalize is not None:
        raise ValueError("collect_segment: a VecNormalize env normalises itself; pass no normalizer with it")
    start = time.perf_counter()
    source = source or type(env).__name__
    action_space = env.action_space
    n_envs = env.num_envs
    observations, raw_observations = _Rows(n_steps), _Rows(n_steps + 1)
    actions_out = _Rows(n_steps)
    rewards_out = np.zeros((n_steps, n_envs), dtype=np.float32)
    buffer_rewards = np.zeros((n_steps, n_envs), dtype=np.float32)
    raw_rewards = np.zeros((n_steps, n_envs), dtype=np.float32)
    episode_starts = np.zeros((n_steps, n_envs), dtype=np.float32)
    dones_out = np.zeros((n_steps, n_envs), dtype=bool)
    episode_timesteps = np.zeros((n_steps + 1, n_envs), dtype=np.int64)
    values_out = np.zeros((n_steps, n_envs), dtype=np.float32)
    log_probs_out = np.zeros((n_steps, n_envs), dtype=np.float32)
    ended: list[list[tuple[int, dict[str, Any]]]] = []
    truncated_steps: list[tuple[int, int]] = []
    terminal_observations: list[Observation] = []
    terminal_timesteps: list[int] = []
    policy.set_training_mode(False)
    forward = sampling_forward(policy)  # a gSDE policy samples with its own forward pass
    check_finite_observations(state.observation, source)
    # callbacks may keep what they are shown: plain no-grad tensors for them, inference tensors otherwise
    grad_free = th.no_grad() if on_step is not None else th.inference_mode()
    with grad_free, unvalidated_distributions():
        for t in range(n_steps):
            if sde_sample_freq is not None and sde_sample_freq > 0 and t % sde_sample_freq == 0:
                policy.reset_noise(n_envs)
            obs_tensor = obs_as_tensor(state.observation, policy.device)
            actions_t, values, log_probs = forward(obs_tensor)
            actions = actions_t.cpu().numpy()
            clipped = actions
            if isinstance(action_space, spaces.Box):
                clipped = (
                    policy.unscale_action(clipped)
                    if policy.squash_output
                    else np.clip(actions, action_space.low, action_space.high)
                )
            new_obs: Any
            new_obs, rewards, dones, infos = env.step(clipped)
            if vec_normalize is not None:
                new_raw, raw_reward = vec_normalize.get_original_obs(), vec_normalize.get_original_reward()
            else:
                new_raw, raw_reward = new_obs, rewards
                if normalizer is not None:
                    new_obs, rewards = normalizer.normalize_obs(new_obs), normalizer.normalize_reward(rewards)
            if on_step is not None and not on_step(
                StepLocals(t, obs_tensor, actions, values, log_probs, clipped, new_obs, rewards, dones, infos)
            ):
                return None
            bootstrapped = np.array(rewards)
            done_infos: list[tuple[int, dict[str, Any]]] = []
            for idx in np.flatnonzero(dones):
                info = infos[idx]
                terminal = info.get("terminal_observation")
                if terminal is not None and info.get("TimeLimit.truncated", False):
                    terminal_input = normalizer.normalize_obs(terminal) if normalizer is not None else terminal
                    terminal_value = policy.predict_values(policy.obs_to_tensor(terminal_input)[0])[0]
                    bootstrapped[idx] += gamma * terminal_value
                    raw_terminal = vec_normalize.unnormalize_obs(terminal) if vec_normalize is not None else terminal
                    truncated_steps.append((t, int(idx)))
                    terminal_observations.append(_copy(raw_terminal))
                    terminal_timesteps.append(int(state.episode_timesteps[idx]) + 1)
                done_infos.append((int(idx), info))
            observations[t] = state.observation
            raw_observations[t] = state.raw_observation
            episode_starts[t] = state.episode_starts
            episode_timesteps[t] = state.episode_timesteps
            actions_out[t] = actions
            rewards_out[t] = rewards
            buffer_rewards[t] = bootstrapped
            raw_rewards[t] = raw_reward
            dones_out[t] = dones
            values_out[t] = values.cpu().numpy().flatten()
            log_probs_out[t] = log_probs.cpu().numpy()
            ended.append(done_infos)
            state.observation, state.raw_observation = new_obs, new_raw
            state.episode_starts = np.asarray(dones, dtype=bool).copy()
            state.episode_timesteps = np.where(dones, 0, state.episode_timesteps + 1)
            check_finite_observations(new_obs, source)
        last_values = policy.predict_values(obs_as_tensor(state.observation, policy.device)).cpu().numpy().flatten()
    raw_observations[n_steps] = state.raw_observation
    episode_timesteps[n_steps] = state.episode_timesteps
    return Segment(
        observations=observations.result(),
        raw_observations=raw_observations.result(),
        last_observation=_copy(state.observation),
        actions=actions_out.array(),
        rewards=rewards_out,
        buffer_rewards=buffer_rewards,
        raw_rewards=raw_rewards,
        episode_starts=episode_starts,
        dones=dones_out,
        episode_timesteps=episode_timesteps,
        values=values_out,
        log_probs=log_probs_out,
        last_values=last_values.astype(np.float32),
        ended=ended,
        truncated_steps=np.array(truncated_steps, dtype=np.int64).reshape(-1, 2),
        terminal_observations=_stack(terminal_observations, like=state.raw_observation) if terminal_observations else None,
        terminal_timesteps=np.array(terminal_timesteps, dtype=np.int64),
        seconds=time.perf_counter() - start,
    )


# ---------------------------------------------------------------------------------------------------- the buffer
class _HoldsSegment(RolloutBuffer):
    """A rollout buffer filled from one :class:`Segment`, which it keeps (``segment``) for the update."""

    segment: Segment | None = None

    def fill(self, segment: Segment) -> None:
        """Reset, take every step of ``segment`` (time-limit bootstraps included), and compute the returns and GAE
        advantages from its last values, as SB3's ``collect_rollouts`` fills the buffer step by step."""
        self.reset()
        discrete = isinstance(self.action_space, spaces.Discrete)
        for t in range(segment.n_steps):
            actions = segment.actions[t]
            observation: Any = _at(segment.observations, t)  # a dict of arrays for the Dict buffer
            self.add(
                observation,
                actions.reshape(-1, 1) if discrete else actions,
                segment.buffer_rewards[t],
                segment.episode_starts[t],
                th.as_tensor(segment.values[t]),
                th.as_tensor(segment.log_probs[t]),
            )
        self.compute_returns_and_advantage(last_values=th.as_tensor(segment.last_values), dones=segment.dones[-1])
        self.segment = segment

    def reset(self) -> None:
        super().reset()
        self.segment = None


class SegmentRolloutBuffer(_HoldsSegment):
    """SB3's ``RolloutBuffer`` filled from a :class:`Segment` (``fill``), which it keeps as ``segment``."""


class SegmentDictRolloutBuffer(_HoldsSegment, DictRolloutBuffer):
    """SB3's ``DictRolloutBuffer`` filled from a :class:`Segment` (``fill``), which it keeps as ``segment``."""
