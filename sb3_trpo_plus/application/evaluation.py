"""Evaluate a trained agent on seeded episodes: success rate and mean return.

    from sb3_trpo_plus.application.evaluation import evaluate_agent, evaluation_env

    env = evaluation_env("Grasper3D-v7", normalization="run/vecnormalize.pkl")
    result = evaluate_agent(model, env, n_episodes=100, seed=20_000)  # reset seeds 20,000, 20,001, ...
    print(result.success_rate, result.mean_return)

The env is one monitored env (a ``VecEnv`` of one); with a run's VecNormalize statistics its observations are
normalized as in training, and the statistics stay fixed (``training=False``); rewards are not normalized, so the
returns are the env's. A ``vecnormalize.pkl`` is read as data (:func:`sb3_trpo_plus.application.agents.load_normalization`):
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
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, VecNormalize

from sb3_trpo_plus.algorithm.normalization import NormalizationStats, StatisticsMismatchError, check_statistics_fit
from sb3_trpo_plus.application.run_files import load_normalization


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
    *,
    n_envs: int = 1,
    render_mode: str | None = None,
    vec_env_wrapper: Callable[[VecEnv], VecEnv] | None = None,
    frame_stack: int | None = None,
    norm_reward: bool = False,
) -> VecEnv:
    """Monitored envs of ``env_id`` made with ``env_kwargs``, as rl-zoo3's ``create_test_env`` makes a test env: the one
    builder of evaluation envs (``evaluate_agent``'s, ``trpo-plus enjoy``'s and ``record-video``'s, a loaded run's).

    :param normalization: the VecNormalize statistics of a run trained with VecNormalize. They are never updated, and
        rewards stay the env's unless ``norm_reward``. One of: the path of the run's ``vecnormalize.pkl``, read as data
        by :func:`sb3_trpo_plus.application.agents.load_normalization` (a file that carries code is refused with
        :class:`~sb3_trpo_plus.application.agents.RunFileError`); the statistics read so (``NormalizationStats``); a
        ``VecNormalize`` (the training one, or one unpickled from a trusted run), whose statistics the env shares, so
        that it follows them as training updates them. Each of these applies its saved ``norm_obs``, ``clip_obs`` and
        ``epsilon``. Or only the observation statistics (``VecNormalize.obs_rms``), with VecNormalize's defaults
        (``clip_obs`` 10, ``epsilon`` 1e-8). ``None``: observations as the env gives them. Statistics of another
        observation shape raise :class:`~sb3_trpo_plus.algorithm.normalization.StatisticsMismatchError`.
    :param seed: seed of the envs (env ``i``: ``seed + i``; their action spaces and first resets); ``evaluate_agent``
        seeds the resets itself
    :param wrapper_class: a Gymnasium wrapper of each env (not the training-only aids). As in SB3's ``make_vec_env``,
        it wraps the Monitor, so the Monitor's returns are the env's rewards before the wrapper changes them.
    :param n_envs: envs in the ``DummyVecEnv`` (``evaluate_agent`` runs one)
    :param render_mode: the envs' render mode (default: none)
    :param vec_env_wrapper: a VecEnv wrapper, applied under the normalization (rl-zoo3's ``vec_env_wrapper``)
    :param frame_stack: stack this many frames over the normalized observations (rl-zoo3's ``frame_stack``)
    :param norm_reward: normalize the rewards with the statistics' return scale (``trpo-plus enjoy --norm-reward``)
    """
    kwargs = dict(env_kwargs or {})
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    env: VecEnv = make_vec_env(gym.spec(env_id).make, n_envs=n_envs, seed=seed, env_kwargs=kwargs, wrapper_class=wrapper_class)
    if vec_env_wrapper is not None:
        env = vec_env_wrapper(env)
    if normalization is not None:
        env = frozen_normalization(env, normalization, norm_reward)
    if frame_stack:
        env = VecFrameStack(env, int(frame_stack))
    return env


def frozen_normalization(
    env: VecEnv, normalization: str | Path | NormalizationStats | VecNormalize | RunningMeanStd, norm_reward: bool = False
) -> VecNormalize:
    """``env`` under ``normalization`` (any form ``evaluation_env`` takes), frozen: for an evaluation env built
    another way (e.g. ``grasp_envs.make_batch_env``)."""
    if isinstance(normalization, str | Path):
        normalization = load_normalization(normalization)
    if isinstance(normalization, NormalizationStats):
        return normalization.wrap(env, training=False, norm_reward=norm_reward)
    if isinstance(normalization, VecNormalize):
        normalized = VecNormalize(
            env,
            training=False,
            norm_obs=normalization.norm_obs,
            norm_reward=norm_reward,
            clip_obs=normalization.clip_obs,
            clip_reward=normalization.clip_reward,
            gamma=normalization.gamma,
            epsilon=normalization.epsilon,
            norm_obs_keys=normalization.norm_obs_keys,
        )
        if normalization.norm_obs:
            _share(normalized, "obs_rms", normalization.obs_rms)
        normalized.ret_rms = normalization.ret_rms
        return normalized
    normalized = VecNormalize(env, training=False, norm_reward=False)
    _share(normalized, "obs_rms", normalization)
    return normalized


def _share(normalized: VecNormalize, name: str, statistics: Any) -> None:
    """Give ``normalized`` the statistics object ``statistics`` (shared, not copied), checked to fit its env."""
    own = getattr(normalized, name)
    if isinstance(own, dict):
        if not isinstance(statistics, dict) or statistics.keys() != own.keys():
            keys = list(statistics) if isinstance(statistics, dict) else "none"
            raise StatisticsMismatchError(f"VecNormalize statistics of keys {keys} do not fit the env's {list(own)}")
        for key, rms in own.items():
            check_statistics_fit(rms, statistics[key].mean)
    else:
        check_statistics_fit(own, statistics.mean)
    setattr(normalized, name, statistics)


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
