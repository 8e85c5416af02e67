"""The value baseline's fit, each update: Adam epochs of the critic over minibatches of (observations, returns[,
sample weights]), or the thesis' linear baseline refit on the update's samples (thesis 5.1.3).

``TRPOPlus`` hands each loss to its own optimiser step (``critic_step``), which moves the critic's parameters only and
skips a non-finite loss.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator, Sequence

import numpy as np
import torch as th
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.policies import ActorCriticPolicy
from torch.nn import functional as F

from sb3_trpo_plus.algorithm.baselines import LinearFeatureBaseline
from sb3_trpo_plus.algorithm.replay import RolloutEvaluation
from sb3_trpo_plus.algorithm.segment import Segment
from sb3_trpo_plus.algorithm.update import ValueFit

Minibatch = tuple[th.Tensor, th.Tensor, th.Tensor | None]
"""Observations, returns (the critic's targets) and the samples' weights (None: unweighted)."""


def shuffled_minibatches(
    observations: th.Tensor, returns: th.Tensor, batch_size: int, weights: th.Tensor | None = None
) -> Iterator[Minibatch]:
    """Minibatches of ``batch_size`` (the last one shorter) in the order of one permutation drawn from NumPy's global
    generator, as SB3's ``RolloutBuffer.get`` draws it."""
    order = th.as_tensor(np.random.permutation(len(returns)), device=returns.device)
    for start in range(0, len(returns), batch_size):
        idx = order[start : start + batch_size]
        yield observations[idx], returns[idx], None if weights is None else weights[idx]


def buffer_minibatches(buffer: RolloutBuffer, batch_size: int, device: th.device) -> Iterator[Minibatch]:
    """``buffer.get(batch_size)``'s minibatches (the same samples in the same order, from the same draw), of the two
    fields the critic reads only."""
    if not (buffer.generator_ready and isinstance(buffer.observations, np.ndarray)):
        for data in buffer.get(batch_size):
            yield data.observations, data.returns, None
        return
    observations = th.as_tensor(buffer.observations, device=device)
    yield from shuffled_minibatches(observations, th.as_tensor(buffer.returns, device=device).flatten(), batch_size)


def fit_critic(
    policy: ActorCriticPolicy,
    minibatches: Callable[[], Iterable[Minibatch]],
    n_epochs: int,
    critic_step: Callable[[th.Tensor], float | None],
) -> ValueFit:
    """``n_epochs`` epochs, each over ``minibatches()``: the squared error of the critic's values to the returns
    (weighted by the samples' weights where a minibatch has them), each loss handed to ``critic_step`` (one optimiser
    step; None where it skipped a non-finite loss)."""
    losses, skipped = [], 0
    for _ in range(n_epochs):
        for observations, returns, weights in minibatches():
            values = policy.predict_values(observations).flatten()
            value_loss = F.mse_loss(returns, values) if weights is None else (weights * (returns - values) ** 2).mean()
            loss = critic_step(value_loss)
            if loss is None:
                skipped += 1
            else:
                losses.append(loss)
    return ValueFit(loss=float(np.mean(losses)) if losses else math.nan, skipped_steps=skipped)


def fit_linear_baseline(
    baseline: LinearFeatureBaseline,
    buffer: RolloutBuffer,
    segment: Segment,
    replayed: Sequence[RolloutEvaluation] = (),
) -> float:
    """Refit ``baseline`` on the rollout buffer's observations and returns (the buffer holds ``segment``) and on the
    ``replayed`` rollouts'; the mean squared error of its fit."""
    observations = buffer.observations.reshape(buffer.buffer_size * buffer.n_envs, -1)
    steps = segment.episode_timesteps[: segment.n_steps]  # [step, env]
    # once RolloutBuffer.get() has run, the buffer's arrays are flattened env by env (swap_and_flatten)
    timesteps = (steps.swapaxes(0, 1) if buffer.generator_ready else steps).reshape(-1)
    returns = buffer.returns.reshape(-1)
    for evaluation in replayed:
        observations = np.concatenate([observations, evaluation.observations.reshape(len(evaluation.observations), -1)])
        stored = evaluation.segment
        timesteps = np.concatenate([timesteps, stored.episode_timesteps[: stored.n_steps].reshape(-1)])
        returns = np.concatenate([returns, evaluation.returns.reshape(-1)])
    baseline.fit(observations, timesteps, returns)
    return float(np.mean((baseline.predict(observations, timesteps) - returns) ** 2))
