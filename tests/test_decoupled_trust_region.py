"""``covariance_kl``: the trust region of a diagonal Gaussian policy decoupled into the mean's and the covariance's
(MPO's split of the KL), the split by hand, and an update that keeps each part within its own radius."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.distributions import DiagGaussianDistribution, kl_divergence
from stable_baselines3.common.env_util import make_vec_env

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.update import decoupled_gaussian_kl
from sb3_trpo_plus.common.arguments import ArgumentError

TINY = dict(n_steps=128, batch_size=64, n_critic_updates=2, cg_max_steps=10, policy_kwargs=dict(net_arch=[16]), seed=4)


def _gaussian(mean: list[float], std: list[float]) -> DiagGaussianDistribution:
    distribution = DiagGaussianDistribution(len(mean))
    return distribution.proba_distribution(th.tensor([mean]), th.log(th.tensor([std])))


def test_the_split_by_hand() -> None:
    """old N(0, 1), new N(1, 2): mean part 1 / 2; covariance part log(1 / 2) + 4 / 2 - 1 / 2."""
    mean_kl, std_kl = decoupled_gaussian_kl(_gaussian([0.0], [1.0]), _gaussian([1.0], [2.0]))
    assert float(mean_kl) == pytest.approx(0.5)
    assert float(std_kl) == pytest.approx(math.log(0.5) + 2.0 - 0.5)


def test_the_parts_add_up_to_the_kl_trpo_bounds() -> None:
    old, new = _gaussian([0.3, -1.0], [0.5, 1.5]), _gaussian([1.1, 0.2], [0.2, 3.0])
    mean_kl, std_kl = decoupled_gaussian_kl(old, new)
    np.testing.assert_allclose(mean_kl + std_kl, kl_divergence(new, old), rtol=1e-6)  # SB3's order: KL(new || old)
    same_std, same_mean = _gaussian([1.1, 0.2], [0.5, 1.5]), _gaussian([0.3, -1.0], [0.2, 3.0])
    assert float(decoupled_gaussian_kl(old, same_std)[1].abs().max()) < 1e-7
    assert float(decoupled_gaussian_kl(old, same_mean)[0].abs().max()) == 0.0


def _std_kl_of_one_update(covariance_kl: float | None) -> tuple[float, float, float]:
    """(covariance KL, mean KL, whole KL) of the first update on Pendulum, each a mean over the rollout."""
    model = TRPOPlus("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=2, seed=4), covariance_kl=covariance_kl, **TINY)
    model.learn(model.n_steps * 2)  # one rollout, then...
    observations = th.as_tensor(model.rollout_buffer.observations.reshape(-1, 3))

    def distribution() -> DiagGaussianDistribution:
        with th.no_grad():
            mean = model.policy.get_distribution(observations).distribution.mean
            return DiagGaussianDistribution(1).proba_distribution(mean.clone(), model.policy.log_std.detach().clone())

    before = distribution()
    model.train()  # ... one update on it
    after = distribution()
    mean_kl, std_kl = decoupled_gaussian_kl(before, after)
    return float(std_kl.mean()), float(mean_kl.mean()), float(kl_divergence(after, before).mean())


def test_the_covariance_moves_within_its_own_radius() -> None:
    """With a radius 1,000 times narrower for the covariance, the log-std's KL stays within it while the mean still
    moves up to target_kl; with one trust region (the option off) the same update moves the log-std far more."""
    narrow = 1e-5
    std_kl, mean_kl, _ = _std_kl_of_one_update(covariance_kl=narrow)
    assert std_kl <= narrow * (1 + 1e-3)
    assert 1e-4 < mean_kl <= 0.01 * (1 + 1e-3)  # sb3-contrib's default target_kl
    coupled_std_kl, _, coupled_kl = _std_kl_of_one_update(covariance_kl=None)
    assert coupled_std_kl > 10 * narrow and coupled_kl <= 0.01 * (1 + 1e-3)


def test_it_needs_a_diagonal_gaussian_policy() -> None:
    with pytest.raises(ArgumentError, match="covariance_kl decouples the trust region of a diagonal Gaussian policy"):
        TRPOPlus("MlpPolicy", make_vec_env("CartPole-v1", n_envs=1), covariance_kl=0.01, **TINY)
    with pytest.raises(ArgumentError, match="StateDependentNoiseDistribution"):
        TRPOPlus("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=1), covariance_kl=0.01, use_sde=True, **TINY)
    with pytest.raises(ArgumentError, match=r"`covariance_kl` must be None or a finite number > 0, got 0"):
        TRPOPlus("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=1), covariance_kl=0, **TINY)


def test_the_covariance_radius_narrows_with_the_generalized_radius(monkeypatch: pytest.MonkeyPatch) -> None:
    """Generalized sample reuse steps within a radius below target_kl; the covariance's radius keeps its ratio to the
    mean's (twice here), so that neither part outruns the other."""
    import sb3_trpo_plus.algorithm.trpo_plus as trpo_plus_module

    seen: list[tuple[float, float, float | None]] = []
    original = trpo_plus_module.natural_gradient_step

    def recording(*args, **kwargs):  # type: ignore[no-untyped-def]
        seen.append((kwargs["step_kl"], kwargs["max_kl"], kwargs["covariance_kl"]))
        return original(*args, **kwargs)

    monkeypatch.setattr(trpo_plus_module, "natural_gradient_step", recording)
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=4)
    model = TRPOPlus("MlpPolicy", env, sample_reuse="generalized", reuse_batches=2, covariance_kl=0.02, target_kl=0.01, **TINY)
    model.learn(model.n_steps * 2 * 3)
    assert len(seen) == 3 and any(step_kl < 0.01 for step_kl, _, _ in seen)  # the reuse radius is narrower
    for step_kl, max_kl, covariance_kl in seen:
        assert step_kl == max_kl and covariance_kl == pytest.approx(2 * step_kl)
