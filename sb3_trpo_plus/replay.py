"""Replay memory of past rollouts and the recomputation of their advantages (thesis section 5.3.1).

A :class:`StoredRollout` keeps what is needed to re-evaluate a rollout under the *current* value
function and observation statistics: raw observations, actions, the sampling policy's
log-probabilities, raw rewards, episode starts, the step index inside the episode, and the terminal
observations of time-limit truncations (for bootstrapping).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

ValueFunction = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``values = value_fn(observations, episode_timesteps)`` on flat batches (already normalised obs)."""


@dataclass
class StoredRollout:
    """One rollout of ``n_steps`` x ``n_envs`` transitions, stored for replay.

    Arrays are indexed ``[step, env]``. Observations and rewards are the environment's own values
    (before any ``VecNormalize``), so they can be re-normalised with the statistics of a later update.
    """

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

    @property
    def n_samples(self) -> int:
        return int(self.rewards.size)


@dataclass(frozen=True)
class RolloutEvaluation:
    """A stored rollout re-evaluated with the current value function and statistics (:func:`recompute_advantages`).

    :param rollout: the stored rollout
    :param observations: its observations, normalised and flattened to ``(n_steps * n_envs, *obs_shape)`` in
        ``[step, env]`` order
    :param values: current value estimates, shaped ``[step, env]``
    :param advantages: GAE advantages, shaped ``[step, env]``
    :param returns: ``advantages + values``, shaped ``[step, env]``
    """

    rollout: StoredRollout
    observations: np.ndarray
    values: np.ndarray
    advantages: np.ndarray
    returns: np.ndarray


class RolloutRecorder:
    """Accumulates one :class:`StoredRollout` step by step during ``collect_rollouts``.

    Preallocates its arrays once per rollout, so a step is a handful of array copies.
    """

    def __init__(self, n_steps: int, n_envs: int, obs_shape: tuple[int, ...], obs_dtype: np.dtype, action_dim: int):
        self.n_steps, self.n_envs = n_steps, n_envs
        self.obs_shape, self.obs_dtype, self.action_dim = obs_shape, obs_dtype, action_dim
        self._pos = 0
        self._allocate()

    def _allocate(self) -> None:
        shape = (self.n_steps, self.n_envs)
        self.observations = np.zeros(shape + self.obs_shape, dtype=self.obs_dtype)
        self.actions = np.zeros((*shape, self.action_dim), dtype=np.float32)
        self.log_probs = np.zeros(shape, dtype=np.float32)
        self.rewards = np.zeros(shape, dtype=np.float32)
        self.episode_starts = np.zeros(shape, dtype=np.float32)
        self.episode_timesteps = np.zeros(shape, dtype=np.int64)
        self._truncated: list[tuple[int, int]] = []
        self._terminal_obs: list[np.ndarray] = []
        self._terminal_t: list[int] = []

    def reset(self) -> None:
        """Start a new rollout (fresh arrays: the previous ones may now live in the memory)."""
        self._pos = 0
        self._allocate()

    def add(
        self,
        observations: np.ndarray,
        actions: np.ndarray,
        log_probs: np.ndarray,
        rewards: np.ndarray,
        episode_starts: np.ndarray,
        episode_timesteps: np.ndarray,
    ) -> None:
        """Record one vectorised step (all arguments have a leading ``n_envs`` axis)."""
        pos = self._pos
        self.observations[pos] = observations
        self.actions[pos] = actions.reshape(self.n_envs, self.action_dim)
        self.log_probs[pos] = log_probs
        self.rewards[pos] = rewards
        self.episode_starts[pos] = episode_starts
        self.episode_timesteps[pos] = episode_timesteps
        self._pos += 1

    def add_truncation(self, env_index: int, terminal_observation: np.ndarray, terminal_timestep: int) -> None:
        """Record that the step just added ended env ``env_index``'s episode by a time limit."""
        self._truncated.append((self._pos - 1, env_index))
        self._terminal_obs.append(np.asarray(terminal_observation, dtype=self.obs_dtype))
        self._terminal_t.append(terminal_timestep)

    def finish(self, last_observations: np.ndarray, last_dones: np.ndarray, last_timesteps: np.ndarray) -> StoredRollout:
        """Return the completed rollout."""
        if self._pos != self.n_steps:
            raise RuntimeError(f"rollout has {self._pos} of {self.n_steps} steps")
        terminal = np.stack(self._terminal_obs) if self._terminal_obs else None
        return StoredRollout(
            observations=self.observations,
            actions=self.actions,
            log_probs=self.log_probs,
            rewards=self.rewards,
            episode_starts=self.episode_starts,
            episode_timesteps=self.episode_timesteps,
            last_observations=np.array(last_observations, dtype=self.obs_dtype),
            last_dones=np.asarray(last_dones, dtype=np.float32).copy(),
            last_timesteps=np.array(last_timesteps, dtype=np.int64),
            truncated_steps=np.array(self._truncated, dtype=np.int64).reshape(-1, 2),
            terminal_observations=terminal,
            terminal_timesteps=np.array(self._terminal_t, dtype=np.int64),
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
    rollout: StoredRollout,
    value_fn: ValueFunction,
    gamma: float,
    gae_lambda: float,
    normalize_obs: Callable[[np.ndarray], np.ndarray] | None = None,
    normalize_reward: Callable[[np.ndarray], np.ndarray] | None = None,
) -> RolloutEvaluation:
    """Re-evaluate a stored rollout with the current value function and statistics.

    :param rollout: the stored rollout
    :param value_fn: current value function on flat (normalised) observations and episode timesteps
    :param normalize_obs: current observation normalisation (``VecNormalize.normalize_obs``), if any
    :param normalize_reward: current reward normalisation (``VecNormalize.normalize_reward``), if any
    :return: the rollout's normalised observations, values, advantages and returns
    """
    n_steps, n_envs = rollout.rewards.shape
    identity = _identity

    def prepare(obs: np.ndarray) -> np.ndarray:
        return (normalize_obs or identity)(obs).astype(np.float32, copy=False)

    obs_shape = rollout.observations.shape[2:]
    flat_obs = prepare(rollout.observations.reshape(n_steps * n_envs, *obs_shape))
    # One batched call for every state we need a value of: rollout, last and terminal observations
    batches = [flat_obs, prepare(rollout.last_observations)]
    times = [rollout.episode_timesteps.reshape(-1), rollout.last_timesteps]
    if rollout.terminal_observations is not None:
        batches.append(prepare(rollout.terminal_observations))
        times.append(rollout.terminal_timesteps)
    all_values = value_fn(np.concatenate(batches), np.concatenate(times)).reshape(-1).astype(np.float32)
    values = all_values[: n_steps * n_envs].reshape(n_steps, n_envs)
    last_values = all_values[n_steps * n_envs : n_steps * n_envs + n_envs]
    terminal_values = all_values[n_steps * n_envs + n_envs :]
    rewards = (normalize_reward or identity)(rollout.rewards).astype(np.float32)
    rewards = bootstrap_truncations(rewards, rollout.truncated_steps, terminal_values, gamma)
    advantages, returns = compute_gae(
        rewards, values, rollout.episode_starts, last_values, rollout.last_dones, gamma, gae_lambda
    )
    return RolloutEvaluation(rollout=rollout, observations=flat_obs, values=values, advantages=advantages, returns=returns)


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
