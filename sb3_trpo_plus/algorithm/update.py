"""One TRPO policy update as public functions: the surrogate's advantages and the natural-gradient step, the thesis'
replay batch they learn from, and the step's log records.

``TRPOPlus.update_policy`` is these two calls; a variant of the update (several steps per batch, another trust
region) calls them itself rather than reaching into the algorithm's private methods. The numerics they combine
(Fisher-vector products, conjugate gradient, the line search) are in :mod:`sb3_trpo_plus.algorithm.natural_gradient`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch as th
from stable_baselines3.common.distributions import Distribution, kl_divergence
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import RolloutBufferSamples
from torch import nn

from sb3_trpo_plus.algorithm.natural_gradient import (
    LineSearchResult,
    backtracking_line_search,
    conjugate_gradient,
    fisher_vector_product,
    flat_gradient,
)
from sb3_trpo_plus.algorithm.replay import RolloutEvaluation, effective_sample_size, importance_weights


def actor_parameters(policy: ActorCriticPolicy) -> list[nn.Parameter]:
    """The parameters that define the action distribution, selected through the policy's modules.

    Features extractor (shared or actor-only), the actor MLP, the action head and a state-independent
    log-std. The value head and the critic MLP are never included.
    """
    mlp_extractor = policy.mlp_extractor
    if not hasattr(mlp_extractor, "policy_net"):
        raise TypeError(
            f"{type(mlp_extractor).__name__} has no `policy_net`: TRPOPlus needs SB3's MlpExtractor layout "
            "to tell actor parameters from critic parameters"
        )
    extractor = policy.features_extractor if policy.share_features_extractor else policy.pi_features_extractor
    modules: list[nn.Module] = [extractor, mlp_extractor.policy_net, policy.action_net]
    params: list[nn.Parameter] = [p for module in modules for p in module.parameters()]
    log_std = getattr(policy, "log_std", None)
    if isinstance(log_std, nn.Parameter):
        params.append(log_std)
    unique: dict[int, nn.Parameter] = {id(p): p for p in params if p.requires_grad}
    return list(unique.values())


# ---------------------------------------------------------------------------------------------------- records
@dataclass(frozen=True)
class PolicyBatch:
    """Samples of one policy update: the current rollout (``n_current`` samples) followed by the replayed ones.

    :param sample_weights: per sample, the weight of its batch in the surrogate, the Fisher matrix and the KL of a
        generalized trust region (None: all equal)
    """

    observations: th.Tensor
    actions: th.Tensor
    sampling_log_prob: th.Tensor
    advantages: th.Tensor
    n_current: int
    sample_weights: th.Tensor | None = None

    @property
    def n_replayed(self) -> int:
        return len(self.advantages) - self.n_current


@dataclass(frozen=True)
class SurrogateAdvantages:
    """The batch's advantages as the surrogate weighs them (normalised, replayed ones truncated).

    :param advantages: one per sample of the batch
    :param replay_ess: effective sample size of the importance weights, a fraction of the batch (1: on-policy)
    """

    advantages: th.Tensor
    replay_ess: float


@dataclass(frozen=True)
class PolicyStep:
    """One natural-gradient step: its line search, the parameter change it made, and its CG diagnostics.

    :param line_search: outcome of the line search
    :param applied_step: the change of the actor parameters (flat), None when the line search rejected the step;
        the next update's CG warm start
    :param objective_before: surrogate objective before the step
    :param cg_iterations: CG iterations
    :param cg_residual: CG's final residual norm
    :param cg_relative_residual: the residual norm over the gradient's
    :param step_gradient_cosine: cosine between the CG solution and the gradient
    :param fisher_vector_products: Fisher-vector products, the warm start's and the step scaling's included
    :param cg_warm_start_cosine: cosine between CG's start and its solution (0 without a warm start)
    :param replay_ess: the replayed samples' effective sample size (:class:`SurrogateAdvantages`)
    """

    line_search: LineSearchResult
    applied_step: np.ndarray | None
    objective_before: float
    cg_iterations: int
    cg_residual: float
    cg_relative_residual: float
    step_gradient_cosine: float
    fisher_vector_products: int
    cg_warm_start_cosine: float
    replay_ess: float


@dataclass(frozen=True)
class NaturalGradientSettings:
    """How a natural-gradient step is solved and searched (TRPOPlus' hyperparameters of the same names).

    :param cg_max_steps: conjugate-gradient iterations
    :param cg_damping: damping added to the Fisher matrix
    :param cg_warm_start_rescale: rescale a warm start to its exact line minimiser
    :param fisher_sub_sampling: estimate the Fisher products on every n-th sample
    :param line_search_shrinking_factor: backtracking factor
    :param line_search_max_iter: line-search trials
    """

    cg_max_steps: int
    cg_damping: float
    cg_warm_start_rescale: bool = True
    fisher_sub_sampling: int = 1
    line_search_shrinking_factor: float = 0.8
    line_search_max_iter: int = 10


# ---------------------------------------------------------------------------------------------------- functions
def surrogate_advantages(
    batch: PolicyBatch, log_prob: th.Tensor, normalize: bool, replay_is_clip: float | None
) -> SurrogateAdvantages:
    """The batch's advantages as the surrogate weighs them: normalised over the batch (``normalize``), the replayed
    samples' importance weights ``pi_current / q`` truncated at ``replay_is_clip`` by a constant factor.

    ``log_prob`` is the current policy's; the current rollout is on-policy by construction (weight 1). With the batch's
    ``sample_weights`` (a generalized update), the advantages are centred and scaled by their weighted statistics
    under the off-policy ratios ``r = pi_current / q`` (GeTRPO's), and come out multiplied by the weights, so that
    the surrogate ``mean(A * pi / q)`` is the weighted one; ``replay_is_clip`` does not apply.
    """
    advantages = batch.advantages
    if batch.sample_weights is not None:
        weights = batch.sample_weights
        ratio = th.exp(th.clamp(log_prob - batch.sampling_log_prob, -50.0, 50.0))
        ratio[: batch.n_current] = 1.0
        if normalize:
            weighted = ratio * weights
            mean = (weighted * advantages).sum() / weighted.sum()
            advantages = (advantages - mean) / ((weighted * advantages).std() + 1e-8)
        ess = effective_sample_size((ratio * weights).cpu().numpy()) / len(weights)
        return SurrogateAdvantages(advantages=advantages * weights, replay_ess=ess)
    if normalize:
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    if batch.n_replayed == 0:
        return SurrogateAdvantages(advantages=advantages, replay_ess=1.0)
    rho, scale = importance_weights(log_prob.cpu().numpy(), batch.sampling_log_prob.cpu().numpy(), replay_is_clip)
    rho[: batch.n_current], scale[: batch.n_current] = 1.0, 1.0
    return SurrogateAdvantages(
        advantages=advantages * th.as_tensor(scale, dtype=th.float32, device=advantages.device),
        replay_ess=effective_sample_size(rho * scale) / len(rho),
    )


def warm_start_from(previous_step: np.ndarray | None) -> Callable[[th.Tensor], th.Tensor | None]:
    """CG's start from the previous update's step (thesis 5.3.2): a function of the gradient, None where there is no
    previous step (the first update, after a rejected line search) or it does not fit the gradient."""

    def start(gradient: th.Tensor) -> th.Tensor | None:
        if previous_step is None or previous_step.shape != gradient.shape:
            return None
        return th.as_tensor(previous_step, dtype=gradient.dtype, device=gradient.device)

    return start


def no_warm_start(gradient: th.Tensor) -> None:
    """CG from zero."""
    return None


def natural_gradient_step(
    policy: ActorCriticPolicy,
    actor_params: Sequence[nn.Parameter],
    batch: PolicyBatch,
    actions: th.Tensor,
    distribution: Distribution,
    surrogate: SurrogateAdvantages,
    anchor: Distribution,
    *,
    step_kl: float,
    max_kl: float,
    settings: NaturalGradientSettings,
    warm_start: Callable[[th.Tensor], th.Tensor | None] = no_warm_start,
    covariance_kl: float | None = None,
) -> PolicyStep:
    """One natural-gradient step of ``actor_params`` from where they are (they are changed in place).

    Gradient of the importance-weighted surrogate ``mean(A * pi / q)`` and Fisher matrix at ``distribution`` (the
    policy at the current parameters, with its graph), CG started from ``warm_start(gradient)``, a full step of
    quadratic KL ``step_kl``, and a backtracking line search that accepts the first trial improving the surrogate
    with a mean KL to ``anchor`` within ``max_kl``. The batch's ``sample_weights`` (where it has them) weigh the
    Fisher matrix and the KL; the surrogate's weights come with its advantages (:func:`surrogate_advantages`).

    :param policy: the policy whose ``get_distribution`` evaluates the trials
    :param actor_params: the parameters the step changes
    :param actions: the batch's actions as the distribution takes them
    :param covariance_kl: None: one trust region on the whole KL. A number: the trust region is decoupled, as MPO's
        (Abdolmaleki et al. 2018), for a diagonal Gaussian policy whose log-std is the last of ``actor_params``: the
        KL of the mean (:func:`decoupled_gaussian_kl`) within ``max_kl`` (its full step of quadratic KL
        ``step_kl``), the KL of the covariance within ``covariance_kl`` (its full step of
        ``covariance_kl * step_kl / max_kl``)
    """
    advantages = surrogate.advantages
    log_prob = distribution.log_prob(actions)
    objective = (advantages * th.exp(log_prob - batch.sampling_log_prob)).mean()
    gradient = flat_gradient(objective, actor_params, retain_graph=settings.fisher_sub_sampling == 1)
    fisher_distribution = distribution
    if settings.fisher_sub_sampling > 1:
        fisher_distribution = policy.get_distribution(batch.observations[:: settings.fisher_sub_sampling])
    weights = batch.sample_weights
    fisher_weights = None if weights is None else weights[:: settings.fisher_sub_sampling]
    fvp = fisher_vector_product(fisher_distribution, actor_params, damping=settings.cg_damping, sample_weights=fisher_weights)

    start = warm_start(gradient)
    cg = conjugate_gradient(
        fvp, gradient, x0=start, max_iter=settings.cg_max_steps, warm_start_rescale=settings.cg_warm_start_rescale
    )
    direction = cg.solution
    extra_products = 0
    if covariance_kl is None:
        quadratic_form = cg.quadratic_form if cg.quadratic_form > 0 else float(th.dot(direction, fvp(direction)))
        full_step = math.sqrt(2.0 * step_kl / quadratic_form) * direction if quadratic_form > 0 else direction * math.nan
        extra_products = 0 if cg.quadratic_form > 0 else 1
    else:  # the log-std is the last actor parameter (actor_parameters): its block of the step gets its own radius
        std_size = int(actor_params[-1].numel())
        mean_part = th.cat([direction[:-std_size], th.zeros_like(direction[-std_size:])])
        std_part = direction - mean_part
        mean_step = _scaled_to_kl(mean_part, fvp, step_kl)
        std_step = _scaled_to_kl(std_part, fvp, covariance_kl * step_kl / max_kl)
        full_step = mean_step + (std_step if th.isfinite(std_step).all() else th.zeros_like(std_step))
        extra_products = 2

    def weighted_mean(kl: th.Tensor) -> float:
        if weights is not None:
            kl = kl * weights.reshape(-1, *([1] * (kl.dim() - 1)))
        return float(kl.mean())

    def evaluate() -> tuple[float, float]:
        new_distribution = policy.get_distribution(batch.observations)
        new_log_prob = new_distribution.log_prob(actions)
        new_objective = (advantages * th.exp(new_log_prob - batch.sampling_log_prob)).mean()
        if covariance_kl is None:
            return float(new_objective), weighted_mean(kl_divergence(new_distribution, anchor))
        mean_kl, std_kl = decoupled_gaussian_kl(anchor, new_distribution)
        # within both radii exactly when this is within max_kl: the line search's one test
        return float(new_objective), max_kl * max(weighted_mean(mean_kl) / max_kl, weighted_mean(std_kl) / covariance_kl)

    result = backtracking_line_search(
        actor_params,
        full_step,
        evaluate,
        float(objective.detach()),
        max_kl,
        settings.line_search_shrinking_factor,
        settings.line_search_max_iter,
    )
    return PolicyStep(
        line_search=result,
        applied_step=(result.coefficient * full_step).cpu().numpy() if result.accepted else None,
        objective_before=float(objective.detach()),
        cg_iterations=cg.iterations,
        cg_residual=cg.residual_norm,
        cg_relative_residual=cg.residual_norm / max(float(th.linalg.vector_norm(gradient)), 1e-12),
        step_gradient_cosine=_cosine(gradient, direction),
        fisher_vector_products=cg.matvecs + extra_products,
        cg_warm_start_cosine=_cosine(start, direction) if start is not None else 0.0,
        replay_ess=surrogate.replay_ess,
    )


def decoupled_gaussian_kl(old: Distribution, new: Distribution) -> tuple[th.Tensor, th.Tensor]:
    """The KL that TRPO bounds, ``KL(new || old)`` (SB3's ``kl_divergence(new, old)``), of two diagonal Gaussian
    policies, split into the part of the mean and the part of the covariance as MPO decouples it (Abdolmaleki et al.
    2018), per sample and action dimension:

    - mean: ``KL(N(mu_new, s_old) || N(mu_old, s_old)) = (mu_new - mu_old)^2 / (2 s_old^2)``;
    - covariance: ``KL(N(mu_old, s_new) || N(mu_old, s_old)) = log(s_old / s_new) + s_new^2 / (2 s_old^2) - 1/2``.

    The two add up to the whole KL exactly; to second order around ``new = old`` the mean's part is the Fisher
    matrix's block of the mean's parameters, the covariance's its log-std block.
    """
    old_normal, new_normal = old.distribution, new.distribution
    if not (isinstance(old_normal, th.distributions.Normal) and isinstance(new_normal, th.distributions.Normal)):
        raise TypeError(f"decoupled_gaussian_kl: needs diagonal Gaussian policies, got {type(old).__name__}")
    old_variance, new_std = old_normal.stddev**2, new_normal.stddev
    mean_kl = (new_normal.mean - old_normal.mean) ** 2 / (2.0 * old_variance)
    std_kl = th.log(old_normal.stddev / new_std) + new_std**2 / (2.0 * old_variance) - 0.5
    return mean_kl, std_kl


def _scaled_to_kl(direction: th.Tensor, fvp: Callable[[th.Tensor], th.Tensor], kl: float) -> th.Tensor:
    """``direction`` scaled to the quadratic KL ``kl`` (``1/2 x^T F x``); NaN where its quadratic form is not
    positive (a direction the line search then refuses)."""
    quadratic_form = float(th.dot(direction, fvp(direction)))
    return math.sqrt(2.0 * kl / quadratic_form) * direction if quadratic_form > 0 else direction * math.nan


def replay_policy_batch(
    current: RolloutBufferSamples,
    replayed: Sequence[RolloutEvaluation],
    policy: ActorCriticPolicy,
    sub_sampling_factor: int = 1,
) -> PolicyBatch:
    """The thesis' replay batch (5.3.1): the current rollout (as SB3's buffer gives it) followed by the replayed
    rollouts, each with the log-probabilities of the policy that sampled it and its advantages under the current
    value function; with ``sub_sampling_factor`` ``k``, every k-th sample of the whole."""
    observations, actions = current.observations, current.actions
    sampling_log_prob, advantages = current.old_log_prob, current.advantages
    n_current = len(advantages)
    if replayed:
        obs_list, act_list, logq_list, adv_list = [observations], [actions], [sampling_log_prob], [advantages]
        for evaluation in replayed:
            stored = evaluation.segment
            # the actions as the rollout buffer holds them: float32, one row of action_dim per sample
            stored_actions = stored.actions.reshape(stored.n_samples, -1).astype(np.float32)
            obs_list.append(policy.obs_to_tensor(evaluation.observations)[0])  # type: ignore[arg-type]
            act_list.append(th.as_tensor(stored_actions, device=policy.device))
            logq_list.append(th.as_tensor(stored.log_probs.reshape(-1), device=policy.device))
            adv_list.append(th.as_tensor(evaluation.advantages.reshape(-1), device=policy.device))
        observations = th.cat(obs_list)
        actions, sampling_log_prob, advantages = th.cat(act_list), th.cat(logq_list), th.cat(adv_list)
    if sub_sampling_factor > 1:
        k = sub_sampling_factor
        n_current = len(range(0, n_current, k))
        observations, actions = observations[::k], actions[::k]
        sampling_log_prob, advantages = sampling_log_prob[::k], advantages[::k]
    return PolicyBatch(observations, actions, sampling_log_prob, advantages, n_current)


def record_policy_step(record: Callable[..., None], batch: PolicyBatch, step: PolicyStep) -> None:
    """The policy step's outcome and diagnostics under ``train/`` (SB3's names where sb3-contrib's TRPO logs them)."""
    line_search = step.line_search
    record("train/policy_objective", line_search.objective if line_search.accepted else step.objective_before)
    record("train/kl_divergence_loss", line_search.kl)
    record("train/is_line_search_success", float(line_search.accepted))
    record("train/cg_iterations", step.cg_iterations)
    record("train/cg_residual", step.cg_residual)
    record("train/cg_relative_residual", step.cg_relative_residual)
    record("train/step_gradient_cosine", step.step_gradient_cosine)
    record("train/fisher_vector_products", step.fisher_vector_products)
    record("train/cg_warm_start_cosine", step.cg_warm_start_cosine)
    record("train/line_search_steps", line_search.steps)
    record("train/step_size", line_search.coefficient)
    record("train/line_search_nonfinite", float(line_search.nonfinite))
    record("train/replay_samples", batch.n_replayed)
    record("train/replay_ess", step.replay_ess)


def _cosine(a: th.Tensor, b: th.Tensor) -> float:
    denominator = float(th.linalg.vector_norm(a) * th.linalg.vector_norm(b))
    return float(th.dot(a, b)) / denominator if denominator > 0 else 0.0


@dataclass(frozen=True)
class UpdateTimings:
    """Seconds of an update's phases: advantages and the batch (``prepare``: the linear baseline, the replayed
    segments evaluated again), the policy step, the value baseline's fit (and the memory)."""

    prepare: float
    policy: float
    value: float


@dataclass(frozen=True)
class ValueFit:
    """Outcome of the value-baseline fit of one update.

    :param loss: mean squared error to the returns (mean over the critic's minibatches; NaN if none was finite)
    :param skipped_steps: critic steps skipped for a non-finite loss
    """

    loss: float
    skipped_steps: int
