"""VecNormalize's statistics as plain data: frozen from a live ``VecNormalize`` (what rollout workers normalise a
segment with) or read from a run's file (:func:`sb3_trpo_plus.application.run_files.load_normalization`), with the face
of ``VecNormalize`` that acting needs."""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecNormalize


@dataclass(frozen=True)
class NormalizationStats:
    """VecNormalize's statistics as plain arrays and numbers, with the face of ``VecNormalize`` that acting needs
    (``normalize_obs``, ``unnormalize_obs``, ``normalize_reward``, ``unnormalize_reward``): a loaded agent acts on a
    plain ``gym.make`` env with ``policy.predict(stats.normalize_obs(obs))``, no VecEnv needed."""

    obs_mean: np.ndarray | dict[str, np.ndarray] | None
    obs_var: np.ndarray | dict[str, np.ndarray] | None
    obs_count: float | dict[str, float] | None
    ret_mean: np.ndarray
    ret_var: np.ndarray
    ret_count: float
    norm_obs: bool
    norm_reward: bool
    clip_obs: float
    clip_reward: float
    gamma: float
    epsilon: float
    norm_obs_keys: list[str] | None

    def normalize_obs(self, obs: np.ndarray | dict[str, np.ndarray]) -> np.ndarray | dict[str, np.ndarray]:
        """``obs`` as the run's ``VecNormalize.normalize_obs`` gives it to the policy (float32; one observation of a
        plain ``gym.make`` env or a batch; the keys of ``norm_obs_keys`` of a dict). Unchanged without ``norm_obs``."""
        return self._map_obs(
            obs,
            lambda x, mean, var: np.clip((x - mean) / np.sqrt(var + self.epsilon), -self.clip_obs, self.clip_obs).astype(
                np.float32
            ),
        )

    def unnormalize_obs(self, obs: np.ndarray | dict[str, np.ndarray]) -> np.ndarray | dict[str, np.ndarray]:
        """The inverse of :meth:`normalize_obs` (where no clipping happened), as ``VecNormalize.unnormalize_obs``."""
        return self._map_obs(obs, lambda x, mean, var: x * np.sqrt(var + self.epsilon) + mean)

    def normalize_reward(self, reward: np.ndarray | float) -> np.ndarray:
        """``reward`` scaled by the return statistics and clipped, as ``VecNormalize.normalize_reward`` (float32);
        only cast without ``norm_reward``."""
        reward = np.asarray(reward)
        if self.norm_reward:
            reward = np.clip(reward / np.sqrt(self.ret_var + self.epsilon), -self.clip_reward, self.clip_reward)
        return reward.astype(np.float32)

    def unnormalize_reward(self, reward: np.ndarray | float) -> np.ndarray:
        """The inverse of :meth:`normalize_reward` (where no clipping happened), as ``VecNormalize.unnormalize_reward``."""
        reward = np.asarray(reward)
        return reward * np.sqrt(self.ret_var + self.epsilon) if self.norm_reward else reward

    def _map_obs(
        self, obs: np.ndarray | dict[str, np.ndarray], function: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    ) -> np.ndarray | dict[str, np.ndarray]:
        if not self.norm_obs:
            return copy.deepcopy(obs)
        if isinstance(obs, dict):
            if not (isinstance(self.obs_mean, dict) and isinstance(self.obs_var, dict)):
                raise TypeError("these statistics are of array observations; got a dict observation")
            keys = self.norm_obs_keys if self.norm_obs_keys is not None else list(self.obs_mean)
            return {
                key: function(np.asarray(value), self.obs_mean[key], self.obs_var[key])
                if key in keys
                else copy.deepcopy(value)
                for key, value in obs.items()
            }
        if isinstance(self.obs_mean, dict) or isinstance(self.obs_var, dict) or self.obs_mean is None or self.obs_var is None:
            raise TypeError("these statistics are of dict observations; got an array observation")
        obs = np.asarray(obs)
        if self.obs_mean.ndim and obs.shape[-self.obs_mean.ndim :] != self.obs_mean.shape:
            raise ValueError(f"an observation of shape {obs.shape} does not end in the statistics' {self.obs_mean.shape}")
        return function(obs, self.obs_mean, self.obs_var)

    @classmethod
    def of(cls, vec_normalize: VecNormalize | None) -> NormalizationStats | None:
        """A frozen copy of ``vec_normalize``'s statistics and settings (None for None): what rollout workers
        normalise a segment with while the learner's statistics move on."""
        if vec_normalize is None:
            return None
        obs_rms: Any = vec_normalize.obs_rms
        if isinstance(obs_rms, dict):
            obs_mean: Any = {key: rms.mean.copy() for key, rms in obs_rms.items()}
            obs_var: Any = {key: rms.var.copy() for key, rms in obs_rms.items()}
            obs_count: Any = {key: float(rms.count) for key, rms in obs_rms.items()}
        else:
            obs_mean, obs_var, obs_count = obs_rms.mean.copy(), obs_rms.var.copy(), float(obs_rms.count)
        ret = vec_normalize.ret_rms
        return cls(
            obs_mean,
            obs_var,
            obs_count,
            np.array(ret.mean, dtype=np.float64),
            np.array(ret.var, dtype=np.float64),
            float(ret.count),
            norm_obs=bool(vec_normalize.norm_obs),
            norm_reward=bool(vec_normalize.norm_reward),
            clip_obs=float(vec_normalize.clip_obs),
            clip_reward=float(vec_normalize.clip_reward),
            gamma=float(vec_normalize.gamma),
            epsilon=float(vec_normalize.epsilon),
            norm_obs_keys=list(vec_normalize.norm_obs_keys) if vec_normalize.norm_obs_keys is not None else None,
        )

    def wrap(self, venv: VecEnv, training: bool = False, norm_reward: bool = False) -> VecNormalize:
        """``venv`` wrapped in a VecNormalize with these statistics (test mode: frozen, raw rewards, by default)."""
        vec_normalize = VecNormalize(
            venv,
            training=training,
            norm_obs=self.norm_obs,
            norm_reward=norm_reward,
            clip_obs=self.clip_obs,
            clip_reward=self.clip_reward,
            gamma=self.gamma,
            epsilon=self.epsilon,
            norm_obs_keys=self.norm_obs_keys,
        )
        if self.norm_obs:
            if isinstance(vec_normalize.obs_rms, dict):
                assert isinstance(self.obs_mean, dict) and isinstance(self.obs_var, dict) and isinstance(self.obs_count, dict)
                for key, rms in vec_normalize.obs_rms.items():
                    _set_rms(rms, self.obs_mean[key], self.obs_var[key], self.obs_count[key])
            else:
                _set_rms(vec_normalize.obs_rms, self.obs_mean, self.obs_var, self.obs_count)
        _set_rms(vec_normalize.ret_rms, self.ret_mean, self.ret_var, self.ret_count)
        return vec_normalize


class StatisticsMismatchError(ValueError):
    """VecNormalize statistics of another observation shape than the env's."""


def check_statistics_fit(rms: Any, mean: Any) -> None:
    """Raise :class:`StatisticsMismatchError` where ``rms`` (the env's) and ``mean`` (the statistics') differ in shape."""
    if np.shape(rms.mean) != np.shape(mean):
        raise StatisticsMismatchError(
            f"VecNormalize statistics of shape {np.shape(mean)} do not fit the env's {np.shape(rms.mean)}"
        )


def _set_rms(rms: Any, mean: Any, var: Any, count: Any) -> None:
    check_statistics_fit(rms, mean)
    rms.mean, rms.var, rms.count = np.array(mean, dtype=np.float64), np.array(var, dtype=np.float64), float(count)
