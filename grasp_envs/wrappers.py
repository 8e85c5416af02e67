"""Training aids: wrappers for training envs only, never for evaluation (they change the start-state distribution)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from grasp_envs.grasper3d import Grasper3DEnv
from grasp_envs.scripted import grasper3d_policy


class ScriptedStarts(gym.Wrapper[NDArray[np.float64], NDArray[np.float32], NDArray[np.float64], NDArray[np.float32]]):
    """Start a share of the Grasper's episodes somewhere along the scripted grasp (Popov et al. 2017).

    After each reset, with probability ``probability`` the scripted controller (``grasp_envs.scripted``) drives the
    arm for a uniform number of steps in ``[steps[0], steps[1])``, and the episode starts from there: the policy sees
    grasps and lifts long before its own exploration finds them. The scripted grasp closes the claw at steps 53-86,
    so ``steps=(50, 100)`` ("late" starts) begins most of those episodes with the cube grasped or lifted. These steps
    are not part of the episode (no reward, no time-limit step). ``hold_height``: the scripted grasp holds the cube
    with its bottom that high (m) instead of raising it until the arm runs out of reach.

    Random numbers come from the env's own generator, and only when ``probability > 0``, so a seeded reset is
    reproducible. Wrap training envs only (in rl-zoo YAML: ``env_wrapper``; the ``trpo-plus`` command leaves
    ``training_only`` wrappers out of its evaluation and enjoy envs).

    :param env: a Grasper3D env (``gymnasium.make("Grasper3D-v7")``), with or without Gymnasium's usual wrappers
    :param probability: share of resets that start along the scripted grasp, in [0, 1]
    :param steps: ``(low, high)``: the number of scripted steps is uniform in ``[low, high)``, ``0 <= low < high``
    :param hold_height: ``None``, or the height (m, > 0) of the cube's bottom at which the scripted grasp holds it
    """

    training_only = True

    def __init__(
        self,
        env: gym.Env[NDArray[np.float64], NDArray[np.float32]],
        probability: float = 0.25,
        steps: Sequence[int] = (0, 100),
        hold_height: float | None = None,
    ):
        super().__init__(env)
        if not isinstance(env.unwrapped, Grasper3DEnv):
            raise TypeError(f"ScriptedStarts wraps a Grasper3D env, got {type(env.unwrapped).__name__}")
        if isinstance(probability, bool) or not isinstance(probability, int | float) or not 0.0 <= probability <= 1.0:
            raise ValueError(f"ScriptedStarts probability must be a number in [0, 1], got {probability!r}")
        bounds = tuple(steps) if isinstance(steps, tuple | list) else ()
        if not (
            len(bounds) == 2
            and all(isinstance(n, int | np.integer) and not isinstance(n, bool) for n in bounds)
            and 0 <= bounds[0] < bounds[1]
        ):
            raise ValueError(f"ScriptedStarts steps must be (low, high) integers with 0 <= low < high, got {steps!r}")
        if hold_height is not None and (isinstance(hold_height, bool) or not hold_height > 0):
            raise ValueError(f"ScriptedStarts hold_height must be None or a positive height (m), got {hold_height!r}")
        self.probability = float(probability)
        self.steps = (int(bounds[0]), int(bounds[1]))
        self.hold_height = hold_height

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float64], dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        grasper: Grasper3DEnv = self.env.unwrapped  # type: ignore[assignment]
        if self.probability > 0 and grasper.np_random.uniform() < self.probability:
            for _ in range(int(grasper.np_random.integers(*self.steps))):
                action = grasper3d_policy(grasper, hold_height=self.hold_height)
                if grasper._simulate(grasper._checked_action(action)):  # unstable: start from a fresh state instead
                    return grasper.reset_model(), grasper._get_reset_info()
            observation, info = grasper._get_obs(), grasper._get_reset_info()
        return observation, info
