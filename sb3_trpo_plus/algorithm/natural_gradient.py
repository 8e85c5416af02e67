"""Natural-gradient numerics used by TRPOPlus, as small pure functions.

* :func:`conjugate_gradient` solves ``F x = g`` with diagnostics and an optional warm start.
* :func:`fisher_vector_product` builds ``v -> (F + damping I) v`` from the policy's
  distribution parameters with the analytic Fisher ``J^T M J`` (no second-order graph of the KL).
* :func:`backtracking_line_search` enforces the trust region and restores parameters exactly
  when no step is acceptable.
* :func:`flat_parameters` / :func:`set_flat_parameters` / :func:`flat_gradient` convert between
  lists of tensors and one flat vector.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch as th
from stable_baselines3.common.distributions import (
    BernoulliDistribution,
    CategoricalDistribution,
    Distribution,
    MultiCategoricalDistribution,
)

FisherVectorProduct = Callable[[th.Tensor], th.Tensor]


# --------------------------------------------------------------------------- flat parameters
def flat_parameters(params: Sequence[th.Tensor]) -> th.Tensor:
    """Concatenate the (detached) values of ``params`` into one new 1-D tensor."""
    return th.cat([p.detach().reshape(-1) for p in params])


def set_flat_parameters(params: Sequence[th.Tensor], flat: th.Tensor) -> None:
    """Copy the 1-D tensor ``flat`` into ``params`` in place (inverse of :func:`flat_parameters`)."""
    expected = sum(p.numel() for p in params)
    if flat.numel() != expected:
        raise ValueError(f"flat vector has {flat.numel()} entries, the parameters need {expected}")
    offset = 0
    with th.no_grad():
        for p in params:
            n = p.numel()
            p.copy_(flat[offset : offset + n].view_as(p))
            offset += n


def flat_gradient(
    output: th.Tensor, params: Sequence[th.Tensor], retain_graph: bool = False, create_graph: bool = False
) -> th.Tensor:
    """Gradient of a scalar ``output`` w.r.t. all ``params`` in one autograd call, flattened.

    Parameters that ``output`` does not depend on get a zero gradient, so the result always has
    ``sum(p.numel())`` entries in the order of ``params``.
    """
    grads = th.autograd.grad(output, list(params), retain_graph=retain_graph, create_graph=create_graph, allow_unused=True)
    return th.cat([(th.zeros_like(p) if g is None else g).reshape(-1) for g, p in zip(grads, params, strict=True)])


# --------------------------------------------------------------------------- conjugate gradient
@dataclass(frozen=True)
class ConjugateGradientResult:
    """Solution of ``A x = b`` and how it was reached.

    :param solution: the approximate solution ``x``
    :param iterations: number of CG iterations (matrix-vector products inside the loop)
    :param residual_norm: ``||b - A x||`` as tracked by the recurrence
    :param matvecs: total matrix-vector products, including the one a warm start needs
    :param quadratic_form: ``x^T A x`` computed from the recurrence (``x^T (b - r)``), so the caller
        does not need another product to scale the step
    :param residual_norms: ``||b - A x||`` at the start and after every iteration (``iterations + 1`` values)
    """

    solution: th.Tensor
    iterations: int
    residual_norm: float
    matvecs: int
    quadratic_form: float
    residual_norms: tuple[float, ...] = ()


def conjugate_gradient(
    matrix_vector_product: FisherVectorProduct,
    b: th.Tensor,
    x0: th.Tensor | None = None,
    max_iter: int = 10,
    residual_tol: float = 1e-10,
    warm_start_rescale: bool = False,
) -> ConjugateGradientResult:
    """Solve ``A x = b`` for a symmetric positive-definite ``A`` given only ``v -> A v``.

    :param matrix_vector_product: function returning ``A v``
    :param b: right-hand side (1-D)
    :param x0: starting point; ``None`` starts from zero (no extra product)
    :param max_iter: maximum number of CG iterations (>= 1)
    :param residual_tol: stop once the *squared* residual norm ``||b - A x||^2`` is below this value
    :param warm_start_rescale: replace ``x0`` by its exact line minimiser ``(x0^T b / x0^T A x0) x0``
        before iterating. This reuses the product ``A x0`` needed for the first residual, so it is free.
    :return: solution and diagnostics
    """
    if max_iter < 1:
        raise ValueError(f"max_iter must be >= 1, got {max_iter}")
    matvecs = 0
    if x0 is None or not bool(th.any(x0 != 0)):
        x = th.zeros_like(b)
        residual = b.clone()
    else:
        x = x0.detach().clone()
        a_x = matrix_vector_product(x)
        matvecs += 1
        if warm_start_rescale:
            curvature = th.dot(x, a_x)
            if curvature > 0:
                scale = th.dot(x, b) / curvature
                x = scale * x
                a_x = scale * a_x
        residual = b - a_x
    residual_sq = th.dot(residual, residual)
    history = [residual_sq]
    direction = residual.clone()
    iterations = 0
    while iterations < max_iter and residual_sq > residual_tol:
        a_direction = matrix_vector_product(direction)
        matvecs += 1
        curvature = th.dot(direction, a_direction)
        if not bool(th.isfinite(curvature)) or curvature <= 0:
            # Not positive definite along this direction (or non-finite): stop with what we have.
            break
        alpha = residual_sq / curvature
        x = x + alpha * direction
        residual = residual - alpha * a_direction
        new_residual_sq = th.dot(residual, residual)
        direction = residual + (new_residual_sq / residual_sq) * direction
        residual_sq = new_residual_sq
        history.append(residual_sq)
        iterations += 1
    quadratic_form = float(th.dot(x, b - residual))
    return ConjugateGradientResult(
        solution=x,
        iterations=iterations,
        residual_norm=math.sqrt(max(float(residual_sq), 0.0)),
        matvecs=matvecs,
        quadratic_form=quadratic_form,
        residual_norms=tuple(math.sqrt(max(float(value), 0.0)) for value in history),
    )


# --------------------------------------------------------------------------- Fisher-vector product
def detached_distribution(distribution: Distribution) -> Distribution:
    """A copy of ``distribution`` cut from the autograd graph: the anchor of the KL, without a second forward."""

    def detach(inner: th.distributions.Distribution) -> th.distributions.Distribution:
        if isinstance(inner, th.distributions.Normal):
            return th.distributions.Normal(inner.loc.detach(), inner.scale.detach(), validate_args=False)
        if isinstance(inner, th.distributions.Categorical):
            return th.distributions.Categorical(logits=inner.logits.detach(), validate_args=False)
        if isinstance(inner, th.distributions.Bernoulli):
            return th.distributions.Bernoulli(logits=inner.logits.detach(), validate_args=False)
        raise TypeError(f"cannot detach a {type(inner).__name__}")

    anchor = copy.copy(distribution)
    inner = distribution.distribution
    anchor.distribution = [detach(d) for d in inner] if isinstance(inner, list) else detach(inner)
    return anchor


def _distribution_parameters(distribution: Distribution) -> tuple[th.Tensor, Callable[[th.Tensor], th.Tensor]]:
    """Distribution parameters per sample, shape ``(N, D)``, and the Fisher metric ``M`` in that space.

    The returned ``metric(u)`` applies ``M / n`` sample-wise to ``u`` of shape ``(N, D)``, where ``n`` is the
    number of terms SB3's ``kl_divergence(p, q).mean()`` averages (sb3-contrib TRPO's KL): for the
    element-wise distributions (diagonal Gaussian, gSDE, squashed Gaussian, Bernoulli) the KL comes per
    action dimension, so ``n = N * D`` and ``target_kl`` bounds the KL *per action dimension*; for
    (multi-)categorical ones it comes per sample, ``n = N``. The Hessian of that mean KL is ``J^T (M / n) J``.
    """
    if isinstance(distribution, CategoricalDistribution | MultiCategoricalDistribution):
        dists = distribution.distribution if isinstance(distribution.distribution, list) else [distribution.distribution]
        logits = th.cat([d.logits for d in dists], dim=1)
        probs = th.cat([d.probs for d in dists], dim=1).detach()
        sizes = [d.logits.shape[1] for d in dists]
        n = logits.shape[0]

        def categorical_metric(u: th.Tensor) -> th.Tensor:
            # Fisher of a softmax in logit space: diag(p) - p p^T, per categorical block
            pu = probs * u
            blocks = [block.sum(dim=1, keepdim=True) for block in th.split(pu, sizes, dim=1)]
            correction = th.cat([s.expand(-1, size) for s, size in zip(blocks, sizes, strict=True)], dim=1)
            return (pu - probs * correction) / n

        return logits, categorical_metric
    if isinstance(distribution, BernoulliDistribution):
        logits = distribution.distribution.logits
        probs = distribution.distribution.probs.detach()
        weight = probs * (1.0 - probs) / logits.numel()  # SB3's KL is per dimension, averaged over N * D
        return logits, lambda u: weight * u
    normal = distribution.distribution
    if isinstance(normal, th.distributions.Normal):
        # Diagonal Gaussian (also gSDE and squashed Gaussians: KL is invariant to the squashing)
        mean = normal.loc
        log_std = normal.scale.log() if normal.scale.shape == mean.shape else normal.scale.log().expand_as(mean)
        std = normal.scale.detach().expand_as(mean)
        # SB3's KL of a diagonal Gaussian is per action dimension and sb3-contrib averages it over N * D
        weight = th.cat([std.pow(-2), th.full_like(mean, 2.0)], dim=1) / mean.numel()
        return th.cat([mean, log_std], dim=1), lambda u: weight * u
    raise TypeError(f"No analytic Fisher information for distribution {type(distribution).__name__}")


def fisher_vector_product(
    distribution: Distribution, params: Sequence[th.Tensor], damping: float = 0.0, sample_weights: th.Tensor | None = None
) -> FisherVectorProduct:
    """Return ``v -> (F + damping I) v`` for the mean-KL Fisher matrix of ``distribution`` w.r.t. ``params``.

    ``F = J^T M J`` where ``J`` is the Jacobian of the distribution parameters (mean and log-std,
    or logits) w.r.t. ``params`` and ``M`` the Fisher of the distribution in its own parameters
    (``1/sigma^2`` and ``2`` for a Gaussian, ``diag(p) - p p^T`` for a categorical). ``J v`` is
    obtained with the double-vjp trick on a graph built once, so every product costs two linear
    backward passes and never differentiates the KL twice.

    The distribution must have been computed with gradients enabled from ``params``. With ``sample_weights`` (one
    per sample, mean 1 for a weighted mean), the Fisher matrix of the weighted mean KL.
    """
    outputs, metric = _distribution_parameters(distribution)
    params = list(params)
    dummy = th.zeros_like(outputs, requires_grad=True)
    # g(u) = J^T u, linear in u; its graph is kept to get J v = d(v^T g(u))/du
    transposed = th.autograd.grad(outputs, params, dummy, create_graph=True, allow_unused=True)
    used = [g is not None for g in transposed]
    jt_dummy = th.cat([g.reshape(-1) for g in transposed if g is not None])
    sizes = [p.numel() for p in params]

    def product(vector: th.Tensor) -> th.Tensor:
        pieces = th.split(vector, sizes)
        used_vector = th.cat([piece for piece, u in zip(pieces, used, strict=True) if u])
        (jacobian_vector,) = th.autograd.grad(jt_dummy, dummy, used_vector, retain_graph=True)
        metric_vector = metric(jacobian_vector)
        if sample_weights is not None:
            metric_vector = metric_vector * sample_weights.reshape(-1, 1)
        grads = th.autograd.grad(outputs, params, metric_vector, retain_graph=True, allow_unused=True)
        flat = th.cat([(th.zeros_like(p) if g is None else g).reshape(-1) for g, p in zip(grads, params, strict=True)])
        return flat + damping * vector if damping else flat

    return product


# --------------------------------------------------------------------------- line search
@dataclass(frozen=True)
class LineSearchResult:
    """Outcome of :func:`backtracking_line_search`.

    :param accepted: whether a step was applied
    :param steps: number of trial points evaluated
    :param coefficient: fraction of the full step that was applied (0 when rejected)
    :param objective: surrogate objective at the final parameters
    :param kl: mean KL divergence at the final parameters (0 when rejected)
    :param nonfinite: whether a non-finite objective, KL or step was met
    """

    accepted: bool
    steps: int
    coefficient: float
    objective: float
    kl: float
    nonfinite: bool


def backtracking_line_search(
    params: Sequence[th.Tensor],
    full_step: th.Tensor,
    evaluate: Callable[[], tuple[float, float]],
    baseline_objective: float,
    target_kl: float,
    shrinking_factor: float = 0.8,
    max_iter: int = 10,
) -> LineSearchResult:
    """Try ``theta0 + beta^i * full_step`` for ``i = 0..max_iter-1`` and keep the first acceptable point.

    A point is acceptable when its KL (to the anchor) is ``<= target_kl`` and the surrogate objective
    is strictly above ``baseline_objective``; both must be finite. If no point is acceptable (or the
    step itself is not finite), the parameters are restored bit-for-bit.

    :param params: parameters to move (in place)
    :param full_step: flat step, same layout as :func:`flat_parameters`
    :param evaluate: returns ``(objective, kl)`` at the current parameter values
    """
    original = flat_parameters(params)
    if not bool(th.isfinite(full_step).all()):
        return LineSearchResult(accepted=False, steps=0, coefficient=0.0, objective=baseline_objective, kl=0.0, nonfinite=True)
    coefficient = 1.0
    nonfinite = False
    with th.no_grad():
        for step in range(1, max_iter + 1):
            set_flat_parameters(params, original + coefficient * full_step)
            objective, kl = evaluate()
            if not (math.isfinite(objective) and math.isfinite(kl)):
                nonfinite = True
            elif kl <= target_kl and objective > baseline_objective:
                return LineSearchResult(
                    accepted=True, steps=step, coefficient=coefficient, objective=objective, kl=kl, nonfinite=nonfinite
                )
            coefficient *= shrinking_factor
        set_flat_parameters(params, original)
    return LineSearchResult(
        accepted=False, steps=max_iter, coefficient=0.0, objective=baseline_objective, kl=0.0, nonfinite=nonfinite
    )
