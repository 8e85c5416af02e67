"""The generalized update's data (GeTRPO): the fresh batch and the stored ones weighted by age, their off-policy
advantages, the trust-region radius, and the weighted critic fit.

``TRPOPlus(sample_reuse="generalized")`` calls :func:`generalized_batch` and :func:`fit_weighted_critic` each update;
the numerics they rest on (the batch weights, off-policy GAE) are in :mod:`sb3_trpo_plus.algorithm.reuse`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import RolloutBufferSamples

from sb3_trpo_plus.algorithm.critic import fit_critic, shuffled_minibatches
from sb3_trpo_plus.algorithm.replay import RolloutEvaluation
from sb3_trpo_plus.algorithm.reuse import ReuseWeights
from sb3_trpo_plus.algorithm.segment import Segment
from sb3_trpo_plus.algorithm.update import PolicyBatch, ValueFit

TraceRatios = Callable[[np.ndarray], np.ndarray]
"""The traces of one stored segment's off-policy GAE, from its normalised observations (flat): ``(n_steps, n_envs)``."""


@dataclass(frozen=True)
class ReuseSettings:
    """How a generalized update reuses its batches.

    :param weights: the batch weights (``sb3_trpo_plus.algorithm.reuse.reuse_weights``)
    :param trace_clip: truncation of the importance ratios that carry off-policy GAE's traces (V-trace: 1)
    :param kl_vary: the radius ``epsilon = sqrt(2 target_kl)`` less the weighted mean ``|pi_current / q - 1|``
        already spent (GeTRPO's ``eps_vary``), instead of ``target_kl * trust_scale**2``
    """

    weights: ReuseWeights
    trace_clip: float = 1.0
    kl_vary: bool = False


@dataclass(frozen=True)
class ReusedBatch:
    """A generalized update's samples: the policy batch (with sample weights) and the critic's data.

    :param critic_observations: every sample's observation (no sub-sampling)
    :param critic_returns: off-policy GAE targets (the fresh batch's: SB3's returns)
    :param critic_weights: every sample's batch weight
    :param n_batches: batches at hand, the fresh one included
    :param radius: the update's trust-region radius
    :param offpolicy_tv: ``mean(w * |pi_current / q - 1|) / 2``, how far the current policy is from the stored batches'
    """

    batch: PolicyBatch
    critic_observations: th.Tensor
    critic_returns: th.Tensor
    critic_weights: th.Tensor
    n_batches: int
    radius: float
    offpolicy_tv: float


def reuse_radius(target_kl: float, trust_scale: float, spent: float, kl_vary: bool) -> float:
    """The KL radius of a generalized update: ``target_kl * trust_scale**2`` (``epsilon = sqrt(2 target_kl)`` scaled
    by ``1 / B``), or with ``kl_vary`` ``(sqrt(2 target_kl) - spent)**2 / 2`` (0 once ``spent`` reaches epsilon)."""
    if kl_vary:
        return max(math.sqrt(2.0 * target_kl) - spent, 0.0) ** 2 / 2.0
    return target_kl * trust_scale**2


def log_prob_of(policy: ActorCriticPolicy, observations: th.Tensor, actions: th.Tensor, action_tensor: Callable) -> th.Tensor:
    """The current policy's log-probabilities of ``actions`` at ``observations``, without gradients."""
    with th.no_grad():
        return policy.get_distribution(observations).log_prob(action_tensor(actions))


class TruncatedTraceRatios:
    """``c_t = min(pi_current / q, clip)`` of ``segment``'s ``actions`` (behaviour log-probabilities ``behaviour``), as
    :data:`TraceRatios`. Keeps the observations it was given as a tensor (``observations``) and the current policy's
    log-probabilities it computed (``log_prob``): the update's batch and off-policy distance need the same ones, so
    they are not made twice."""

    def __init__(
        self,
        policy: ActorCriticPolicy,
        segment: Segment,
        actions: th.Tensor,
        behaviour: th.Tensor,
        clip: float,
        action_tensor: Callable,
    ) -> None:
        self.policy, self.segment, self.actions, self.behaviour = policy, segment, actions, behaviour
        self.clip, self.action_tensor = clip, action_tensor
        self.observations: th.Tensor | None = None
        self.log_prob: th.Tensor | None = None

    def __call__(self, flat_observations: np.ndarray) -> np.ndarray:
        self.observations = self.policy.obs_to_tensor(flat_observations)[0]  # type: ignore[assignment]
        self.log_prob = log_prob_of(self.policy, self.observations, self.actions, self.action_tensor)  # type: ignore[arg-type]
        ratio = th.exp(th.clamp(self.log_prob - self.behaviour, -50.0, 50.0)).cpu().numpy()
        return np.minimum(ratio, self.clip).reshape(self.segment.n_steps, self.segment.n_envs)


def generalized_batch(
    policy: ActorCriticPolicy,
    current: RolloutBufferSamples | None,
    stored: Sequence[Segment],
    evaluate: Callable[[Segment, TraceRatios], RolloutEvaluation],
    settings: ReuseSettings,
    target_kl: float,
    action_tensor: Callable[[th.Tensor], th.Tensor],
    sub_sampling: int = 1,
) -> ReusedBatch:
    """The fresh batch ``current`` (as SB3 buffered it) and the ``stored`` segments, newest first, for one generalized
    update: each stored segment evaluated now by ``evaluate`` (current statistics and critic) with off-policy GAE whose
    traces are the current policy's truncated importance ratios; every sample weighted by its batch's age; the policy
    batch on every ``sub_sampling``-th sample, the critic's on all.

    ``current`` None: the fresh batch is ``stored[0]``, collected by an earlier policy (overlapped collection); it is
    evaluated as the stored ones are, with the weight of the fresh batch, and no sample counts as on-policy."""
    weights = settings.weights.per_sample(len(stored) + (current is not None))
    observations: list[th.Tensor] = []
    actions: list[th.Tensor] = []
    sampling: list[th.Tensor] = []
    current_log_prob: list[th.Tensor] = []
    advantages: list[th.Tensor] = []
    returns: list[th.Tensor] = []
    sample_weights: list[th.Tensor] = []
    n_current = 0
    if current is not None:
        device = current.advantages.device
        n_current = len(current.advantages)
        observations.append(current.observations)  # type: ignore[arg-type]
        actions.append(current.actions)
        sampling.append(current.old_log_prob)
        current_log_prob.append(current.old_log_prob)  # on-policy: its importance ratio is 1
        advantages.append(current.advantages)
        returns.append(current.returns)
        sample_weights.append(th.full((n_current,), float(weights[0]), device=device))
    else:
        if not stored:
            raise ValueError("generalized_batch: without a fresh batch `current`, `stored` must hold the fresh segment")
        device = policy.device
    for age, segment in enumerate(stored, start=len(sample_weights)):
        as_buffered = segment.actions.reshape(segment.n_samples, -1).astype(np.float32)  # the buffer's actions
        stored_actions = th.as_tensor(as_buffered, device=device)
        behaviour = th.as_tensor(segment.log_probs.reshape(-1), device=device)
        traces = TruncatedTraceRatios(policy, segment, stored_actions, behaviour, settings.trace_clip, action_tensor)
        evaluation = evaluate(segment, traces)
        if traces.log_prob is None or traces.observations is None:
            raise RuntimeError("generalized_batch: `evaluate` must compute the segment's trace ratios from its observations")
        current_log_prob.append(traces.log_prob)
        observations.append(traces.observations)  # the evaluation's normalised observations, as the traces saw them
        actions.append(stored_actions)
        sampling.append(behaviour)
        advantages.append(th.as_tensor(evaluation.advantages.reshape(-1), device=device))
        returns.append(th.as_tensor(evaluation.returns.reshape(-1), device=device))
        sample_weights.append(th.full((segment.n_samples,), float(weights[age]), device=device))
    all_observations, all_actions = th.cat(observations), th.cat(actions)
    all_sampling, all_weights = th.cat(sampling), th.cat(sample_weights)
    # how far the current policy already is from the ones that collected the stored batches
    offpolicy = th.exp(th.clamp(th.cat(current_log_prob) - all_sampling, -50.0, 50.0))
    offpolicy[:n_current] = 1.0
    spent = float((all_weights * (offpolicy - 1.0).abs()).mean())
    k = sub_sampling
    batch = PolicyBatch(
        observations=all_observations[::k],
        actions=all_actions[::k],
        sampling_log_prob=all_sampling[::k],
        advantages=th.cat(advantages)[::k],
        n_current=len(range(0, n_current, k)),
        sample_weights=all_weights[::k],
    )
    return ReusedBatch(
        batch=batch,
        critic_observations=all_observations,
        critic_returns=th.cat(returns),
        critic_weights=all_weights,
        n_batches=len(sample_weights),
        radius=reuse_radius(target_kl, settings.weights.trust_scale, spent, settings.kl_vary),
        offpolicy_tv=spent / 2.0,
    )


def fit_weighted_critic(
    policy: ActorCriticPolicy,
    reused: ReusedBatch,
    n_epochs: int,
    batch_size: int,
    critic_step: Callable[[th.Tensor], float | None],
) -> ValueFit:
    """``n_epochs`` critic epochs on every reused sample: weighted squared error to the off-policy GAE targets (GePPO's
    critic), minibatches of ``batch_size`` from one permutation per epoch (numpy's global generator, as SB3's
    buffers), each loss handed to ``critic_step`` (one optimiser step; None where it skipped a non-finite loss)."""
    observations, returns, weights = reused.critic_observations, reused.critic_returns, reused.critic_weights
    return fit_critic(policy, lambda: shuffled_minibatches(observations, returns, batch_size, weights), n_epochs, critic_step)
