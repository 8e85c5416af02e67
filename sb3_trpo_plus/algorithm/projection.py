"""The projected trust region of ``TRPOPlus(policy_update="projection")``: per-state projections of a diagonal
Gaussian policy (Otto et al., "Differentiable Trust Region Layers for Deep Reinforcement Learning", ICLR 2021,
https://arxiv.org/abs/2101.09207) and the policy step that trains the actor through them with minibatch epochs.

Every update freezes the policy it starts from (``old``) and trains the actor with Adam for ``epochs`` passes of
``minibatches`` minibatches, as PPO does, on the surrogate of the *projected* policy: each state's Gaussian moved back
into its trust region with the old one, the mean and the covariance each by their own part of ``KL(new || old)``
(:func:`mean_part`, :func:`covariance_part`, the split of :func:`~sb3_trpo_plus.algorithm.update.decoupled_gaussian_kl`).
Mean: the closed-form interpolation towards the old mean (:func:`project_mean`); covariance: the interpolation of the
precisions whose multiplier solves the bound (:func:`project_std`, its gradient through the implicit function
theorem). A regression term, ``regression * KL(network || projected)``, pulls the network's own output to the
projected policy, which is what acts after the update. The step ends as TRPO's line search does: when the network's
mean KL to the old policy is above the sum of the two radii (which the projected policy keeps in every state), the
parameter change shrinks until it is within, and is undone when no trial is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch as th
from stable_baselines3.common.distributions import Distribution
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn

from sb3_trpo_plus.algorithm.natural_gradient import LineSearchResult, flat_parameters, set_flat_parameters
from sb3_trpo_plus.algorithm.update import PolicyBatch, PolicyStep, surrogate_advantages

_LOG_ETA_RANGE = (-30.0, 30.0)
"""The precision multiplier's search interval (natural log): at ``e^-30`` the projection leaves the covariance where
the network put it, at ``e^30`` it is the old one to float64's precision."""


# ---------------------------------------------------------------------------------------------------- numerics
def mean_part(mean: th.Tensor, old_mean: th.Tensor, old_std: th.Tensor) -> th.Tensor:
    """The mean's part of ``KL(new || old)`` per state (last axis: the action dimensions):
    ``sum((mean - old_mean)^2 / (2 old_std^2))``."""
    return (((mean - old_mean) / old_std) ** 2).sum(-1) / 2.0


def covariance_part(std: th.Tensor, old_std: th.Tensor) -> th.Tensor:
    """The covariance's part of ``KL(new || old)`` per state: ``sum(log(old_std / std) + std^2 / (2 old_std^2) - 1/2)``."""
    ratio = (std / old_std) ** 2
    return ((ratio - 1.0 - th.log(ratio)) / 2.0).sum(-1)


def project_mean(mean: th.Tensor, old_mean: th.Tensor, old_std: th.Tensor, bound: float) -> th.Tensor:
    """Each state's mean moved towards its old mean until :func:`mean_part` is at most ``bound``.

    Outside the bound the projection is ``(mean + w old_mean) / (1 + w)`` with ``w = sqrt(m / bound) - 1`` (``m`` the
    state's mean part), which puts ``m`` exactly on the bound; inside, the mean is unchanged. Differentiable in
    ``mean``, ``w`` included.
    """
    if not (math.isfinite(bound) and bound > 0):
        raise ValueError(f"project_mean: the bound must be a finite number > 0, got {bound!r}")
    distance = mean_part(mean, old_mean, old_std)
    outside = distance > bound
    # inside the bound w = 0 (sqrt(bound / bound) - 1): no infinite derivative of sqrt at 0 reaches the gradient
    omega = (th.sqrt(th.where(outside, distance, th.full_like(distance, bound)) / bound) - 1.0).unsqueeze(-1)
    return (mean + omega * old_mean) / (1.0 + omega)


def _interpolated_variance(precision: th.Tensor, old_precision: th.Tensor, eta: th.Tensor) -> th.Tensor:
    """The variance whose precision is ``(precision + eta old_precision) / (1 + eta)``."""
    return (1.0 + eta) / (precision + eta * old_precision)


def _covariance_part_at(precision: th.Tensor, old_precision: th.Tensor, eta: th.Tensor) -> th.Tensor:
    ratio = _interpolated_variance(precision, old_precision, eta) * old_precision
    return ((ratio - 1.0 - th.log(ratio)) / 2.0).sum(-1)


def project_std(std: th.Tensor, old_std: th.Tensor, bound: float, iterations: int = 80) -> th.Tensor:
    """Each state's standard deviations moved towards the old ones until :func:`covariance_part` is at most ``bound``.

    Outside the bound the projected precision is ``(1 / std^2 + eta / old_std^2) / (1 + eta)`` (Otto et al.'s KL
    projection of a covariance, for a diagonal one), ``eta > 0`` the multiplier that puts the covariance part on the
    bound: the part falls monotonically from its value at ``eta = 0`` to 0 as ``eta`` grows, and ``eta`` is found in
    float64 by Newton's method over ``log(eta)`` kept inside a bisection bracket (:func:`_solve_multiplier`). Its derivative in
    ``std`` is the implicit function's, ``-(dc/dstd) / (dc/deta)``, so the gradient of a loss of the projected
    standard deviations is exact. Inside the bound ``std`` is unchanged. Where every row of ``std`` and of ``old_std``
    is the same (a state-independent log-std), the multiplier is solved once and shared.
    """
    if not (math.isfinite(bound) and bound > 0):
        raise ValueError(f"project_std: the bound must be a finite number > 0, got {bound!r}")
    outside = covariance_part(std, old_std) > bound
    if not bool(outside.any()):
        return std
    precision, old_precision = std.detach().double() ** -2, old_std.detach().double() ** -2
    if std.dim() > 1 and len(std) > 1 and bool((std == std[:1]).all() and (old_std == old_std[:1]).all()):
        # one covariance for every state (a log-std): one solve, shared
        shared = _solve_multiplier(precision[:1], old_precision[:1], bound, iterations)
        eta_value = shared.expand(outside.shape).unsqueeze(-1)
    else:  # the states outside the bound, each its own solve (the others keep eta = 0 below)
        solved = th.ones(outside.shape, dtype=th.float64, device=std.device)
        solved[outside] = _solve_multiplier(precision[outside], old_precision[outside], bound, iterations)
        eta_value = solved.unsqueeze(-1)
    _, slope = _part_and_slope(precision, old_precision, eta_value)  # at the solution, float64
    slope = th.where(outside & (slope < 0), slope, th.full_like(slope, -1.0)).to(std.dtype)
    eta_fixed = eta_value.squeeze(-1).to(std.dtype)
    live_precision = std**-2
    live_part = _covariance_part_at(live_precision, old_std.detach() ** -2, eta_fixed.unsqueeze(-1))
    # value eta, derivative -(dc/dstd) / (dc/deta): the implicit function's
    eta = eta_fixed - (live_part - live_part.detach()) / slope
    eta = th.where(outside, eta, th.zeros_like(eta)).unsqueeze(-1)
    return th.sqrt(_interpolated_variance(live_precision, old_std.detach() ** -2, eta))


def _part_and_slope(precision: th.Tensor, old_precision: th.Tensor, eta: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """The covariance part at the interpolated precision of ``eta`` and its derivative in ``eta``:
    ``(1/2) sum (1 - 1/r) q (p - q) / (p + eta q)^2``, ``p`` and ``q`` the two precisions, ``r`` the variance ratio."""
    ratio = _interpolated_variance(precision, old_precision, eta) * old_precision
    part = ((ratio - 1.0 - th.log(ratio)) / 2.0).sum(-1)
    slope = 0.5 * (1.0 - 1.0 / ratio) * old_precision * (precision - old_precision) / (precision + eta * old_precision) ** 2
    return part, slope.sum(-1)


def _solve_multiplier(precision: th.Tensor, old_precision: th.Tensor, bound: float, iterations: int) -> th.Tensor:
    """Per row, the ``eta`` whose interpolated covariance part is ``bound`` (float64; every row's part at ``eta = 0``
    above it): Newton steps over ``t = log(eta)`` in :data:`_LOG_ETA_RANGE`, a step that leaves the bracket of the root
    replaced by the bracket's midpoint, until no row's ``t`` moves by more than ``1e-13`` (at most ``iterations``)."""
    low = th.full(precision.shape[:-1], _LOG_ETA_RANGE[0], dtype=th.float64, device=precision.device)
    high = th.full_like(low, _LOG_ETA_RANGE[1])
    t = th.zeros_like(low)
    for _ in range(iterations):
        eta = th.exp(t).unsqueeze(-1)
        part, slope = _part_and_slope(precision, old_precision, eta)
        excess = part - bound
        low, high = th.where(excess > 0, t, low), th.where(excess > 0, high, t)  # the part falls as t grows
        newton = t - excess / (slope * eta.squeeze(-1))
        inside = th.isfinite(newton) & (newton > low) & (newton < high)
        step = th.where(inside, newton, (low + high) / 2.0)
        converged = bool(((step - t).abs() <= 1e-13).all())
        t = step
        if converged:
            break
    return th.exp(t)


def gaussian_kl(mean: th.Tensor, std: th.Tensor, other_mean: th.Tensor, other_std: th.Tensor) -> th.Tensor:
    """``KL(N(mean, std) || N(other_mean, other_std))`` per state (diagonal Gaussians, summed over the last axis)."""
    return mean_part(mean, other_mean, other_std) + covariance_part(std, other_std)


@dataclass(frozen=True)
class ProjectionSettings:
    """How a projected policy step trains (TRPOPlus' ``projection_*`` hyperparameters and its line-search ones).

    :param epochs: passes over the update's batch
    :param minibatches: minibatches per pass (the batch split evenly after a shuffle)
    :param regression: weight of ``KL(network || projected)`` in the loss
    :param max_grad_norm: the actor's gradient clipped to this norm per Adam step
    :param line_search_shrinking_factor: the factor that shrinks a change whose mean KL is above the radii
    :param line_search_max_iter: shrinking trials before the change is undone
    """

    epochs: int
    minibatches: int
    regression: float = 1.0
    max_grad_norm: float = 0.5
    line_search_shrinking_factor: float = 0.8
    line_search_max_iter: int = 10


def projected_policy_step(
    policy: ActorCriticPolicy,
    actor_params: Sequence[nn.Parameter],
    optimizer: th.optim.Optimizer,
    batch: PolicyBatch,
    actions: th.Tensor,
    *,
    mean_radius: float,
    covariance_radius: float,
    normalize_advantage: bool,
    replay_is_clip: float | None,
    settings: ProjectionSettings,
    record: Callable[..., None],
) -> PolicyStep:
    """One projected policy step of ``actor_params`` (changed in place by ``optimizer``, an optimiser of them): the
    module's update, on the batch's surrogate (:func:`~sb3_trpo_plus.algorithm.update.surrogate_advantages`: generalized
    reuse's weights and off-policy ratios included). Logs ``train/projection_mean_kl``, ``train/projection_covariance_kl``
    (the two parts of the network's KL to the old policy after the step, means over the batch) and
    ``train/projection_skipped_steps`` (Adam steps skipped for a non-finite loss or gradient: none reaches the weights).
    """
    with th.no_grad():
        old = _normal(policy.get_distribution(batch.observations))
        old_mean, old_std = old.mean, old.stddev
        old_log_prob = old.log_prob(actions).sum(-1)
    surrogate = surrogate_advantages(batch, old_log_prob, normalize_advantage, replay_is_clip)
    advantages = surrogate.advantages
    start = flat_parameters(actor_params).detach().clone()
    objective_before = float((advantages * th.exp(old_log_prob - batch.sampling_log_prob)).mean())
    n_samples = len(advantages)
    size = max(1, math.ceil(n_samples / settings.minibatches))
    skipped = 0
    for _ in range(settings.epochs):
        for index in th.randperm(n_samples, device=advantages.device).split(size):
            loss = projection_loss(
                policy, batch, actions, advantages, index, (old_mean, old_std), (mean_radius, covariance_radius), settings
            )
            optimizer.zero_grad()
            if not bool(th.isfinite(loss)):
                skipped += 1
                continue
            loss.backward()
            norm = nn.utils.clip_grad_norm_(actor_params, settings.max_grad_norm)
            if not bool(th.isfinite(norm)):
                skipped += 1
                continue
            optimizer.step()
    optimizer.zero_grad()
    bound = mean_radius + covariance_radius
    line_search = _bounded_change(
        policy, actor_params, batch, (actions, advantages), start, (old_mean, old_std), bound, objective_before, settings
    )
    with th.no_grad():
        new = _normal(policy.get_distribution(batch.observations))
        record("train/projection_mean_kl", float(mean_part(new.mean, old_mean, old_std).mean()))
        record("train/projection_covariance_kl", float(covariance_part(new.stddev, old_std).mean()))
    record("train/projection_skipped_steps", skipped)
    change = (flat_parameters(actor_params).detach() - start).cpu().numpy()
    return PolicyStep(
        line_search=line_search,
        applied_step=change if line_search.accepted else None,
        objective_before=objective_before,
        cg_iterations=0,
        cg_residual=0.0,
        cg_relative_residual=0.0,
        step_gradient_cosine=0.0,
        fisher_vector_products=0,
        cg_warm_start_cosine=0.0,
        replay_ess=surrogate.replay_ess,
    )


def projection_loss(
    policy: ActorCriticPolicy,
    batch: PolicyBatch,
    actions: th.Tensor,
    advantages: th.Tensor,
    index: th.Tensor,
    old: tuple[th.Tensor, th.Tensor],
    radii: tuple[float, float],
    settings: ProjectionSettings,
) -> th.Tensor:
    """Minus the projected policy's surrogate on the minibatch ``index``, plus the regression to it."""
    normal = _normal(policy.get_distribution(batch.observations[index]))
    old_mean, old_std = old[0][index], old[1][index]
    mean = project_mean(normal.mean, old_mean, old_std, radii[0])
    std = project_std(normal.stddev, old_std, radii[1])
    log_prob = th.distributions.Normal(mean, std).log_prob(actions[index]).sum(-1)
    objective = (advantages[index] * th.exp(log_prob - batch.sampling_log_prob[index])).mean()
    regression = gaussian_kl(normal.mean, normal.stddev, mean.detach(), std.detach()).mean()
    return -objective + settings.regression * regression


def _bounded_change(
    policy: ActorCriticPolicy,
    actor_params: Sequence[nn.Parameter],
    batch: PolicyBatch,
    actions_and_advantages: tuple[th.Tensor, th.Tensor],
    start: th.Tensor,
    old: tuple[th.Tensor, th.Tensor],
    max_kl: float,
    objective_before: float,
    settings: ProjectionSettings,
) -> LineSearchResult:
    """Shrink the epochs' parameter change until the network's mean KL to the old policy is within ``max_kl`` (the
    batch's sample weights weigh it, as TRPO's constraint); undone when no trial is."""
    actions, advantages = actions_and_advantages
    change = flat_parameters(actor_params).detach() - start
    weights = batch.sample_weights
    coefficient = 1.0
    nonfinite = False
    for trial in range(settings.line_search_max_iter + 1):
        set_flat_parameters(actor_params, start + coefficient * change)
        with th.no_grad():
            new = _normal(policy.get_distribution(batch.observations))
            kl = gaussian_kl(new.mean, new.stddev, *old)
            mean_kl = float((kl * weights).mean() if weights is not None else kl.mean())
            log_prob = new.log_prob(actions).sum(-1)
            objective = float((advantages * th.exp(log_prob - batch.sampling_log_prob)).mean())
        finite = math.isfinite(mean_kl) and math.isfinite(objective)
        nonfinite = nonfinite or not finite
        if finite and mean_kl <= max_kl:
            return LineSearchResult(True, trial + 1, coefficient, objective, mean_kl, nonfinite)
        coefficient *= settings.line_search_shrinking_factor
    set_flat_parameters(actor_params, start)
    return LineSearchResult(False, settings.line_search_max_iter + 1, 0.0, objective_before, 0.0, nonfinite)


def _normal(distribution: Distribution) -> th.distributions.Normal:
    """The torch ``Normal`` of an SB3 diagonal Gaussian distribution."""
    normal = distribution.distribution
    if not isinstance(normal, th.distributions.Normal):
        raise TypeError(f"the projected trust region needs a diagonal Gaussian policy, got {type(distribution).__name__}")
    return normal
