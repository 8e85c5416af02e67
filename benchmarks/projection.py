"""Per-state trust-region projections trained with minibatch epochs: can a trust-region method take PPO's many small
steps per batch?

A probe for the studies (``algo_class: benchmarks.projection.ProjectedTRPOPlus`` in a study variant,
``python -m benchmarks.time_to_grasp --algo-class benchmarks.projection.ProjectedTRPOPlus``), not an option of
``TRPOPlus``. It follows Otto et al., "Differentiable Trust Region Layers for Deep Reinforcement Learning" (ICLR 2021,
https://arxiv.org/abs/2101.09207), for a diagonal Gaussian policy with a state-independent log-std:

- every update freezes the policy it starts from (``old``), then trains the actor with Adam for ``projection_epochs``
  epochs of ``projection_minibatches`` minibatches, as PPO does, on the surrogate of the *projected* policy;
- the projection moves each state's Gaussian back into its trust region with the old one, the mean and the
  covariance each by their own part of ``KL(new || old)`` (:func:`mean_part`, :func:`covariance_part`, the split of
  :func:`~sb3_trpo_plus.algorithm.update.decoupled_gaussian_kl`): the mean within the update's radius (``target_kl``,
  or generalized reuse's narrower radius), the covariance within ``covariance_kl``'s radius (the mean's when
  ``covariance_kl`` is None). Mean: the closed-form interpolation towards the old mean (:func:`project_mean`);
  covariance: the interpolation of the precisions whose multiplier solves the KL bound (:func:`project_std`, its
  gradient through the implicit function theorem). The surrogate's gradient flows through both projections;
- a regression term, ``projection_regression * KL(network || projected)``, pulls the network's own output to the
  projected policy, which is what acts after the update;
- the update ends as TRPO's line search does: when the network's mean KL to the old policy is above the sum of the two
  radii (which the projected policy keeps in every state), the parameter change is shrunk by
  ``line_search_shrinking_factor`` until it is within, and undone after ``line_search_max_iter`` trials. Every update
  therefore stays in a trust region of the same mean KL as a decoupled TRPO step.

The surrogate is the batch's (:func:`~sb3_trpo_plus.algorithm.update.surrogate_advantages`: generalized reuse's
weights and off-policy ratios included), the critic's fit TRPOPlus' own.
"""

from __future__ import annotations

import math
from typing import Any

import torch as th
from stable_baselines3.common.distributions import DiagGaussianDistribution, Distribution
from torch import nn

from sb3_trpo_plus import TRPOPlus
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
    bound: the part falls monotonically from its value at ``eta = 0`` to 0 as ``eta`` grows, and ``eta`` is found by
    bisection over ``log(eta)`` in float64 (``iterations`` halvings of :data:`_LOG_ETA_RANGE`). Its derivative in
    ``std`` is the implicit function's, ``-(dc/dstd) / (dc/deta)``, so the gradient of a loss of the projected
    standard deviations is exact. Inside the bound ``std`` is unchanged.
    """
    if not (math.isfinite(bound) and bound > 0):
        raise ValueError(f"project_std: the bound must be a finite number > 0, got {bound!r}")
    outside = covariance_part(std, old_std) > bound
    if not bool(outside.any()):
        return std
    precision, old_precision = std.detach().double() ** -2, old_std.detach().double() ** -2
    low = th.full(outside.shape, _LOG_ETA_RANGE[0], dtype=th.float64, device=std.device)
    high = th.full_like(low, _LOG_ETA_RANGE[1])
    for _ in range(iterations):
        middle = (low + high) / 2.0
        above = _covariance_part_at(precision, old_precision, th.exp(middle).unsqueeze(-1)) > bound
        low, high = th.where(above, middle, low), th.where(above, high, middle)
    eta_value = th.exp(high).unsqueeze(-1)  # the upper end: its part is within the bound
    # dc/deta at the solution (float64): (1/2) sum (1 - 1/r) q (p - q) / (p + eta q)^2, p and q the two precisions
    ratio = _interpolated_variance(precision, old_precision, eta_value) * old_precision
    denominator = (precision + eta_value * old_precision) ** 2
    slope = (0.5 * (1.0 - 1.0 / ratio) * old_precision * (precision - old_precision) / denominator).sum(-1)
    slope = th.where(outside & (slope < 0), slope, th.full_like(slope, -1.0)).to(std.dtype)
    eta_fixed = eta_value.squeeze(-1).to(std.dtype)
    live_precision = std**-2
    live_part = _covariance_part_at(live_precision, old_std.detach() ** -2, eta_fixed.unsqueeze(-1))
    # value eta, derivative -(dc/dstd) / (dc/deta): the implicit function's
    eta = eta_fixed - (live_part - live_part.detach()) / slope
    eta = th.where(outside, eta, th.zeros_like(eta)).unsqueeze(-1)
    return th.sqrt(_interpolated_variance(live_precision, old_std.detach() ** -2, eta))


def gaussian_kl(mean: th.Tensor, std: th.Tensor, other_mean: th.Tensor, other_std: th.Tensor) -> th.Tensor:
    """``KL(N(mean, std) || N(other_mean, other_std))`` per state (diagonal Gaussians, summed over the last axis)."""
    return mean_part(mean, other_mean, other_std) + covariance_part(std, other_std)


# ---------------------------------------------------------------------------------------------------- algorithm
class ProjectedTRPOPlus(TRPOPlus):
    """TRPOPlus whose policy step is Otto et al.'s projected trust region trained with minibatch epochs (the module's
    docstring).

    :param projection_epochs: passes over the update's batch
    :param projection_minibatches: minibatches per pass (the batch split evenly after a shuffle)
    :param projection_learning_rate: the actor's Adam step size (the critic keeps ``learning_rate``)
    :param projection_regression: weight of ``KL(network || projected)`` in the loss
    :param projection_max_grad_norm: the actor's gradient clipped to this norm per step (None: no clipping)
    """

    def __init__(
        self,
        *args: Any,
        projection_epochs: int = 10,
        projection_minibatches: int = 32,
        projection_learning_rate: float = 3e-4,
        projection_regression: float = 1.0,
        projection_max_grad_norm: float | None = 0.5,
        **kwargs: Any,
    ) -> None:
        for name, value in (("projection_epochs", projection_epochs), ("projection_minibatches", projection_minibatches)):
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"ProjectedTRPOPlus: {name} must be an integer >= 1, got {value!r}")
        for name, number, positive in (
            ("projection_learning_rate", projection_learning_rate, True),
            ("projection_regression", projection_regression, False),
            ("projection_max_grad_norm", 1.0 if projection_max_grad_norm is None else projection_max_grad_norm, True),
        ):
            if isinstance(number, bool) or not isinstance(number, int | float) or not math.isfinite(number) or number < 0:
                raise ValueError(f"ProjectedTRPOPlus: {name} must be a finite number >= 0, got {number!r}")
            if positive and number == 0:
                raise ValueError(f"ProjectedTRPOPlus: {name} must be > 0, got {number!r}")
        self.projection_epochs = projection_epochs
        self.projection_minibatches = projection_minibatches
        self.projection_learning_rate = float(projection_learning_rate)
        self.projection_regression = float(projection_regression)
        self.projection_max_grad_norm = None if projection_max_grad_norm is None else float(projection_max_grad_norm)
        super().__init__(*args, **kwargs)

    def _setup_model(self) -> None:
        super()._setup_model()
        gaussian = isinstance(self.policy.action_dist, DiagGaussianDistribution)
        if not (gaussian and self._actor_params[-1] is self.policy.log_std):
            raise ValueError(
                "ProjectedTRPOPlus projects diagonal Gaussian policies with a state-independent log-std; this policy's "
                f"action distribution is {type(self.policy.action_dist).__name__}"
            )
        self.projection_optimizer = th.optim.Adam(self._actor_params, lr=self.projection_learning_rate, eps=1e-5)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "projection_optimizer"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, tensors = super()._get_torch_save_params()
        return [*state_dicts, "projection_optimizer"], tensors

    def update_policy(self, batch: PolicyBatch, radius: float | None = None) -> PolicyStep:
        radius = self.current_target_kl if radius is None else radius
        covariance_radius = self.covariance_radius(radius)
        covariance_radius = radius if covariance_radius is None else covariance_radius
        actions = self.action_tensor(batch.actions)
        params: list[nn.Parameter] = list(self._actor_params)
        with th.no_grad():
            old = _normal(self.policy.get_distribution(batch.observations))
            old_mean, old_std = old.mean, old.stddev
            old_log_prob = old.log_prob(actions).sum(-1)
        surrogate = surrogate_advantages(batch, old_log_prob, self.normalize_advantage, self.replay_is_clip)
        advantages = surrogate.advantages
        start = flat_parameters(params).detach().clone()
        objective_before = float((advantages * th.exp(old_log_prob - batch.sampling_log_prob)).mean())
        n_samples = len(advantages)
        size = max(1, math.ceil(n_samples / self.projection_minibatches))
        skipped = 0
        for _ in range(self.projection_epochs):
            for index in th.randperm(n_samples, device=advantages.device).split(size):
                loss = self._projection_loss(
                    batch, actions, advantages, index, (old_mean, old_std), (radius, covariance_radius)
                )
                self.projection_optimizer.zero_grad()
                if not bool(th.isfinite(loss)):
                    skipped += 1
                    continue
                loss.backward()
                norm = nn.utils.clip_grad_norm_(params, self.projection_max_grad_norm or math.inf)
                if not bool(th.isfinite(norm)):
                    skipped += 1
                    continue
                self.projection_optimizer.step()
        self.projection_optimizer.zero_grad()
        line_search = self._bounded_change(
            batch, actions, advantages, start, (old_mean, old_std), radius + covariance_radius, objective_before
        )
        with th.no_grad():
            new = _normal(self.policy.get_distribution(batch.observations))
            self.logger.record("train/projection_mean_kl", float(mean_part(new.mean, old_mean, old_std).mean()))
            self.logger.record("train/projection_covariance_kl", float(covariance_part(new.stddev, old_std).mean()))
        self.logger.record("train/projection_skipped_steps", skipped)
        change = (flat_parameters(params).detach() - start).cpu().numpy()
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

    def _projection_loss(
        self,
        batch: PolicyBatch,
        actions: th.Tensor,
        advantages: th.Tensor,
        index: th.Tensor,
        old: tuple[th.Tensor, th.Tensor],
        radii: tuple[float, float],
    ) -> th.Tensor:
        """Minus the projected policy's surrogate on the minibatch ``index``, plus the regression to it."""
        normal = _normal(self.policy.get_distribution(batch.observations[index]))
        old_mean, old_std = old[0][index], old[1][index]
        mean = project_mean(normal.mean, old_mean, old_std, radii[0])
        std = project_std(normal.stddev, old_std, radii[1])
        log_prob = th.distributions.Normal(mean, std).log_prob(actions[index]).sum(-1)
        objective = (advantages[index] * th.exp(log_prob - batch.sampling_log_prob[index])).mean()
        regression = gaussian_kl(normal.mean, normal.stddev, mean.detach(), std.detach()).mean()
        return -objective + self.projection_regression * regression

    def _bounded_change(
        self,
        batch: PolicyBatch,
        actions: th.Tensor,
        advantages: th.Tensor,
        start: th.Tensor,
        old: tuple[th.Tensor, th.Tensor],
        max_kl: float,
        objective_before: float,
    ) -> LineSearchResult:
        """Shrink the epochs' parameter change until the network's mean KL to the old policy is within ``max_kl``
        (the batch's sample weights weigh it, as TRPO's constraint); undone when no trial is."""
        params = list(self._actor_params)
        change = flat_parameters(params).detach() - start
        weights = batch.sample_weights
        coefficient = 1.0
        nonfinite = False
        for trial in range(self.line_search_max_iter + 1):
            set_flat_parameters(params, start + coefficient * change)
            with th.no_grad():
                new = _normal(self.policy.get_distribution(batch.observations))
                kl = gaussian_kl(new.mean, new.stddev, *old)
                mean_kl = float((kl * weights).mean() if weights is not None else kl.mean())
                log_prob = new.log_prob(actions).sum(-1)
                objective = float((advantages * th.exp(log_prob - batch.sampling_log_prob)).mean())
            finite = math.isfinite(mean_kl) and math.isfinite(objective)
            nonfinite = nonfinite or not finite
            if finite and mean_kl <= max_kl:
                return LineSearchResult(True, trial + 1, coefficient, objective, mean_kl, nonfinite)
            coefficient *= self.line_search_shrinking_factor
        set_flat_parameters(params, start)
        return LineSearchResult(False, self.line_search_max_iter + 1, 0.0, objective_before, 0.0, nonfinite)


def _normal(distribution: Distribution) -> th.distributions.Normal:
    """The torch ``Normal`` of an SB3 diagonal Gaussian distribution."""
    normal = distribution.distribution
    if not isinstance(normal, th.distributions.Normal):
        raise TypeError(f"ProjectedTRPOPlus: needs a diagonal Gaussian policy, got {type(distribution).__name__}")
    return normal


__all__ = ["ProjectedTRPOPlus", "covariance_part", "gaussian_kl", "mean_part", "project_mean", "project_std"]
