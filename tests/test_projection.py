"""TRPOPlus' projected trust region (``policy_update="projection"``, sb3_trpo_plus/algorithm/projection.py): the
projections against hand-computed values and finite differences, and every update inside its trust region."""

import math
import pathlib
import unittest.mock

import numpy as np
import pytest
import torch as th
from scipy.optimize import brentq
from stable_baselines3.common.env_util import make_vec_env

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.projection import (
    covariance_part,
    gaussian_kl,
    mean_part,
    project_mean,
    project_std,
)
from sb3_trpo_plus.common.arguments import ArgumentError

TINY = dict(n_steps=64, batch_size=64, n_critic_updates=2, policy_kwargs=dict(net_arch=[16]))


def test_mean_outside_the_bound_lands_on_it() -> None:
    # m = (2 - 0)^2 / (2 * 1^2) = 2 > 0.5: w = sqrt(2 / 0.5) - 1 = 1, the mean halfway back: 1
    mean = th.tensor([[2.0, 0.0]])
    projected = project_mean(mean, th.zeros(1, 2), th.ones(1, 2), 0.5)
    np.testing.assert_allclose(projected.numpy(), [[1.0, 0.0]], atol=1e-7)
    assert float(mean_part(projected, th.zeros(1, 2), th.ones(1, 2))) == pytest.approx(0.5)


def test_mean_inside_the_bound_is_unchanged_with_a_unit_derivative() -> None:
    mean = th.tensor([[0.3, -0.2]], requires_grad=True)
    projected = project_mean(mean, th.zeros(1, 2), th.ones(1, 2), 0.5)
    assert th.equal(projected.detach(), mean.detach())
    projected.sum().backward()
    assert mean.grad is not None
    np.testing.assert_array_equal(mean.grad.numpy(), [[1.0, 1.0]])


def test_std_outside_the_bound_lands_on_it() -> None:
    # one dimension, old std 1, new std 2 (part 0.5 (4 - 1 - log 4) = 0.807): the projected variance r solves
    # 0.5 (r - 1 - log r) = 0.1 with r > 1
    r = brentq(lambda x: 0.5 * (x - 1.0 - math.log(x)) - 0.1, 1.0, 4.0)
    projected = project_std(th.tensor([[2.0]], dtype=th.float64), th.ones(1, 1, dtype=th.float64), 0.1)
    assert float(projected) ** 2 == pytest.approx(r, rel=1e-9)
    # a shrinking std: r < 1
    r_low = brentq(lambda x: 0.5 * (x - 1.0 - math.log(x)) - 0.1, 1e-6, 1.0)
    projected = project_std(th.tensor([[0.2]], dtype=th.float64), th.ones(1, 1, dtype=th.float64), 0.1)
    assert float(projected) ** 2 == pytest.approx(r_low, rel=1e-9)


def test_projections_keep_every_state_within_its_bounds() -> None:
    generator = th.Generator().manual_seed(0)
    old_mean = th.randn(200, 3, generator=generator)
    old_std = th.exp(0.5 * th.randn(200, 3, generator=generator))
    mean = old_mean + th.randn(200, 3, generator=generator)
    std = old_std * th.exp(th.randn(200, 3, generator=generator))
    projected_mean = project_mean(mean, old_mean, old_std, 0.05)
    projected_std = project_std(std, old_std, 0.02)
    assert float(mean_part(projected_mean, old_mean, old_std).max()) <= 0.05 * (1 + 1e-5)
    assert float(covariance_part(projected_std, old_std).max()) <= 0.02 * (1 + 1e-5)
    inside = mean_part(mean, old_mean, old_std) <= 0.05
    assert bool(inside.any()) and th.equal(projected_mean[inside], mean[inside])
    # the whole KL of the projected policy is within the sum of the two bounds
    assert float(gaussian_kl(projected_mean, projected_std, old_mean, old_std).max()) <= 0.07 * (1 + 1e-5)


def test_projection_gradients_match_finite_differences() -> None:
    generator = th.Generator().manual_seed(1)
    old_mean = th.randn(4, 2, generator=generator, dtype=th.float64)
    old_std = th.exp(0.3 * th.randn(4, 2, generator=generator, dtype=th.float64))
    mean = (old_mean + 2.0 * th.randn(4, 2, generator=generator, dtype=th.float64)).requires_grad_()
    std = (old_std * th.exp(th.randn(4, 2, generator=generator, dtype=th.float64))).requires_grad_()
    assert bool((covariance_part(std, old_std) > 0.01).all())  # every state projected: the implicit derivative
    assert th.autograd.gradcheck(lambda m: project_mean(m, old_mean, old_std, 0.01), (mean,))
    assert th.autograd.gradcheck(lambda s: project_std(s, old_std, 0.01), (std,), atol=1e-6)


def test_a_shared_covariance_is_solved_once_with_the_same_result() -> None:
    # SB3's state-independent log-std: every row the same; the one solve gives each row what its own solve gives
    log_std = th.tensor([0.4, -0.9, 0.1], requires_grad=True)
    old_std = th.ones(64, 3) * th.tensor([0.2, 0.1, 0.5]).exp()
    shared = project_std(th.ones(64, 3) * log_std.exp(), old_std, 0.05)
    (gradient,) = th.autograd.grad((shared * th.arange(192.0).reshape(64, 3)).sum(), log_std)
    std = th.ones(64, 3) * log_std.exp()
    rows = [project_std(std[i : i + 1], old_std[i : i + 1], 0.05) for i in range(64)]
    assert th.equal(shared, th.cat(rows))
    (row_gradient,) = th.autograd.grad((th.cat(rows) * th.arange(192.0).reshape(64, 3)).sum(), log_std)
    np.testing.assert_allclose(gradient.numpy(), row_gradient.numpy(), rtol=1e-6)


def _bisection_multiplier(precision: th.Tensor, old_precision: th.Tensor, bound: float, iterations: int) -> th.Tensor:
    """The slow reference: 80 halvings of log(eta) in [-30, 30], the bracket's upper end."""
    from sb3_trpo_plus.algorithm import projection

    low = th.full(precision.shape[:-1], -30.0, dtype=th.float64)
    high = th.full_like(low, 30.0)
    for _ in range(80):
        middle = (low + high) / 2.0
        above = projection._covariance_part_at(precision, old_precision, th.exp(middle).unsqueeze(-1)) > bound
        low, high = th.where(above, middle, low), th.where(above, high, middle)
    return th.exp(high)


def test_the_newton_solve_gives_the_bisections_projection() -> None:
    generator = th.Generator().manual_seed(2)
    old_std = th.exp(0.5 * th.randn(2000, 4, generator=generator))
    std = old_std * th.exp(th.randn(2000, 4, generator=generator))
    fast = project_std(std, old_std, 0.01)
    with unittest.mock.patch("sb3_trpo_plus.algorithm.projection._solve_multiplier", _bisection_multiplier):
        slow = project_std(std, old_std, 0.01)
    assert bool((covariance_part(std, old_std) > 0.01).sum() > 1500)
    np.testing.assert_allclose(fast.numpy(), slow.numpy(), rtol=1e-6)
    assert float((fast != slow).float().mean()) < 0.01  # float32: the same value almost everywhere


def test_learning_with_the_newton_solve_equals_the_bisection() -> None:
    fast = _make(projection_epochs=2, projection_minibatches=4, sample_reuse="generalized").learn(1024)
    with unittest.mock.patch("sb3_trpo_plus.algorithm.projection._solve_multiplier", _bisection_multiplier):
        slow = _make(projection_epochs=2, projection_minibatches=4, sample_reuse="generalized").learn(1024)
    for (name, a), b in zip(fast.policy.state_dict().items(), slow.policy.state_dict().values(), strict=True):
        np.testing.assert_allclose(a.numpy(), b.numpy(), rtol=1e-5, atol=1e-7, err_msg=name)


@pytest.mark.parametrize("bound", [0.0, -1.0, math.inf, math.nan])
def test_bad_bound_is_named(bound: float) -> None:
    with pytest.raises(ValueError, match="bound"):
        project_mean(th.zeros(1, 1), th.zeros(1, 1), th.ones(1, 1), bound)
    with pytest.raises(ValueError, match="bound"):
        project_std(th.ones(1, 1), th.ones(1, 1), bound)


def _make(**kwargs: object) -> TRPOPlus:
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=3)
    kwargs = {"policy_update": "projection", **kwargs}
    return TRPOPlus("MlpPolicy", env, seed=3, **TINY, **kwargs)  # type: ignore[arg-type]


@pytest.mark.parametrize("variant", [dict(), dict(sample_reuse="generalized", covariance_kl=0.002)])
def test_every_update_stays_in_the_trust_region(variant: dict) -> None:
    model = _make(projection_epochs=4, projection_minibatches=4, projection_learning_rate=3e-3, **variant)
    update = model.update_policy
    seen: list[tuple[float, float, bool]] = []

    def measured(batch, radius=None):  # type: ignore[no-untyped-def]
        with th.no_grad():
            before = model.policy.get_distribution(batch.observations).distribution
            old_mean, old_std = before.mean.clone(), before.stddev.clone()
        start = [p.detach().clone() for p in model.policy.parameters()]
        result = update(batch, radius)
        with th.no_grad():
            after = model.policy.get_distribution(batch.observations).distribution
            kl = gaussian_kl(after.mean, after.stddev, old_mean, old_std)
            weights = batch.sample_weights
            mean_kl = float((kl * weights).mean() if weights is not None else kl.mean())
        used = model.current_target_kl if radius is None else radius
        bound = used + (model.covariance_radius(used) or used)
        moved = any(not th.equal(a, b) for a, b in zip(start, model.policy.parameters(), strict=True))
        seen.append((mean_kl, bound, moved and result.line_search.accepted))
        assert result.line_search.kl == pytest.approx(mean_kl, rel=1e-5, abs=1e-9)
        return result

    model.update_policy = measured  # type: ignore[method-assign]
    model.learn(6 * 128)
    assert len(seen) == 6
    assert all(kl <= bound * (1 + 1e-6) for kl, bound, _ in seen)
    assert sum(accepted for *_, accepted in seen) >= 3  # the updates move the policy, not all undone
    assert model.logger.name_to_value["train/projection_skipped_steps"] == 0
    for param in model.policy.parameters():
        assert bool(th.isfinite(param).all())


def test_a_non_finite_loss_never_reaches_the_weights() -> None:
    model = _make(projection_epochs=2, projection_minibatches=2)
    nan = th.tensor(math.nan, requires_grad=True)
    start = [p.detach().clone() for p in model.policy.parameters()]
    with unittest.mock.patch("sb3_trpo_plus.algorithm.projection.projection_loss", lambda *args: nan * 1.0):
        model.learn(128)
    actor = {id(p) for p in model._actor_params}
    for before, param in zip(start, model.policy.parameters(), strict=True):
        if id(param) in actor:
            assert th.equal(before, param.detach())
    assert model.logger.name_to_value["train/projection_skipped_steps"] == 4


def test_save_load_keeps_the_settings_and_the_optimizer(tmp_path: pathlib.Path) -> None:
    model = _make(projection_epochs=2, projection_minibatches=3, projection_learning_rate=1e-3).learn(128)
    model.save(tmp_path / "model")
    loaded = TRPOPlus.load(tmp_path / "model.zip")
    assert (loaded.projection_epochs, loaded.projection_minibatches, loaded.projection_learning_rate) == (2, 3, 1e-3)
    assert loaded.policy_update == "projection"
    assert model.projection_optimizer is not None and loaded.projection_optimizer is not None
    saved, restored = model.projection_optimizer.state_dict(), loaded.projection_optimizer.state_dict()
    assert restored["param_groups"][0]["lr"] == 1e-3
    assert set(restored["state"]) == set(saved["state"]) and saved["state"]
    for key, state in saved["state"].items():
        np.testing.assert_array_equal(restored["state"][key]["exp_avg"].numpy(), state["exp_avg"].numpy())


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("projection_epochs", 0),
        ("projection_epochs", 1.5),
        ("projection_minibatches", True),
        ("projection_learning_rate", 0.0),
        ("projection_learning_rate", math.nan),
        ("projection_regression", -1.0),
        ("projection_max_grad_norm", 0.0),
        ("policy_update", "projected"),
    ],
)
def test_bad_settings_are_named(name: str, value: object) -> None:
    with pytest.raises(ArgumentError, match=name):
        _make(**{name: value})


@pytest.mark.parametrize("conflict", [dict(cg_warm_start=True), dict(fisher_sub_sampling=4)])
def test_conjugate_gradient_settings_are_refused(conflict: dict) -> None:
    with pytest.raises(ArgumentError, match=f"policy_update='projection'.*{next(iter(conflict))}"):
        _make(**conflict)


def test_projection_settings_without_the_projection_are_refused() -> None:
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=3)
    with pytest.raises(ArgumentError, match=r"\['projection_epochs'\] set the projected trust region"):
        TRPOPlus("MlpPolicy", env, projection_epochs=3, **TINY)  # type: ignore[arg-type]
    assert TRPOPlus("MlpPolicy", env, **TINY).projection_optimizer is None  # type: ignore[arg-type]


def test_a_policy_that_is_no_diagonal_gaussian_is_refused() -> None:
    env = make_vec_env("CartPole-v1", n_envs=2, seed=0)
    with pytest.raises(ArgumentError, match="diagonal Gaussian"):
        TRPOPlus("MlpPolicy", env, policy_update="projection", **TINY)  # type: ignore[arg-type]
