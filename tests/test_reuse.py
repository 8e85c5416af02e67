"""Sample reuse numerics (sb3_trpo_plus.algorithm.reuse): the batch weights and off-policy GAE."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from sb3_trpo_plus.algorithm.replay import compute_gae
from sb3_trpo_plus.algorithm.reuse import reuse_weights, vtrace_gae


def _brute_force(batches: float, max_batches: int) -> np.ndarray:
    """The quadratic programme solved on every support: the least-norm v on it under both equalities, kept where
    v >= 0; the smallest norm wins."""
    best, best_norm = None, np.inf
    for size in range(1, max_batches + 1):
        for support in itertools.combinations(range(1, max_batches + 1), size):
            i = np.array(support, dtype=np.float64)
            constraints = np.stack([np.ones_like(i), i])
            v, *_ = np.linalg.lstsq(constraints, np.array([1.0, batches]), rcond=None)
            # lstsq gives the least-norm solution of the equalities on this support, where one exists
            if np.allclose(constraints @ v, [1.0, batches], atol=1e-10) and v.min() >= -1e-12 and v @ v < best_norm:
                best, best_norm = np.zeros(max_batches), v @ v
                best[np.array(support) - 1] = v
    assert best is not None
    return best


def test_gepps_defaults_give_four_batches_weighted_four_three_two_one() -> None:
    result = reuse_weights(2, 10)
    np.testing.assert_allclose(result.weights, [0.4, 0.3, 0.2, 0.1], atol=1e-12)
    assert result.n_batches == 4 and result.trust_scale == pytest.approx(0.5)


@pytest.mark.parametrize(("batches", "max_batches"), [(1.5, 6), (2, 10), (2.5, 8), (3, 8), (1.2, 4), (4.5, 8)])
def test_weights_are_the_brute_force_optimum(batches: float, max_batches: int) -> None:
    expected = _brute_force(batches, max_batches)
    expected = expected[expected > 0.01]
    expected /= expected.sum()
    result = reuse_weights(batches, max_batches)
    np.testing.assert_allclose(result.weights, expected, atol=1e-9)
    assert result.weights.sum() == pytest.approx(1.0)
    assert result.trust_scale == pytest.approx(1.0 / np.dot(result.weights, np.arange(1, result.n_batches + 1)))


def test_one_batch_is_on_policy() -> None:
    result = reuse_weights(1, 10)
    assert result.weights.tolist() == [1.0] and result.trust_scale == 1.0
    assert result.per_sample(1).tolist() == [1.0]


def test_per_sample_weights_average_one_over_the_batches_at_hand() -> None:
    result = reuse_weights(2, 10)
    np.testing.assert_allclose(result.per_sample(4), [1.6, 1.2, 0.8, 0.4])
    np.testing.assert_allclose(result.per_sample(2), [8 / 7, 6 / 7])
    with pytest.raises(ValueError, match="n_present"):
        result.per_sample(5)


@pytest.mark.parametrize(
    ("batches", "max_batches", "message"),
    [
        (0.5, 10, "batches must be in"),
        (6, 10, "batches must be in"),
        (2, 0, "max_batches"),
        (True, 4, "batches"),
        (float("nan"), 4, "finite"),
        (2, 2.5, "max_batches"),
    ],
)
def test_bad_settings_are_named(batches: object, max_batches: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        reuse_weights(batches, max_batches)  # type: ignore[arg-type]


def _segment(seed: int = 0, n_steps: int = 12, n_envs: int = 3) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "rewards": rng.normal(size=(n_steps, n_envs)).astype(np.float32),
        "values": rng.normal(size=(n_steps, n_envs)).astype(np.float32),
        "dones": rng.random((n_steps, n_envs)) < 0.2,
        "last_values": rng.normal(size=n_envs).astype(np.float32),
    }


def test_with_every_ratio_one_it_is_on_policy_gae() -> None:
    data = _segment()
    ones = np.ones_like(data["rewards"])
    advantages, returns = vtrace_gae(**data, trace_ratios=ones, gamma=0.9, gae_lambda=0.8)
    starts = np.concatenate([np.ones((1, 3)), data["dones"][:-1]]).astype(np.float32)  # the step after a done starts
    expected_advantages, expected_returns = compute_gae(
        data["rewards"], data["values"], starts, data["last_values"], data["dones"][-1], 0.9, 0.8
    )
    np.testing.assert_allclose(advantages, expected_advantages, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(returns, expected_returns, rtol=1e-6, atol=1e-6)


def test_vtrace_by_hand() -> None:
    """One env, three steps, no episode end: gamma = lambda = 0.5, c = (0.5, 0.25, 1).
    delta = r + 0.5 V' - V with V = (1, 2, 3), V_last = 4, r = (1, 1, 1): delta = (1, 0.5, 0).
    A_2 = 0; A_1 = 0.5 + 0.25 * c_2 * A_2 = 0.5; A_0 = 1 + 0.25 * c_1 * A_1 = 1 + 0.25 * 0.25 * 0.5 = 1.03125.
    Targets A * c + V: (1.515625, 2.125, 3)."""
    advantages, returns = vtrace_gae(
        rewards=np.ones((3, 1), np.float32),
        values=np.array([[1.0], [2.0], [3.0]], np.float32),
        dones=np.zeros((3, 1), bool),
        last_values=np.array([4.0], np.float32),
        trace_ratios=np.array([[0.5], [0.25], [1.0]], np.float32),
        gamma=0.5,
        gae_lambda=0.5,
    )
    np.testing.assert_allclose(advantages[:, 0], [1.03125, 0.5, 0.0])
    np.testing.assert_allclose(returns[:, 0], [1.515625, 2.125, 3.0])


def test_an_episode_end_cuts_the_trace() -> None:
    data = _segment(seed=1)
    data["dones"][:] = False
    data["dones"][5] = True
    ratios = np.full_like(data["rewards"], 0.5)
    a, _ = vtrace_gae(**data, trace_ratios=ratios, gamma=0.9, gae_lambda=0.8)
    data["rewards"][6:] += 100.0  # what happens after the episode end does not reach its steps
    data["last_values"] += 100.0
    b, _ = vtrace_gae(**data, trace_ratios=ratios, gamma=0.9, gae_lambda=0.8)
    np.testing.assert_array_equal(a[:6], b[:6])


def test_the_generalized_radius_by_hand() -> None:
    """``target_kl * trust_scale**2`` (B = 2: 0.01 / 4), or GeTRPO's eps_vary: ``(sqrt(2 * 0.01) - spent)**2 / 2``,
    and 0 once the spent distance reaches epsilon."""
    from sb3_trpo_plus.algorithm.generalized import reuse_radius

    assert reuse_radius(0.01, 0.5, spent=0.3, kl_vary=False) == pytest.approx(0.0025, rel=1e-12)
    assert reuse_radius(0.01, 0.5, spent=0.04, kl_vary=True) == pytest.approx((0.1414213562373095 - 0.04) ** 2 / 2, rel=1e-12)
    assert reuse_radius(0.01, 0.5, spent=0.0, kl_vary=True) == pytest.approx(0.01, rel=1e-12)
    assert reuse_radius(0.01, 0.5, spent=0.2, kl_vary=True) == 0.0
