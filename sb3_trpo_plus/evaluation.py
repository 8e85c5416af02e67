"""Evaluate a trained agent on seeded episodes: success rate and mean return.

    from sb3_trpo_plus.evaluation import evaluate_agent, evaluation_env

    env = evaluation_env("Grasper3D-v7", normalization="run/vecnormalize.pkl")
    result = evaluate_agent(model, env, n_episodes=100, seed=20_000)  # reset seeds 20,000, 20,001, ...
    print(result.success_rate, result.mean_return)

The env is one monitored env (a ``VecEnv`` of one); with a run's VecNormalize statistics its observations are
normalized as in training, and the statistics stay fixed (``training=False``); rewards are not normalized, so the
returns are the env's. A ``vecnormalize.pkl`` is read as data (:func:`sb3_trpo_plus.agents.load_normalization`):
a file that would run code when unpickled is refused.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from sb3_trpo_plus.agents import NormalizationStats, load_normalization


@dataclass(frozen=True)
class EvaluationResult:
    """Per-episode returns (the env's rewards, summed) and successes (``info["is_success"]`` at the last step)."""

    returns: tuple[float, ...]
    successes: tuple[bool, ...]

    @property
    def episodes(self) -> int:
        return len(self.returns)

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.successes))

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))

    @property
    def std_return(self) -> float:
        return float(np.std(self.returns))


def evaluation_env(
    env_id: str,
    env_kwargs: dict[str, Any] | None = None,
    normalization: str | Path | NormalizationStats | VecNormalize | RunningMeanStd | None = None,
    seed: int | None = None,
    wrapper_class: Callable[[gym.Env], gym.Env] | None = None,
) -> VecEnv:
    """One monitored env of ``env_id`` made with ``env_kwargs``, for ``evaluate_agent``.

    :param normalization: the VecNormalize statistics of a run trained with VecNormalize. They are never updated, and
        rewards stay the env's. One of: the path of the run's ``vecnormalize.pkl``, read as data by
        :func:`sb3_trpo_plus.agents.load_normalization` (a file that carries code is refused with
        :class:`~sb3_trpo_plus.agents.RunFileError`); the statistics read so (``NormalizationStats``); the training
        ``VecNormalize`` itself, whose observation statistics the env shares, so that it follows them as training
        updates them. Each of these applies its saved ``norm_obs``, ``clip_obs`` and ``epsilon``. Or only the
        observation statistics (``VecNormalize.obs_rms``), with VecNormalize's defaults (``clip_obs`` 10, ``epsilon``
        1e-8). ``None``: observations as the env gives them.
    :param seed: seed of the env (its action space and first reset); ``evaluate_agent`` seeds the resets itself
    :param wrapper_class: a Gymnasium wrapper of the env (not the training-only aids). As in SB3's ``make_vec_env``,
        it wraps the Monitor, so the Monitor's returns are the env's rewards before the wrapper changes them.
    """
    env = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=env_kwargs, wrapper_class=wrapper_class)
    if normalization is None:
        return env
    if isinstance(normalization, str | Path):
        normalization = load_normalization(normalization)
    if isinstance(normalization, NormalizationStats):
        return normalization.wrap(env, training=False, norm_reward=False)
    if isinstance(normalization, VecNormalize):
        normalized = VecNormalize(
            env, training=False, norm_obs=normalization.norm_obs, norm_reward=False, clip_obs=normalization.clip_obs,
            gamma=normalization.gamma, epsilon=normalization.epsilon, norm_obs_keys=normalization.norm_obs_keys,
        )  # fmt: skip
        if normalization.norm_obs:
            normalized.obs_rms = normalization.obs_rms
        return normalized
    normalized = VecNormalize(env, training=False, norm_reward=False)
    statistics: Any = normalization  # a RunningMeanStd; mypy infers obs_rms as the Dict-space form, a dict of them
    normalized.obs_rms = statistics
    return normalized


def evaluate_agent(
    model: Any,
    env: VecEnv,
    n_episodes: int,
    seed: int,
    deterministic: bool = True,
    seed_every_episode: bool = True,
) -> EvaluationResult:
    """Run ``model`` for ``n_episodes`` episodes on ``env`` (one env, e.g. from ``evaluation_env``).

    :param model: an SB3 model (anything with ``predict(observation, deterministic=...)``)
    :param n_episodes: episodes to run, at least 1
    :param seed: reset seed of the first episode; with ``seed_every_episode`` episode ``k`` is reset with ``seed + k``
        (the same episodes whatever ran before), else only the first reset is seeded and the env's own generator
        draws the later ones (one seeded stream; the convergence study's protocol)
    :param deterministic: the policy's mean action (True) or a sample of its distribution
    :return: the episodes' returns and successes. A return is the Monitor's (the env's rewards, before any
        normalization) where the env has one, else the sum of the rewards ``env`` gives.
    """
    if env.num_envs != 1:
        raise ValueError(f"evaluate_agent runs one env, so that episode k has reset seed k; got {env.num_envs}")
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be at least 1, got {n_episodes}")
    returns: list[float] = []
    successes: list[bool] = []
    env.seed(seed)
    observation = env.reset()
    summed = 0.0
    while len(returns) < n_episodes:
        action, _ = model.predict(observation, deterministic=deterministic)
        observation, reward, done, info = env.step(action)
        summed += float(reward[0])
        if not done[0]:
            continue
        returns.append(float(info[0]["episode"]["r"]) if "episode" in info[0] else summed)
        successes.append(bool(info[0].get("is_success", False)))
        summed = 0.0
        if seed_every_episode and len(returns) < n_episodes:
            env.seed(seed + len(returns))  # the env has reset itself already; this reset starts episode k from seed + k
            observation = env.reset()
    return EvaluationResult(tuple(returns), tuple(successes))
