"""``crashing_env:CrashOnce-v0``: an env whose process exits at a chosen step, once per marker file (the first env
to create the file exits; later envs, e.g. a restarted worker's, run on). For the rollout workers' fault tests."""

from __future__ import annotations

import os
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces


class CrashOnce(gym.Env):
    observation_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
    action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    def __init__(self, marker: str, at_step: int = 10):
        self.marker, self.at_step, self.steps = marker, at_step, 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        return self.np_random.uniform(-1, 1, 3).astype(np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.steps += 1
        if self.steps == self.at_step:
            try:
                os.close(os.open(self.marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
            except FileExistsError:
                pass
            else:
                os._exit(3)
        return self.np_random.uniform(-1, 1, 3).astype(np.float32), float(action[0]), False, False, {}


gym.register("CrashOnce-v0", entry_point=CrashOnce, max_episode_steps=25)
