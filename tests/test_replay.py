"""Replay memory: GAE recomputation, importance weights, the linear baseline."""

import numpy as np
import pytest

from sb3_trpo_plus.algorithm.baselines import LinearFeatureBaseline
from sb3_trpo_plus.algorithm.replay import (
    StoredRollout,
    bootstrap_truncations,
    compute_gae,
    effective_sample_size,
    importance_weights,
    recompute_advantages,
)
from sb3_trpo_plus.algorithm.segment import Segment

TOY_VALUES = np.array([[0.5], [1.0], [1.5], [2.0]], dtype=np.float32)


def _toy_rollout() -> StoredRollout:
    """One env, 4 steps: an episode of 2 steps cut by a time limit, then one that terminates.

    Observations encode the value the toy value function returns (obs[0] = V(s)).
    """
    return StoredRollout(
        observations=TOY_VALUES[..., None],
        actions=np.zeros((4, 1, 1), dtype=np.float32),
        log_probs=np.zeros((4, 1), dtype=np.float32),
        rewards=np.array([[1.0], [2.0], [3.0], [4.0]], dtype=np.float32),
        episode_starts=np.array([[1.0], [0.0], [1.0], [0.0]], dtype=np.float32),
        episode_timesteps=np.array([[0], [1], [0], [1]]),
        last_observations=np.array([[10.0]], dtype=np.float32),
        last_dones=np.array([1.0], dtype=np.float32),
        last_timesteps=np.array([0]),
        truncated_steps=np.array([[1, 0]]),
        terminal_observations=np.array([[4.0]], dtype=np.float32),
        terminal_timesteps=np.array([2]),
    )


def _toy_segment() -> Segment:
    """The toy rollout as a collected segment records it."""
    rewards = np.array([[1.0], [2.0], [3.0], [4.0]], dtype=np.float32)
    zeros = np.zeros((4, 1), dtype=np.float32)
    return Segment(
        observations=TOY_VALUES[..., None],
        raw_observations=np.concatenate([TOY_VALUES, [[10.0]]])[..., None],
        last_observation=np.array([[10.0]], dtype=np.float32),
        actions=np.zeros((4, 1, 1), dtype=np.float32),
        rewards=rewards,
        buffer_rewards=rewards,
        raw_rewards=rewards,
        episode_starts=np.array([[1.0], [0.0], [1.0], [0.0]], dtype=np.float32),
        dones=np.array([[False], [True], [False], [True]]),
        episode_timesteps=np.array([[0], [1], [0], [1], [0]]),
        values=zeros,
        log_probs=zeros,
        last_values=np.zeros(1, dtype=np.float32),
        ended=[[], [], [], []],
        truncated_steps=np.array([[1, 0]]),
        terminal_observations=np.array([[4.0]], dtype=np.float32),
        terminal_timesteps=np.array([2]),
    )


def test_recompute_advantages_hand_computed() -> None:
    # gamma = lambda = 0.5. Truncation at step 1 bootstraps r1 = 2 + 0.5 * V(terminal)=4 -> 4.
    # step 3 (terminates): delta = 4 - 2 = 2                         A3 = 2
    # step 2: delta = 3 + 0.5 * 2.0 - 1.5 = 2.5;  A2 = 2.5 + 0.25 * 2  = 3
    # step 1 (episode ends): delta = 4 - 1 = 3                        A1 = 3
    # step 0: delta = 1 + 0.5 * 1.0 - 0.5 = 1;    A0 = 1 + 0.25 * 3   = 1.75
    def value_fn(obs: np.ndarray, t: np.ndarray) -> np.ndarray:
        return obs[:, 0]

    segment = _toy_segment()
    evaluation = recompute_advantages(segment, value_fn, gamma=0.5, gae_lambda=0.5)
    np.testing.assert_allclose(evaluation.advantages[:, 0], [1.75, 3.0, 3.0, 2.0])
    np.testing.assert_allclose(evaluation.returns[:, 0], [2.25, 4.0, 4.5, 4.0])
    np.testing.assert_allclose(evaluation.values[:, 0], [0.5, 1.0, 1.5, 2.0])
    assert evaluation.observations.shape == (4, 1)
    assert evaluation.segment is segment


def test_recompute_uses_current_normalisation() -> None:
    def value_fn(obs: np.ndarray, t: np.ndarray) -> np.ndarray:
        return obs[:, 0]

    # value doubles, rewards halve: recomputation must see both
    evaluation = recompute_advantages(
        _toy_segment(), value_fn, 0.5, 0.5, normalize_obs=lambda o: 2 * o, normalize_reward=lambda r: r / 2
    )
    np.testing.assert_allclose(evaluation.values[:, 0], [1.0, 2.0, 3.0, 4.0])
    # terminated last step: return = normalised reward only
    assert evaluation.returns[3, 0] == pytest.approx(2.0)


def test_compute_gae_matches_sb3_rollout_buffer() -> None:
    import torch as th
    from gymnasium import spaces
    from stable_baselines3.common.buffers import RolloutBuffer

    rng = np.random.default_rng(0)
    n_steps, n_envs = 16, 3
    buffer = RolloutBuffer(n_steps, spaces.Box(-1, 1, (2,)), spaces.Box(-1, 1, (1,)), gamma=0.9, gae_lambda=0.8, n_envs=n_envs)
    rewards = rng.normal(size=(n_steps, n_envs)).astype(np.float32)
    values = rng.normal(size=(n_steps, n_envs)).astype(np.float32)
    starts = (rng.random((n_steps, n_envs)) < 0.2).astype(np.float32)
    for t in range(n_steps):
        buffer.add(
            np.zeros((n_envs, 2)), np.zeros((n_envs, 1)), rewards[t], starts[t], th.as_tensor(values[t]), th.zeros(n_envs)
        )
    last_values, last_dones = rng.normal(size=n_envs).astype(np.float32), np.array([0.0, 1.0, 0.0])
    buffer.compute_returns_and_advantage(th.as_tensor(last_values), last_dones)
    advantages, returns = compute_gae(rewards, values, starts, last_values, last_dones, 0.9, 0.8)
    np.testing.assert_allclose(advantages, buffer.advantages, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(returns, buffer.returns, rtol=1e-5, atol=1e-6)


def test_bootstrap_truncations_adds_discounted_terminal_values() -> None:
    rewards = np.zeros((3, 2), dtype=np.float32)
    out = bootstrap_truncations(rewards, np.array([[0, 1], [2, 0]]), np.array([10.0, -4.0]), gamma=0.9)
    np.testing.assert_allclose(out, [[0, 9.0], [0, 0], [-3.6, 0]])
    assert rewards.sum() == 0  # input untouched


def test_importance_weights_and_truncation() -> None:
    log_now = np.log(np.array([0.2, 0.5, 0.9]))
    log_q = np.log(np.array([0.4, 0.5, 0.1]))
    rho, scale = importance_weights(log_now, log_q)
    np.testing.assert_allclose(rho, [0.5, 1.0, 9.0])
    np.testing.assert_allclose(scale, 1.0)
    rho, scale = importance_weights(log_now, log_q, clip=2.0)
    np.testing.assert_allclose(rho * scale, [0.5, 1.0, 2.0])


def test_effective_sample_size() -> None:
    assert effective_sample_size(np.ones(10)) == pytest.approx(10.0)
    assert effective_sample_size(np.array([1.0, 0.0, 0.0])) == pytest.approx(1.0)
    assert effective_sample_size(np.array([1.0, 3.0])) == pytest.approx(16.0 / 10.0)
    assert effective_sample_size(np.zeros(3)) == 0.0


def test_a_replay_record_of_version_0_1_is_the_same_segment_for_replay() -> None:
    """Models saved by 0.1.0 hold StoredRollout records; converted, they replay exactly as the segment would."""
    converted, segment = _toy_rollout().to_segment(), _toy_segment()
    for name in (
        "raw_observations",
        "raw_rewards",
        "episode_starts",
        "dones",
        "episode_timesteps",
        "actions",
        "log_probs",
        "truncated_steps",
        "terminal_observations",
        "terminal_timesteps",
    ):
        np.testing.assert_array_equal(getattr(converted, name), getattr(segment, name), err_msg=name)

    def value_fn(obs: np.ndarray, t: np.ndarray) -> np.ndarray:
        return obs[:, 0] + t

    a = recompute_advantages(converted, value_fn, gamma=0.9, gae_lambda=0.8)
    b = recompute_advantages(segment, value_fn, gamma=0.9, gae_lambda=0.8)
    np.testing.assert_array_equal(a.advantages, b.advantages)
    np.testing.assert_array_equal(a.returns, b.returns)


def test_linear_baseline_features_and_fit() -> None:
    baseline = LinearFeatureBaseline(l2_reg=0.0)
    obs = np.array([[1.0, -2.0], [20.0, 0.5]])
    features = baseline.features(obs, np.array([0, 50]))
    np.testing.assert_allclose(features[0], [1, -2, 1, 4, 0, 0, 0, 1])
    np.testing.assert_allclose(features[1], [10, 0.5, 100, 0.25, 0.5, 0.25, 0.125, 1])  # obs clipped to 10, t/100
    # exact recovery of a linear target without regularisation
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(200, 2))
    t = rng.integers(0, 100, size=200)
    true_w = rng.normal(size=8)
    baseline.fit(obs, t, baseline.features(obs, t) @ true_w)
    np.testing.assert_allclose(baseline.weights, true_w, rtol=1e-6, atol=1e-8)


def test_linear_baseline_ridge_closed_form() -> None:
    baseline = LinearFeatureBaseline(l2_reg=2.0)
    obs, t, y = np.array([[1.0], [2.0], [3.0]]), np.array([0, 1, 2]), np.array([1.0, 0.0, 2.0])
    baseline.fit(obs, t, y)
    x = baseline.features(obs, t)
    expected = np.linalg.solve(x.T @ x + 2.0 * np.eye(x.shape[1]), x.T @ y)
    np.testing.assert_allclose(baseline.weights, expected, rtol=1e-8)
    np.testing.assert_allclose(baseline.predict(obs, t), x @ expected, rtol=1e-6)
    assert np.all(LinearFeatureBaseline().predict(obs, t) == 0)
    with pytest.raises(ValueError, match="l2_reg"):
        LinearFeatureBaseline(l2_reg=-1.0)
