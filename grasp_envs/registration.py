"""Every registered id is a row of one preset table: the task's class, its options, the time limit and the threshold.

As Gymnasium registers ``LunarLanderContinuous-v3`` as ``LunarLander`` with ``continuous=True``, ``Grasper3D-v4`` is
``Grasper3DEnv`` with the options that version introduced. A released row is frozen: a change of observation, reward
or dynamics is a new option and a new row (``tests/test_env_presets.py`` replays recorded trajectories of each).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from gymnasium.envs.registration import register, registry


@dataclass(frozen=True)
class Preset:
    """One registered id: ``entry_point`` made with ``kwargs``, truncated after ``max_episode_steps``."""

    entry_point: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    max_episode_steps: int = 100
    reward_threshold: float | None = None


REACHER2D = "grasp_envs.reacher2d:Reacher2DEnv"
REACHER3D = "grasp_envs.reacher3d:Reacher3DEnv"
WALL_REACHER3D = "grasp_envs.wall_reacher3d:WallReacher3DEnv"
GRASPER3D = "grasp_envs.grasper3d:Grasper3DEnv"

# The Grasper's versions, each the one before with what it changed (the class docstring's Version History)
GRASPER_V0: dict[str, Any] = {
    "claw": "torque",
    "control": "joint_torque",
    "observation": "joint",
    "observe_claw_torque": False,
    "cube_rotation": None,
    "start_pose": "stretched",
    "reach_distance": "grip",
    "grasp_test": "touch",
    "reward_grasp_weight": 1.0,
    "reward_lift_weight": 2.0,
    "reward_hold_weight": 2.0,
    "reward_floor_weight": 0.0,
    "reward_squeeze_weight": 0.0,
}
GRASPER_V1 = GRASPER_V0 | {
    "claw": "servo",
    "reach_distance": "claw_segment",
    "grasp_test": "between",
    "reward_grasp_weight": 4.0,
    "reward_lift_weight": 4.0,
    "reward_hold_weight": 4.0,
    "reward_floor_weight": 1.0,
}
GRASPER_V2 = GRASPER_V1 | {"control": "grip_velocity", "ik_mode": "weighted"}
GRASPER_V3 = GRASPER_V2 | {"reward_squeeze_weight": 2.0, "observe_claw_torque": True}
GRASPER_V4 = GRASPER_V3 | {"ik_mode": "priority", "grasp_test": "per_axis"}
GRASPER_V5 = GRASPER_V4 | {"observation": "task"}
GRASPER_V6 = GRASPER_V5 | {"cube_rotation": "yaw"}
GRASPER_V7 = GRASPER_V6 | {"start_pose": "ready"}

# Thresholds are measured returns of a solution, rounded down: the hand-written controllers of grasp_envs.scripted
# (mean of 20 episodes, seeds 0-19: Reacher3D -8.2, WallReacher3D -45.1, Grasper3D 91.7, Grasper3D-v1 214.9,
# Grasper3D-v2 210.8, Grasper3D-v3 243.0, Grasper3D-v4 253.4, Grasper3D-v6 303.0, Grasper3D-v7 589.1, Reacher2D-v1
# 5.4, Reacher3D-v1 30.6) and, for Reacher2D-v0, a trained TRPOPlus policy (-3.9; the controller's large torques cost
# -8.0 there). Grasper3D-v5's is v4's: it only observes differently, with v4's dynamics and reward, and the
# controller, which reads the simulator state, returns the same 253.4 there.
PRESETS: dict[str, Preset] = {
    "Reacher2D-v0": Preset(REACHER2D, {"reward_near_weight": 0.0}, 50, -4.0),
    "Reacher2D-v1": Preset(REACHER2D, {"reward_near_weight": 0.5}, 50, 5.0),
    "Reacher3D-v0": Preset(REACHER3D, {"reward_near_weight": 0.0}, 100, -8.0),
    "Reacher3D-v1": Preset(REACHER3D, {"reward_near_weight": 0.5}, 100, 30.0),
    "WallReacher3D-v0": Preset(WALL_REACHER3D, {}, 100, -45.0),
    "Grasper3D-v0": Preset(GRASPER3D, GRASPER_V0, 100, 90.0),
    "Grasper3D-v1": Preset(GRASPER3D, GRASPER_V1, 100, 210.0),
    "Grasper3D-v2": Preset(GRASPER3D, GRASPER_V2, 100, 210.0),
    "Grasper3D-v3": Preset(GRASPER3D, GRASPER_V3, 100, 240.0),
    "Grasper3D-v4": Preset(GRASPER3D, GRASPER_V4, 100, 250.0),
    "Grasper3D-v5": Preset(GRASPER3D, GRASPER_V5, 100, 250.0),  # v4's, as its return is v4's
    "Grasper3D-v6": Preset(GRASPER3D, GRASPER_V6, 100, 300.0),
    "Grasper3D-v7": Preset(GRASPER3D, GRASPER_V7, 100, 580.0),
}
ENV_IDS = tuple(PRESETS)
RECOMMENDED_GRASPER = "Grasper3D-v7"


def register_presets() -> None:
    """Register every preset with Gymnasium (ids already registered are left as they are)."""
    for env_id, preset in PRESETS.items():
        if env_id not in registry:
            register(
                id=env_id,
                entry_point=preset.entry_point,
                kwargs=dict(preset.kwargs),
                max_episode_steps=preset.max_episode_steps,
                reward_threshold=preset.reward_threshold,
            )
