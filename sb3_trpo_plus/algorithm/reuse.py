"""Sample reuse with a generalized trust region (Queeney, Paschalidis & Cassandras, *Generalized Proximal Policy
Optimization with Sample Reuse*, NeurIPS 2021; its TRPO form, GeTRPO): the numerics, as pure functions.

Each update learns from the last ``M`` batches, the fresh one and ``M - 1`` collected by earlier policies, weighted
by their age (:func:`reuse_weights`), with advantages and critic targets from off-policy GAE whose traces are cut by
truncated importance ratios (:func:`vtrace_gae`, V-trace style). ``TRPOPlus(sample_reuse="generalized")`` uses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

PRUNE_BELOW = 0.01
"""Weights at or below this are dropped and the rest renormalised (GePPO's ``active = weights > 0.01``)."""


@dataclass(frozen=True)
class ReuseWeights:
    """The batch weights of a generalized update.

    :param weights: ``v_1 .. v_M``, the weight of the batch of age ``i - 1`` (the fresh batch first); they sum to 1
    :param trust_scale: the factor ``1 / sum(i * v_i)`` (``1 / B``) that scales the trust region's ``epsilon``
    """

    weights: np.ndarray
    trust_scale: float

    @property
    def n_batches(self) -> int:
        """``M``: the batches an update learns from, the fresh one included."""
        return len(self.weights)

    def per_sample(self, n_present: int) -> np.ndarray:
        """The weight of a sample of each of the ``n_present`` batches at hand (fewer than ``M`` early in training):
        the first ``n_present`` weights, rescaled to average 1 over equally sized batches (as GePPO does)."""
        if not 1 <= n_present <= self.n_batches:
            raise ValueError(f"n_present must be in [1, {self.n_batches}], got {n_present}")
        active = self.weights[:n_present]
        return active / active.sum() * n_present


def reuse_weights(batches: float, max_batches: int) -> ReuseWeights:
    """Weights ``v`` of the last ``max_batches`` batches that maximise the effective sample size, ``min sum v_i^2``,
    subject to ``sum v_i = 1``, ``sum i * v_i = batches`` (``B``: the sample size of one update is ``B`` fresh batches'
    worth) and ``v >= 0`` (GePPO's ``optweights_ess``); weights ``<= 0.01`` are then dropped and the rest renormalised.

    The optimum is linear in ``i`` on its support ``1..m`` and zero beyond (the KKT conditions of this quadratic
    programme): ``B = 2, max_batches = 10`` gives ``0.4, 0.3, 0.2, 0.1``; ``B = 1`` gives the fresh batch alone.

    :param batches: ``B >= 1``; at most ``(max_batches + 1) / 2``, what equal weights over every batch reach
    :param max_batches: ``M_max >= 1``, the oldest batch that may be reused
    """
    if not (isinstance(max_batches, int | np.integer) and not isinstance(max_batches, bool) and max_batches >= 1):
        raise ValueError(f"max_batches must be an integer >= 1, got {max_batches!r}")
    if not (isinstance(batches, int | float | np.number) and not isinstance(batches, bool) and math.isfinite(batches)):
        raise ValueError(f"batches must be a finite number, got {batches!r}")
    if not 1.0 <= batches <= (max_batches + 1) / 2:
        raise ValueError(f"batches must be in [1, {(max_batches + 1) / 2}] for max_batches={max_batches}, got {batches}")
    weights = _ess_optimal(float(batches), int(max_batches))
    weights = weights[weights > PRUNE_BELOW]
    weights = weights / weights.sum()
    ages = np.arange(1, len(weights) + 1)
    return ReuseWeights(weights=weights, trust_scale=float(1.0 / np.dot(weights, ages)))


def _ess_optimal(batches: float, max_batches: int) -> np.ndarray:
    """The quadratic programme's optimum: ``v_i = alpha + beta * i`` on ``1..m`` for the longest feasible ``m``."""
    if batches == 1.0:
        return np.array([1.0])
    for m in range(max_batches, 1, -1):
        i = np.arange(1, m + 1, dtype=np.float64)
        # sum v = 1 and sum i v = B for v = alpha + beta i on 1..m
        system = np.array([[m, i.sum()], [i.sum(), (i * i).sum()]])
        alpha, beta = np.linalg.solve(system, np.array([1.0, batches]))
        v = alpha + beta * i
        if v.min() >= -1e-12:
            return np.clip(v, 0.0, None)
    raise AssertionError("unreachable: m = 2 is feasible for 1 < B <= 1.5")  # pragma: no cover


def vtrace_gae(
    rewards: np.ndarray,
    values: np.ndarray,
    dones: np.ndarray,
    last_values: np.ndarray,
    trace_ratios: np.ndarray,
    gamma: float,
    gae_lambda: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Off-policy GAE over a ``[step, env]`` segment with traces cut by truncated importance ratios ``c_t``:
    ``A_t = delta_t + gamma * lambda * (1 - done_t) * c_{t+1} * A_{t+1}`` and critic targets ``A_t * c_t + V_t``
    (GePPO's ``gae_vtrace``). With every ``c_t = 1`` this is SB3's on-policy GAE, targets ``A_t + V_t``.

    :param rewards: the rewards (time-limit truncations already bootstrapped in)
    :param values: ``V(s_t)``
    :param dones: whether step ``t`` ended an episode
    :param last_values: ``V`` of the observation after the last step
    :param trace_ratios: ``c_t = min(pi(a_t|s_t) / q(a_t|s_t), c_max)``
    :return: ``(advantages, returns)``, float32
    """
    n_steps = rewards.shape[0]
    advantages = np.zeros_like(rewards, dtype=np.float32)
    next_advantage = np.zeros_like(last_values, dtype=np.float32)
    next_ratio = np.zeros_like(last_values, dtype=np.float32)  # no trace beyond the segment
    for t in reversed(range(n_steps)):
        non_terminal = 1.0 - dones[t].astype(np.float32)
        next_values = last_values if t == n_steps - 1 else values[t + 1]
        delta = rewards[t] + gamma * next_values * non_terminal - values[t]
        advantages[t] = delta + gamma * gae_lambda * non_terminal * next_ratio * next_advantage
        next_advantage, next_ratio = advantages[t], trace_ratios[t]
    return advantages, (advantages * trace_ratios + values).astype(np.float32)
