"""Hand-written feedback controllers that solve each task from the simulator state.

They prove that success is physically attainable (see ``tests/test_envs.py``) and give a reference
return for learning curves. Each is a callable ``policy(env) -> action`` on the *unwrapped* env.
Inverse kinematics by damped least squares on MuJoCo's Jacobians, then a joint-velocity servo
(``grasp_envs.control``).
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import ArmEnv
from grasp_envs.control import grip_down_commands, reach, velocity_servo


def reacher2d_policy(env: ArmEnv) -> NDArray[np.float64]:
    goal = env.data.mocap_pos[0].copy()
    goal[2] = env.data.site("fingertip").xpos[2]
    return np.clip(reach(env, "fingertip", goal, np.arange(2)), -1, 1)


def reacher3d_policy(env: ArmEnv) -> NDArray[np.float64]:
    return np.clip(reach(env, "palm", env.data.mocap_pos[0].copy(), np.arange(4)), -0.5, 0.5)


def wall_reacher3d_policy(env: ArmEnv) -> NDArray[np.float64]:
    """Keep the arm straight and horizontal (above the wall) while turning towards the target, then reach."""
    target = env.data.mocap_pos[0].copy()
    qpos = env.data.qpos[:4]
    azimuth_error = np.angle(np.exp(1j * (np.arctan2(target[1], target[0]) - qpos[1])))
    palm = env.data.site("palm").xpos
    arm_up = palm[2] > -0.05
    if arm_up and (np.sign(target[0]) * palm[0] < 0.03 or abs(azimuth_error) > 0.2):
        wrapped = np.angle(np.exp(1j * qpos))
        desired = 6.0 * np.array([-wrapped[0], azimuth_error, -wrapped[2], -wrapped[3]])
        return np.clip(velocity_servo(env, np.arange(4), np.clip(desired, -6.0, 6.0)), -0.5, 0.5)
    return np.clip(reach(env, "palm", target, np.arange(4)), -0.5, 0.5)


GRIP_COMMAND = 0.05  # a gentle squeeze: 5 N m on the claw holds the 14 g cube; full torque squirts it out
SERVO_GRIP_COMMAND = 0.5  # v1/v2's servo: aim at -0.1 rad, ~0.5 N m on the cube (v2, 20 seeds: 0.3-1.0 all lift 14-17)
APPROACH_SPEED, LIFT_SPEED = 0.35, 0.25  # m/s of the grip site


def grasper3d_policy(env: ArmEnv, lift: bool = True, hold_height: float | None = None) -> NDArray[np.float64]:
    """Open, align above the cube with the forearm down, descend, close, lift.

    ``lift=False`` grasps and keeps the cube on the floor: the "farm the contact reward" behaviour.
    ``hold_height``: lift until the cube's bottom is this high (m) and hold it there. ``None`` keeps commanding
    the grip 12 cm above the cube, so the cube rises until the arm runs out of reach, where the forearm tilts and
    the claw turns about it; a cube that cannot turn with the claw is then levered out (Grasper3D-v5, 40 held-out
    resets: lost after lifting 13 times; hold at 0.07: 3); one that can turn with it mostly stays (Grasper3D-v6: 2).
    """
    data, model = env.data, env.model
    cube = data.geom("cube").xpos.copy()
    grip = data.site("grip").xpos
    contacts = env.claw_cube_contacts()  # type: ignore[attr-defined]
    holding = contacts["right"] + contacts["left"] >= 2 and np.linalg.norm(grip - cube) < 0.03
    claw_angle = data.qpos[model.joint("claw_right").qposadr[0]]
    horizontal = np.linalg.norm((grip - cube)[:2])
    servo = model.actuator_biastype[-1] != mujoco.mjtBias.mjBIAS_NONE  # v1: a force-limited position servo
    aligned = horizontal < (0.02 if servo else 0.01)  # lifts in 20 seeded episodes: v1 15 (2 cm), v0 14 (1 cm)
    # finger tips just above the floor: the grip site 1 cm above the cube's centre in v0 (0.145 m along the
    # forearm), at its centre in v1 (0.155 m)
    low = cube + np.array([0.0, 0.0, 0.155 - model.site("grip").pos[0]])
    if holding and claw_angle > -0.5:
        if not lift:
            rise = 0.0  # hold it on the floor
        elif hold_height is None:
            rise = 0.12
        else:
            rise = hold_height - env.cube_height()  # type: ignore[attr-defined]
        goal, claw = cube + np.array([0.0, 0.0, rise]), GRIP_COMMAND
    elif aligned and grip[2] - low[2] < 0.006:
        goal, claw = low, GRIP_COMMAND  # close around the cube
    elif aligned:
        goal, claw = low, -0.5  # descend, claw open
    else:
        goal, claw = cube + np.array([0.0, 0.0, 0.06]), -0.5  # hover above the cube, open
    approach = 15.0 * (goal - grip)
    max_speed = LIFT_SPEED if claw > 0 else APPROACH_SPEED
    approach *= min(1.0, max_speed / max(float(np.linalg.norm(approach)), 1e-9))
    if servo:
        claw = SERVO_GRIP_COMMAND if claw > 0 else -1.0
    if getattr(env, "control", "joint_torque") == "grip_velocity":  # the action is the grip velocity itself
        arm = approach / env.max_grip_speed  # type: ignore[attr-defined]
    else:
        arm = grip_down_commands(env, approach)
    return np.clip(np.concatenate([arm, [claw]]), env.action_space.low, env.action_space.high)


SCRIPTED_POLICIES = {
    "Reacher2D-v0": reacher2d_policy,
    "Reacher2D-v1": reacher2d_policy,
    "Reacher3D-v0": reacher3d_policy,
    "Reacher3D-v1": reacher3d_policy,
    "WallReacher3D-v0": wall_reacher3d_policy,
    "Grasper3D-v0": grasper3d_policy,
    "Grasper3D-v1": grasper3d_policy,
    "Grasper3D-v2": grasper3d_policy,
    "Grasper3D-v3": grasper3d_policy,
    "Grasper3D-v4": grasper3d_policy,
    "Grasper3D-v5": grasper3d_policy,
    "Grasper3D-v6": grasper3d_policy,
    "Grasper3D-v7": grasper3d_policy,
}
