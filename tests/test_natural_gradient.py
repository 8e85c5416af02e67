"""Conjugate gradient, Fisher-vector products, line search and flat-parameter helpers."""

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn
from torch.func import functional_call

from sb3_trpo_plus.algorithm.natural_gradient import (
    backtracking_line_search,
    conjugate_gradient,
    fisher_vector_product,
    flat_gradient,
    flat_parameters,
    set_flat_parameters,
)
from sb3_trpo_plus.algorithm.trpo_plus import actor_parameters


def _spd(n: int, seed: int = 0) -> th.Tensor:
    g = th.Generator().manual_seed(seed)
    q = th.randn(n, n, generator=g, dtype=th.float64)
    return q @ q.T + 0.5 * th.eye(n, dtype=th.float64)


# ----------------------------------------------------------------------------- conjugate gradient
def test_cg_solves_spd_system() -> None:
    a = _spd(8)
    b = th.arange(1.0, 9.0, dtype=th.float64)
    result = conjugate_gradient(lambda v: a @ v, b, max_iter=50, residual_tol=1e-24)
    np.testing.assert_allclose(result.solution.numpy(), np.linalg.solve(a.numpy(), b.numpy()), rtol=1e-8)
    assert result.residual_norm < 1e-10
    assert result.iterations <= 12
    assert result.quadratic_form == pytest.approx(float(result.solution @ a @ result.solution), rel=1e-8)


def test_cg_hand_computed_two_by_two() -> None:
    # A = diag(2, 4), b = (2, 4): one CG step from 0 along r0 = b gives alpha = 20/72
    a = th.tensor([[2.0, 0.0], [0.0, 4.0]], dtype=th.float64)
    b = th.tensor([2.0, 4.0], dtype=th.float64)
    one = conjugate_gradient(lambda v: a @ v, b, max_iter=1)
    np.testing.assert_allclose(one.solution.numpy(), (20.0 / 72.0) * b.numpy())
    assert one.iterations == 1 and one.matvecs == 1
    # residual b - A x after the step: (2 - 2 * 20/72 * 2, 4 - 4 * 20/72 * 4) = (8/9, -4/9)
    np.testing.assert_allclose(one.residual_norms, [np.sqrt(20.0), np.sqrt(80.0) / 9.0])
    assert one.residual_norms[-1] == pytest.approx(one.residual_norm)
    two = conjugate_gradient(lambda v: a @ v, b, max_iter=2, residual_tol=1e-30)
    np.testing.assert_allclose(two.solution.numpy(), [1.0, 1.0], atol=1e-12)


def test_cg_stops_at_once_from_exact_solution() -> None:
    a = _spd(6, seed=1)
    x_star = th.linspace(-1, 1, 6, dtype=th.float64)
    b = a @ x_star
    result = conjugate_gradient(lambda v: a @ v, b, x0=x_star, max_iter=10, residual_tol=1e-20)
    assert result.iterations == 0
    assert result.matvecs == 1  # only the residual of the warm start
    np.testing.assert_allclose(result.solution.numpy(), x_star.numpy())


def test_cg_needs_fewer_iterations_from_nearby_start() -> None:
    a = _spd(30, seed=2)
    x_star = th.randn(30, generator=th.Generator().manual_seed(3), dtype=th.float64)
    b = a @ x_star
    kwargs = dict(max_iter=200, residual_tol=1e-16)
    cold = conjugate_gradient(lambda v: a @ v, b, **kwargs)
    warm = conjugate_gradient(lambda v: a @ v, b, x0=x_star + 1e-3 * th.ones(30, dtype=th.float64), **kwargs)
    assert warm.iterations < cold.iterations


def test_cg_warm_start_rescale_is_line_minimiser() -> None:
    a = _spd(5, seed=4)
    b = th.ones(5, dtype=th.float64)
    x0 = th.tensor([1.0, -2.0, 0.5, 3.0, 1.0], dtype=th.float64)
    # one iteration after rescaling: compare with doing the rescale by hand and then one CG step
    scale = float(x0 @ b / (x0 @ a @ x0))
    manual = conjugate_gradient(lambda v: a @ v, b, x0=scale * x0, max_iter=1)
    rescaled = conjugate_gradient(lambda v: a @ v, b, x0=x0, max_iter=1, warm_start_rescale=True)
    np.testing.assert_allclose(rescaled.solution.numpy(), manual.solution.numpy(), rtol=1e-10)
    assert rescaled.matvecs == 2  # the rescaling reuses the warm start's product


def test_cg_rejects_bad_max_iter() -> None:
    with pytest.raises(ValueError, match="max_iter"):
        conjugate_gradient(lambda v: v, th.ones(2), max_iter=0)


# ----------------------------------------------------------------------------- Fisher-vector product
class _DistributionParameters(nn.Module):
    """Wraps a policy so that ``functional_call`` can evaluate its action distribution."""

    def __init__(self, policy: ActorCriticPolicy):
        super().__init__()
        self.policy = policy

    def forward(self, obs: th.Tensor) -> th.distributions.Distribution:
        return self.policy.get_distribution(obs).distribution


def _explicit_fisher(policy: ActorCriticPolicy, obs: th.Tensor) -> th.Tensor:
    """Hessian at theta0 of sb3-contrib's KL, ``kl_divergence(pi_theta, pi_theta0).mean()``, entry by entry.

    torch's KL of a ``Normal`` is per action dimension, so that mean runs over samples *and* dimensions;
    a ``Categorical``'s is per sample.
    """
    params = actor_parameters(policy)
    names = {id(p): n for n, p in policy.named_parameters()}
    keys = [f"policy.{names[id(p)]}" for p in params]
    shapes = [p.shape for p in params]
    theta0 = flat_parameters(params)
    wrapper = _DistributionParameters(policy)
    with th.no_grad():
        anchor = wrapper(obs)

    def kl(flat: th.Tensor) -> th.Tensor:
        chunks = th.split(flat, [int(np.prod(s)) for s in shapes])
        new = functional_call(wrapper, {k: c.view(s) for k, c, s in zip(keys, chunks, shapes, strict=True)}, (obs,))
        return th.distributions.kl_divergence(new, anchor).mean()  # at theta0 the Hessian of either direction

    return th.autograd.functional.hessian(kl, theta0)


@pytest.mark.parametrize("action_space", [spaces.Box(-1, 1, (2,)), spaces.Discrete(3)], ids=["gaussian", "categorical"])
def test_fisher_vector_product_equals_explicit_fisher(action_space: spaces.Space) -> None:
    th.manual_seed(0)
    observation_space = spaces.Box(-1, 1, (3,))
    policy = ActorCriticPolicy(observation_space, action_space, lambda _: 1e-3, net_arch=[4], log_std_init=-0.3)
    obs = th.randn(7, 3)
    fisher = _explicit_fisher(policy, obs)
    params = actor_parameters(policy)
    fvp = fisher_vector_product(policy.get_distribution(obs), params, damping=0.0)
    damped = fisher_vector_product(policy.get_distribution(obs), params, damping=0.1)
    for seed in range(3):
        v = th.randn(fisher.shape[0], generator=th.Generator().manual_seed(seed))
        np.testing.assert_allclose(fvp(v).detach().numpy(), (fisher @ v).numpy(), rtol=1e-4, atol=1e-6)
        np.testing.assert_allclose(damped(v).detach().numpy(), (fisher @ v + 0.1 * v).numpy(), rtol=1e-4, atol=1e-6)
    assert th.linalg.matrix_norm(fisher) > 0.1  # a non-trivial Fisher


def test_fisher_vector_product_gsde() -> None:
    th.manual_seed(1)
    policy = ActorCriticPolicy(spaces.Box(-1, 1, (3,)), spaces.Box(-1, 1, (2,)), lambda _: 1e-3, net_arch=[4], use_sde=True)
    obs = th.randn(5, 3)
    fisher = _explicit_fisher(policy, obs)
    fvp = fisher_vector_product(policy.get_distribution(obs), actor_parameters(policy))
    v = th.randn(fisher.shape[0])
    np.testing.assert_allclose(fvp(v).detach().numpy(), (fisher @ v).numpy(), rtol=1e-3, atol=1e-5)


# ----------------------------------------------------------------------------- flat helpers
def test_flat_parameter_round_trip_and_gradient() -> None:
    params = [nn.Parameter(th.ones(2, 3)), nn.Parameter(th.zeros(4)), nn.Parameter(th.ones(1))]
    flat = flat_parameters(params)
    assert flat.shape == (11,)
    set_flat_parameters(params, th.arange(11.0))
    np.testing.assert_array_equal(flat_parameters(params).numpy(), np.arange(11.0))
    with pytest.raises(ValueError, match="entries"):
        set_flat_parameters(params, th.zeros(3))
    loss = (params[0] ** 2).sum() + 3 * params[1].sum()  # params[2] unused: zero gradient
    grad = flat_gradient(loss, params)
    np.testing.assert_allclose(grad.numpy(), np.concatenate([2 * np.arange(6.0), 3 * np.ones(4), [0.0]]))


# ----------------------------------------------------------------------------- line search
def _quadratic_problem():
    theta = nn.Parameter(th.tensor([0.0, 0.0]))

    def evaluate(kl_scale: float = 1.0, broken: bool = False):
        def fn() -> tuple[float, float]:
            x = theta.detach()
            objective = float(-((x - 1.0) ** 2).sum())
            kl = float(kl_scale * (x**2).sum())
            return (float("nan"), kl) if broken else (objective, kl)

        return fn

    return theta, evaluate


def test_line_search_accepts_first_point_within_trust_region() -> None:
    theta, evaluate = _quadratic_problem()
    # full step (2, 2) gives KL 8 > 0.5; shrinking by 0.5: (1, 1) KL 2, (0.5, 0.5) KL 0.5 -> accepted
    result = backtracking_line_search([theta], th.tensor([2.0, 2.0]), evaluate(), -2.0, 0.5, 0.5, 10)
    assert result.accepted and result.steps == 3 and result.coefficient == 0.25
    np.testing.assert_allclose(theta.detach().numpy(), [0.5, 0.5])
    assert result.kl == pytest.approx(0.5) and result.objective == pytest.approx(-0.5)


def test_line_search_restores_parameters_exactly_on_failure() -> None:
    theta, evaluate = _quadratic_problem()
    with th.no_grad():
        theta.copy_(th.tensor([0.1234567, -7.654321]))
    before = theta.detach().clone()
    # moving away from the optimum never improves the objective
    result = backtracking_line_search([theta], th.tensor([-1.0, 5.0]), evaluate(), 0.0, 10.0, 0.5, 4)
    assert not result.accepted and result.steps == 4 and result.coefficient == 0.0
    assert th.equal(theta.detach(), before)


@pytest.mark.parametrize("step", [th.tensor([1.0, float("nan")]), th.tensor([float("inf"), 0.0])])
def test_line_search_rejects_nonfinite_step(step: th.Tensor) -> None:
    theta, evaluate = _quadratic_problem()
    before = theta.detach().clone()
    result = backtracking_line_search([theta], step, evaluate(), -2.0, 1.0)
    assert not result.accepted and result.nonfinite
    assert th.equal(theta.detach(), before)


def test_line_search_rejects_nonfinite_objective() -> None:
    theta, evaluate = _quadratic_problem()
    before = theta.detach().clone()
    result = backtracking_line_search([theta], th.tensor([0.5, 0.5]), evaluate(broken=True), -2.0, 1.0, 0.5, 3)
    assert not result.accepted and result.nonfinite
    assert th.equal(theta.detach(), before)


def test_fisher_sub_sampling_error_is_bounded() -> None:
    """The Fisher estimated on every 4th state of a large batch stays close to the full one."""
    th.manual_seed(3)
    policy = ActorCriticPolicy(spaces.Box(-1, 1, (4,)), spaces.Box(-1, 1, (2,)), lambda _: 1e-3, net_arch=[16])
    obs = th.randn(4096, 4)
    params = actor_parameters(policy)
    full = fisher_vector_product(policy.get_distribution(obs), params)
    sub = fisher_vector_product(policy.get_distribution(obs[::4]), params)
    for seed in range(5):
        v = th.randn(sum(p.numel() for p in params), generator=th.Generator().manual_seed(seed))
        exact, approx = full(v), sub(v)
        relative = float(th.linalg.vector_norm(approx - exact) / th.linalg.vector_norm(exact))
        assert relative < 0.1, relative
    # and the natural-gradient direction it gives is nearly the same
    g = th.randn(sum(p.numel() for p in params), generator=th.Generator().manual_seed(9))
    x_full = conjugate_gradient(lambda v: full(v) + 0.1 * v, g, max_iter=20).solution
    x_sub = conjugate_gradient(lambda v: sub(v) + 0.1 * v, g, max_iter=20).solution
    cosine = float(x_full @ x_sub / (th.linalg.vector_norm(x_full) * th.linalg.vector_norm(x_sub)))
    assert cosine > 0.98, cosine


@pytest.mark.parametrize("action_space", [spaces.Box(-1, 1, (2,)), spaces.Discrete(3), spaces.MultiDiscrete([2, 3])])
def test_detached_distribution_is_the_kl_anchor(action_space: spaces.Space) -> None:
    from stable_baselines3.common.distributions import kl_divergence

    from sb3_trpo_plus.algorithm.natural_gradient import detached_distribution

    policy = ActorCriticPolicy(spaces.Box(-1, 1, (3,)), action_space, lambda _: 1e-3, net_arch=[4])
    obs = th.randn(6, 3)
    distribution = policy.get_distribution(obs)
    anchor = detached_distribution(distribution)
    kl = kl_divergence(distribution, anchor).mean()
    assert float(kl) == pytest.approx(0.0, abs=1e-7)
    assert kl.requires_grad  # through `distribution` only
    actions = distribution.sample().detach()
    expected = distribution.log_prob(actions).detach().numpy()
    np.testing.assert_allclose(anchor.log_prob(actions).numpy(), expected, rtol=1e-6)
    assert not anchor.log_prob(actions).requires_grad
