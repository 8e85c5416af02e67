"""Several natural-gradient steps per batch: is that what makes SB3 PPO faster than TRPOPlus on the Grasper?

A probe for the convergence study (`python -m benchmarks.convergence`, variant ``plain_scripted25_ms3``), not an option: on
Grasper3D-v4 PPO's updates move the policy *less* than TRPOPlus' (KL 0.008 against 0.019 per state) yet it learns
the lift about twice as fast, and neither a larger trust region, an exact CG solve, a smaller initial std nor
PPO's critic step size closed the gap (docs/results.md). What is left of PPO's update is that it takes many small
steps on each batch, every one from where the last one ended. ``MultiStepTRPOPlus`` does that within TRPO: each
update takes ``n_policy_steps`` natural-gradient steps, each with the surrogate's gradient and the Fisher matrix
re-evaluated at the parameters the previous step left (the surrogate's importance weights against the rollout's
policy), each scaled to a quadratic KL of ``target_kl / n_policy_steps``, and every line search keeps the KL to
the rollout's policy within ``target_kl``, so the update stays inside TRPO's trust region. With one step it is
TRPOPlus (tests/test_multistep.py). The warm start, where on, starts the first step's CG from the last update's
whole step. The logged KL, objective and policy std are the whole update's; the CG statistics are its last step's.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from stable_baselines3.common.distributions import Distribution

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.natural_gradient import detached_distribution
from sb3_trpo_plus.algorithm.update import (
    PolicyBatch,
    PolicyStep,
    natural_gradient_step,
    no_warm_start,
    surrogate_advantages,
    warm_start_from,
)


class MultiStepTRPOPlus(TRPOPlus):
    """TRPOPlus taking ``n_policy_steps`` natural-gradient steps per update inside one trust region."""

    def __init__(self, *args: Any, n_policy_steps: int = 3, **kwargs: Any) -> None:
        if not isinstance(n_policy_steps, int) or isinstance(n_policy_steps, bool) or n_policy_steps < 1:
            raise ValueError(f"n_policy_steps must be an integer >= 1, got {n_policy_steps!r}")
        self.n_policy_steps = n_policy_steps
        super().__init__(*args, **kwargs)

    def update_policy(self, batch: PolicyBatch, radius: float | None = None) -> PolicyStep:
        radius = self.current_target_kl if radius is None else radius
        actions = self.action_tensor(batch.actions)
        distribution: Distribution = self.policy.get_distribution(batch.observations)
        anchor = detached_distribution(distribution)  # the rollout's policy: the trust region's centre
        surrogate = surrogate_advantages(
            batch, distribution.log_prob(actions).detach(), self.normalize_advantage, self.replay_is_clip
        )
        step_kl = radius / self.n_policy_steps
        steps: list[PolicyStep] = []
        moved: np.ndarray | None = None
        for index in range(self.n_policy_steps):
            if index > 0:
                distribution = self.policy.get_distribution(batch.observations)
            first_start = warm_start_from(self.previous_step) if self.cg_warm_start else no_warm_start
            step = natural_gradient_step(
                self.policy,
                self._actor_params,
                batch,
                actions,
                distribution,
                surrogate,
                anchor,
                step_kl=step_kl,
                max_kl=radius,
                settings=self.natural_gradient_settings,
                warm_start=first_start if index == 0 else no_warm_start,
                covariance_kl=self.covariance_radius(radius),
            )
            steps.append(step)
            if step.applied_step is None:
                break
            moved = step.applied_step if moved is None else moved + step.applied_step
        accepted = [s for s in steps if s.line_search.accepted]
        self.logger.record("train/policy_steps", len(accepted))
        last = accepted[-1] if accepted else steps[-1]
        line_search = replace(
            last.line_search,
            accepted=bool(accepted),
            steps=sum(s.line_search.steps for s in steps),
            nonfinite=any(s.line_search.nonfinite for s in steps),
            coefficient=float(np.mean([s.line_search.coefficient for s in steps])),
        )
        # the CG statistics of the last step taken; the warm start of the next update: the whole update's step, as
        # TRPOPlus keeps its one step
        return replace(steps[-1], line_search=line_search, applied_step=moved)
