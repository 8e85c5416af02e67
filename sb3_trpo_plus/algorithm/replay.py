"""Replay memory of past segments and the recomputation of their advantages (thesis section 5.3.1).

A :class:`~sb3_trpo_plus.algorithm.segment.Segment` keeps what is needed to evaluate it again under the *current* value
function and observation statistics: raw observations, actions, the sampling policy's log-probabilities, raw
rewards, episode starts, the step index inside the episode, and the raw terminal observations of time-limit
truncations (for bootstrapping). :func:`recompute_advantages` does that evaluation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sb3_trpo_plus.algorithm.reuse import vtrace_gae
from sb3_trpo_plus.algorithm.segment import Segment

ValueFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``values = value_fn(observations, episode_timesteps)`` on flat batches (already normalised obs)."""


@dataclass(frozen=True)
class RolloutEvaluation:
    """A stored segment evaluated with the current value function and statistics (:func:`recompute_advantages`).

    :param segment: the stored segment
    :param observations: its raw observations, normalised and flattened to ``(n_steps * n_envs, *obs_shape)`` in
        ``[step, env]`` order
    :param values: current value estimates, shaped ``[step, env]``
    :param advantages: GAE advantages, shaped ``[step, env]``
    :param returns: ``advantages + values``, shaped ``[step, env]``
    """

    segment: Segment
    observations: np.ndarray
    values: np.ndarray
    advantages: np.ndarray
    returns: np.ndarray


@dataclass
class StoredRollout:
    """The replay record of models saved by version 0.1.0, read only to convert it (:meth:`to_segment`)."""

    observations: np.ndarray
    actions: np.ndarray
    log_probs: np.ndarray
    rewards: np.ndarray
    episode_starts: np.ndarray
    episode_timesteps: np.ndarray
    last_observations: np.ndarray
    last_dones: np.ndarray
    last_timesteps: np.ndarray
    truncated_steps: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    terminal_observations: np.ndarray | None = None
    terminal_timesteps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def to_segment(self) -> Segment:
        """The segment with this record's raw data. A 0.1.0 record kept neither the policy's inputs nor the values
        it was collected with; replay never reads them: they are the raw observations and zeros here."""
        n_steps, n_envs = self.rewards.shape
        raw = np.concatenate([self.observations, self.last_observations[None]])
        dones = np.concatenate([self.episode_starts[1:], self.last_dones[None]]).astype(bool)
        zeros = np.zeros((n_steps, n_envs), dtype=np.float32)
        ended: list[list[tuple[int, dict[str, Any]]]] = [[] for _ in range(n_steps)]
        return Segment(
            observations=self.observations,
            raw_observations=raw,
            last_observation=self.last_observations,
            actions=self.actions,
            rewards=self.rewards,
            buffer_rewards=self.rewards,
            raw_rewards=self.rewards,
            episode_starts=self.episode_starts,
            dones=dones,
            episode_timesteps=np.concatenate([self.episode_timesteps, self.last_timesteps[None]]),
            values=zeros,
            log_probs=self.log_probs,
            last_values=np.zeros(n_envs, dtype=np.float32),
            ended=ended,
            truncated_steps=self.truncated_steps,
            terminal_observations=self.terminal_observations,
            terminal_timesteps=self.terminal_timesteps,
        )


def compute_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    episode_starts: np.ndarray,
    last_values: np.ndarray,
    last_dones: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Generalised advantage estimation over a ``[step, env]`` rollout, as SB3's ``RolloutBuffer``.

    ``episode_starts[t + 1]`` (or ``last_dones`` after the last step) marks the end of an episode;
    time-limit truncations must already be bootstrapped into ``rewards`` (see
    :func:`bootstrap_truncations`).

    :return: ``(advantages, returns)`` with ``returns = advantages + values``
    """
    n_steps = rewards.shape[0]
    advantages = np.zeros_like(rewards, dtype=np.float32)
    last_gae = np.zeros_like(last_values, dtype=np.float32)
    for step in reversed(range(n_steps)):
        if step == n_steps - 1:
            next_non_terminal = 1.0 - last_dones.astype(np.float32)
            next_values = last_values
        else:
            next_non_terminal = 1.0 - episode_starts[step + 1]
            next_values = values[step + 1]
        delta = rewards[step] + gamma * next_values * next_non_terminal - values[step]
        last_gae = delta + gamma * gae_lambda * next_non_terminal * last_gae
        advantages[step] = last_gae
    return advantages, (advantages + values).astype(np.float32)


def bootstrap_truncations(
    rewards: np.ndarray, truncated_steps: np.ndarray, terminal_values: np.ndarray, gamma: float
) -> np.ndarray:
    """Return a copy of ``rewards`` with ``gamma * V(terminal_obs)`` added where a time limit cut the episode."""
    rewards = rewards.copy()
    if len(truncated_steps):
        np.add.at(rewards, (truncated_steps[:, 0], truncated_steps[:, 1]), gamma * terminal_values)
    return rewards


def recompute_advantages(
    segment: Segment,
    value_fn: ValueFunction,
    gamma: float,
    gae_lambda: float,
    normalize_obs: Callable[[np.ndarray], np.ndarray] | None = None,
    normalize_reward: Callable[[np.ndarray], np.ndarray] | None = None,
    trace_ratios: Callable[[np.ndarray], np.ndarray] | None = None,
) -> RolloutEvaluation:
    """Evaluate a stored segment again with the current value function and statistics.

    :param segment: the stored segment (array observations)
    :param value_fn: current value function on flat (normalised) observations and episode timesteps
    :param normalize_obs: current observation normalisation (``VecNormalize.normalize_obs``), if any
    :param normalize_reward: current reward normalisation (``VecNormalize.normalize_reward``), if any
    :param trace_ratios: the truncated importance ratios ``c_t`` (``[step, env]``) from the flat normalised
        observations: off-policy GAE (:func:`~sb3_trpo_plus.algorithm.reuse.vtrace_gae`) instead of on-policy GAE
    :return: the segment's normalised observations, values, advantages and returns
    """
    n_steps, n_envs = segment.raw_rewards.shape
    identity = _identity
    raw_observations = segment.raw_observations
    assert isinstance(raw_observations, np.ndarray), "replay needs array observations"

    def prepare(obs: np.ndarray) -> np.ndarray:
        return (normalize_obs or identity)(obs).astype(np.float32, copy=False)

    obs_shape = raw_observations.shape[2:]
    flat_obs = prepare(raw_observations[:n_steps].reshape(n_steps * n_envs, *obs_shape))
    # One batched call for every state we need a value of: the steps', the last and the terminal observations
    batches = [flat_obs, prepare(raw_observations[n_steps])]
    times = [segment.episode_timesteps[:n_steps].reshape(-1), segment.episode_timesteps[n_steps]]
    if segment.terminal_observations is not None:
        assert isinstance(segment.terminal_observations, np.ndarray)
        batches.append(prepare(segment.terminal_observations))
        times.append(segment.terminal_timesteps)
    all_values = value_fn(np.concatenate(batches), np.concatenate(times)).reshape(-1).astype(np.float32)
    values = all_values[: n_steps * n_envs].reshape(n_steps, n_envs)
    last_values = all_values[n_steps * n_envs : n_steps * n_envs + n_envs]
    terminal_values = all_values[n_steps * n_envs + n_envs :]
    rewards = (normalize_reward or identity)(segment.raw_rewards).astype(np.float32)
    rewards = bootstrap_truncations(rewards, segment.truncated_steps, terminal_values, gamma)
    if trace_ratios is not None:
        ratios = trace_ratios(flat_obs)
        advantages, returns = vtrace_gae(rewards, values, segment.dones, last_values, ratios, gamma, gae_lambda)
    else:
        advantages, returns = compute_gae(
            rewards, values, segment.episode_starts, last_values, segment.dones[-1], gamma, gae_lambda
        )
    return RolloutEvaluation(segment=segment, observations=flat_obs, values=values, advantages=advantages, returns=returns)


def _identity(x: np.ndarray) -> np.ndarray:
    return x


def importance_weights(
    log_prob_current: np.ndarray, log_prob_sampling: np.ndarray, clip: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Importance weights ``rho = pi_current(a|s) / q(a|s)`` and their truncation factors.

    :return: ``(rho, scale)`` where ``scale = min(1, clip / rho)`` (ones without ``clip``) so that the
        truncated weight is ``rho * scale = min(rho, clip)``; ``scale`` multiplies the ratio
        ``pi_theta / q`` in the surrogate and is constant during the update.
    """
    rho = np.exp(np.clip(log_prob_current - log_prob_sampling, -50.0, 50.0))
    if clip is None:
        return rho, np.ones_like(rho)
    return rho, np.minimum(1.0, clip / rho)


def effective_sample_size(weights: np.ndarray) -> float:
    """Kish's effective sample size ``(sum w)^2 / sum w^2`` (equals ``len(w)`` for equal weights)."""
    total_sq = float(np.sum(np.square(weights, dtype=np.float64)))
    if total_sq == 0.0:
        return 0.0
    return float(np.sum(weights, dtype=np.float64) ** 2 / total_sq)
