"""The public policy update (sb3_trpo_plus.algorithm.update): the surrogate's advantages and one natural-gradient step."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.distributions import kl_divergence

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.natural_gradient import detached_distribution
from sb3_trpo_plus.algorithm.update import (
    NaturalGradientSettings,
    PolicyBatch,
    natural_gradient_step,
    no_warm_start,
    surrogate_advantages,
    warm_start_from,
)


def _batch(model: TRPOPlus, n: int = 64, seed: int = 0) -> PolicyBatch:
    generator = th.Generator().manual_seed(seed)
    observations = th.randn(n, 3, generator=generator)
    with th.no_grad():
        distribution = model.policy.get_distribution(observations)
        actions = distribution.sample()
        log_prob = distribution.log_prob(actions)
    advantages = actions[:, 0] - actions[:, 0].mean()  # larger actions are better
    return PolicyBatch(observations, actions, log_prob, advantages, n_current=n)


def test_a_step_improves_the_surrogate_inside_the_trust_region() -> None:
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", policy_kwargs={"net_arch": [8]}, seed=0, device="cpu")
    batch = _batch(model)
    distribution = model.policy.get_distribution(batch.observations)
    anchor = detached_distribution(distribution)
    surrogate = surrogate_advantages(batch, distribution.log_prob(batch.actions).detach(), True, None)
    settings = NaturalGradientSettings(cg_max_steps=20, cg_damping=0.01)
    step = natural_gradient_step(
        model.policy,
        model._actor_params,
        batch,
        batch.actions,
        distribution,
        surrogate,
        anchor,
        step_kl=0.01,
        max_kl=0.01,
        settings=settings,
    )
    assert step.line_search.accepted and step.applied_step is not None
    after = model.policy.get_distribution(batch.observations)
    kl = float(kl_divergence(after, anchor).mean())
    assert kl == pytest.approx(step.line_search.kl, rel=1e-5) and 0 < kl <= 0.01
    objective = float((surrogate.advantages * th.exp(after.log_prob(batch.actions) - batch.sampling_log_prob)).mean())
    assert objective > step.objective_before and objective == pytest.approx(step.line_search.objective, rel=1e-5)
    # a CG solve of 20 iterations on a well-damped 8-unit actor: the direction is the gradient's natural one
    assert step.step_gradient_cosine > 0 and step.cg_relative_residual < 1e-2
    assert step.cg_warm_start_cosine == 0.0 and step.replay_ess == 1.0


def test_update_policy_is_one_natural_gradient_step() -> None:
    """TRPOPlus.update_policy equals the public step called with the model's settings."""
    results = []
    for call_directly in (False, True):
        model = TRPOPlus("MlpPolicy", "Pendulum-v1", policy_kwargs={"net_arch": [8]}, seed=0, device="cpu")
        model.current_target_kl = 0.01
        batch = _batch(model)
        if call_directly:
            distribution = model.policy.get_distribution(batch.observations)
            surrogate = surrogate_advantages(batch, distribution.log_prob(batch.actions).detach(), True, None)
            natural_gradient_step(
                model.policy,
                model._actor_params,
                batch,
                batch.actions,
                distribution,
                surrogate,
                detached_distribution(distribution),
                step_kl=0.01,
                max_kl=0.01,
                settings=model.natural_gradient_settings,
            )
        else:
            model.update_policy(batch)
        results.append({k: v.clone() for k, v in model.policy.state_dict().items()})
    for name in results[0]:
        th.testing.assert_close(results[0][name], results[1][name], rtol=0, atol=0)


def test_surrogate_advantages_are_normalised_over_the_batch() -> None:
    advantages = th.tensor([1.0, 2.0, 3.0, 6.0])
    batch = PolicyBatch(th.zeros(4, 1), th.zeros(4, 1), th.zeros(4), advantages, n_current=4)
    normalised = surrogate_advantages(batch, th.zeros(4), normalize=True, replay_is_clip=None).advantages
    assert float(normalised.mean()) == pytest.approx(0.0, abs=1e-6) and float(normalised.std()) == pytest.approx(1.0, abs=1e-6)
    assert th.equal(surrogate_advantages(batch, th.zeros(4), normalize=False, replay_is_clip=None).advantages, advantages)


def test_warm_start_is_the_previous_step_where_it_fits() -> None:
    gradient = th.ones(3)
    assert warm_start_from(None)(gradient) is None
    assert warm_start_from(np.ones(4))(gradient) is None  # another network's step
    np.testing.assert_array_equal(warm_start_from(np.arange(3.0))(gradient).numpy(), [0.0, 1.0, 2.0])  # type: ignore[union-attr]
    assert no_warm_start(gradient) is None
