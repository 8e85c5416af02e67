"""Grasper3D's options: what each one accepts, checked when they are made (``Grasper3DOptions``), and the choices
and defaults they are made of. ``grasp_envs.grasper3d`` holds the task that runs them and the Gymnasium env."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from grasp_envs.base import TaskOptions
from grasp_envs.options import amount, choice, flag, integer, option, path

REWARD_MODES = ("staged", "thesis")
CLAWS = {"torque": "grasper3d.xml", "servo": "grasper3d_v1.xml"}  # claw -> the model it comes with
CONTROLS = ("joint_torque", "grip_velocity")
IK_MODES = ("weighted", "priority")
OBSERVATIONS = ("joint", "task")
REACH_DISTANCES = ("grip", "claw_segment")
GRASP_TESTS = ("touch", "between", "per_axis")

MAX_GRIP_SPEED = 0.4  # m/s of the grip site at an action of 1

# Claw servo torque (N m) at which reward_squeeze saturates: a firm squeeze of the scripted grasp (the torques it
# measured per closing command are in docs/environments.md, "The squeeze torque").
SQUEEZE_TORQUE = 0.5

# cube_rotation -> the joint that lets the cube turn: "yaw" about the world's vertical (it stays upright), "free" about
# every axis (it can also tip over: the claw tumbles it on the floor and learning was slower)
CUBE_ROTATIONS: dict[str, dict[str, Any]] = {
    "yaw": {"type": mujoco.mjtJoint.mjJNT_HINGE, "axis": [0.0, 0.0, 1.0]},
    "free": {"type": mujoco.mjtJoint.mjJNT_BALL},
}
# start_pose -> the arm's joint angles before the reset noise (shoulder_y, shoulder_z, elbow_y, elbow_z, forearm_roll):
# "stretched", the thesis' (horizontal along +x); "ready", the upper arm pitched 30 deg up and the forearm pointing
# down, the grip 8.7 cm out along +x and 7 cm above the cube's top face, as manipulation benchmarks start
# (Gymnasium Robotics' Fetch: the gripper above the table)
START_POSES: dict[str, tuple[float, ...]] = {
    "stretched": (0.0, 0.0, 0.0, 0.0, 0.0),
    "ready": (-np.pi / 6, 0.0, 2 * np.pi / 3, 0.0, 0.0),
}


@dataclass(frozen=True)
class Grasper3DOptions(TaskOptions):
    """Grasper3D's options (``Grasper3DEnv``'s Arguments), each checked when they are made, with the rules that tie
    them together (the claw rate and the servo's torque need the servo claw)."""

    xml_file: str | None = option(None, path(optional=True))
    frame_skip: int = option(2, integer(1))
    claw: str = option("servo", choice(CLAWS))
    control: str = option("grip_velocity", choice(CONTROLS))
    ik_mode: str = option("priority", choice(IK_MODES))
    max_grip_speed: float = option(MAX_GRIP_SPEED, amount(positive=True))
    claw_rate: float | None = option(None, amount(positive=True, optional=True))
    observation: str = option("task", choice(OBSERVATIONS))
    observe_claw_torque: bool | None = option(None, flag(optional=True))
    cube_rotation: str | None = option("yaw", choice((None, *CUBE_ROTATIONS)))
    start_pose: str = option("ready", choice(START_POSES))
    reward_mode: str = option("staged", choice(REWARD_MODES))
    reach_distance: str = option("claw_segment", choice(REACH_DISTANCES))
    grasp_test: str = option("per_axis", choice(GRASP_TESTS))
    reward_reach_weight: float = option(1.0, amount())
    reward_grasp_weight: float = option(4.0, amount())
    reward_lift_weight: float = option(4.0, amount())
    reward_hold_weight: float = option(4.0, amount())
    reward_floor_weight: float = option(1.0, amount())
    reward_squeeze_weight: float | None = option(None, amount(optional=True))
    squeeze_torque: float = option(SQUEEZE_TORQUE, amount(positive=True))
    reward_control_weight: float | None = option(None, amount(optional=True))
    terminate_on_success: bool | None = option(None, flag(optional=True))
    reset_noise_scale: float = option(0.1, amount())
    lift_height: float = option(0.05, amount(positive=True))

    def __post_init__(self) -> None:
        super().__post_init__()
        servo = self.claw == "servo"
        if self.claw_rate is not None and not (self.control == "grip_velocity" and servo):
            raise ValueError("claw_rate moves the servo claw's target: it needs control='grip_velocity' and claw='servo'")
        if not servo and (self.reward_squeeze_weight or self.observe_claw_torque):  # None and 0 ask for nothing
            raise ValueError(
                "reward_squeeze_weight and observe_claw_torque read the claw servo's torque: they need claw='servo'"
            )


__all__ = ["CLAWS", "CUBE_ROTATIONS", "START_POSES", "Grasper3DOptions"]
