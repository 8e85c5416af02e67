"""The thesis' linear value baseline (thesis section 5.1.3; rllab's ``LinearFeatureBaseline``)."""

from __future__ import annotations

import numpy as np


class LinearFeatureBaseline:
    """Ridge regression of returns on ``[o, o^2, t, t^2, t^3, 1]``.

    ``o`` is the (normalised) observation clipped to ``[-10, 10]`` and ``t`` the step index inside
    the episode divided by ``time_scale`` (the thesis used 100). Refit in closed form on every update:
    ``w = (X^T X + l2 I)^{-1} X^T y``.

    :param l2_reg: ridge coefficient lambda (the thesis used 2)
    :param time_scale: divisor of the in-episode step index
    """

    def __init__(self, l2_reg: float = 2.0, time_scale: float = 100.0):
        if l2_reg < 0:
            raise ValueError(f"l2_reg must be >= 0, got {l2_reg}")
        if time_scale <= 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale}")
        self.l2_reg = l2_reg
        self.time_scale = time_scale
        self.weights: np.ndarray | None = None

    def features(self, observations: np.ndarray, timesteps: np.ndarray) -> np.ndarray:
        """Feature matrix ``(N, 2 * obs_dim + 4)`` in float64."""
        obs = np.clip(observations.reshape(len(observations), -1).astype(np.float64), -10.0, 10.0)
        t = (np.asarray(timesteps, dtype=np.float64) / self.time_scale).reshape(-1, 1)
        return np.concatenate([obs, obs**2, t, t**2, t**3, np.ones_like(t)], axis=1)

    def fit(self, observations: np.ndarray, timesteps: np.ndarray, returns: np.ndarray) -> None:
        """Closed-form ridge fit of ``returns`` (the bias column is regularised too, as in rllab)."""
        x = self.features(observations, timesteps)
        y = np.asarray(returns, dtype=np.float64).reshape(-1)
        gram = x.T @ x + self.l2_reg * np.eye(x.shape[1])
        weights = np.linalg.lstsq(gram, x.T @ y, rcond=None)[0]
        if np.all(np.isfinite(weights)):
            self.weights = weights

    def predict(self, observations: np.ndarray, timesteps: np.ndarray) -> np.ndarray:
        """Predicted values (zeros before the first fit)."""
        if self.weights is None:
            return np.zeros(len(observations), dtype=np.float32)
        return (self.features(observations, timesteps) @ self.weights).astype(np.float32)
