"""Hand-written feedback controllers that solve each task from the simulator state.

They prove that success is physically attainable (see ``tests/test_envs.py``) and give a reference
return for learning curves. Each is a callable ``policy(env) -> action`` on the *unwrapped* env.
Inverse kinematics by damped least squares on MuJoCo's Jacobians, then a joint-velocity servo
(``grasp_envs.control``).
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import ArmEnv, SimArrays, norm
from grasp_envs.control import grip_down_commands, reach, velocity_servo
from grasp_envs.grasper3d import Grasper3DTask


def reacher2d_policy(env: ArmEnv) -> NDArray[np.float64]:
    sim, fingertip = env.sim, int(env.model.site("fingertip").id)
    goal = sim.mocap_pos[:, 0].copy()
    goal[:, 2] = sim.site_xpos[:, fingertip, 2]
    return np.clip(reach(sim, fingertip, goal, np.arange(2)), -1, 1)[0]


def reacher3d_policy(env: ArmEnv) -> NDArray[np.float64]:
    sim = env.sim
    return np.clip(reach(sim, int(env.model.site("palm").id), sim.mocap_pos[:, 0].copy(), np.arange(4)), -0.5, 0.5)[0]


def wall_reacher3d_policy(env: ArmEnv) -> NDArray[np.float64]:
    """Keep the arm straight and horizontal (above the wall) while turning towards the target, then reach."""
    sim, palm_site = env.sim, int(env.model.site("palm").id)
    target = sim.mocap_pos[0, 0].copy()
    qpos = sim.qpos[0, :4]
    azimuth_error = np.angle(np.exp(1j * (np.arctan2(target[1], target[0]) - qpos[1])))
    palm = sim.site_xpos[0, palm_site]
    arm_up = palm[2] > -0.05
    if arm_up and (np.sign(target[0]) * palm[0] < 0.03 or abs(azimuth_error) > 0.2):
        wrapped = np.angle(np.exp(1j * qpos))
        desired = 6.0 * np.array([-wrapped[0], azimuth_error, -wrapped[2], -wrapped[3]])
        return np.clip(velocity_servo(sim, np.arange(4), np.clip(desired, -6.0, 6.0)[None]), -0.5, 0.5)[0]
    return np.clip(reach(sim, palm_site, target[None], np.arange(4)), -0.5, 0.5)[0]


GRIP_COMMAND = 0.05  # a gentle squeeze: 5 N m on the claw holds the 14 g cube; full torque squirts it out
SERVO_GRIP_COMMAND = 0.5  # v1/v2's servo: aim at -0.1 rad, ~0.5 N m on the cube (v2, 20 seeds: 0.3-1.0 all lift 14-17)
APPROACH_SPEED, LIFT_SPEED = 0.35, 0.25  # m/s of the grip site


def grasper3d_actions(
    task: Grasper3DTask,
    sim: SimArrays,
    action_low: NDArray[Any],
    action_high: NDArray[Any],
    lift: bool = True,
    hold_height: float | None = None,
) -> NDArray[np.float64]:
    """The scripted grasp's actions ``(n, action_dim)`` for ``n`` simulations of a ``Grasper3DTask``: open, align
    above the cube with the forearm down, descend, close, lift (``grasper3d_policy``)."""
    model = sim.model
    cube = task.cube_pos(sim).copy()
    grip = sim.site_xpos[:, task.grip_site]
    contacts = task.claw_cube_contacts(sim)
    holding = (contacts["right"] + contacts["left"] >= 2) & (norm(grip - cube) < 0.03)
    claw_angle = sim.qpos[:, task.claw_qpos]
    horizontal = norm((grip - cube)[:, :2])
    servo = model.actuator_biastype[-1] != mujoco.mjtBias.mjBIAS_NONE  # v1: a force-limited position servo
    aligned = horizontal < (0.02 if servo else 0.01)  # lifts in 20 seeded episodes: v1 15 (2 cm), v0 14 (1 cm)
    # finger tips just above the floor: the grip site 1 cm above the cube's centre in v0 (0.145 m along the
    # forearm), at its centre in v1 (0.155 m)
    low = cube + np.array([0.0, 0.0, 0.155 - model.site("grip").pos[0]])
    if not lift:
        rise: Any = 0.0  # hold it on the floor
    elif hold_height is None:
        rise = 0.12
    else:
        rise = hold_height - task.cube_height(sim)
    lifting = holding & (claw_angle > -0.5)
    closing = ~lifting & aligned & (grip[:, 2] - low[:, 2] < 0.006)  # close around the cube
    descending = ~lifting & aligned & ~closing  # descend, claw open
    hover = cube.copy()
    hover[:, 2] += 0.06  # hover above the cube, open
    lift_goal = cube.copy()
    lift_goal[:, 2] += rise
    goal = np.where(lifting[:, None], lift_goal, np.where((closing | descending)[:, None], low, hover))
    claw = np.where(lifting | closing, GRIP_COMMAND, -0.5)
    approach = 15.0 * (goal - grip)
    max_speed = np.where(claw > 0, LIFT_SPEED, APPROACH_SPEED)
    approach *= np.minimum(1.0, max_speed / np.maximum(norm(approach), 1e-9))[:, None]
    if servo:
        claw = np.where(claw > 0, SERVO_GRIP_COMMAND, -1.0)
    # with grip-velocity control the action is the grip velocity itself
    if task.options.control == "grip_velocity":
        arm = approach / float(task.options.max_grip_speed)
    else:
        arm = grip_down_commands(sim, approach)
    return np.clip(np.concatenate([arm, claw[:, None]], axis=1), action_low, action_high)


def grasper3d_policy(env: ArmEnv, lift: bool = True, hold_height: float | None = None) -> NDArray[np.float64]:
    """Open, align above the cube with the forearm down, descend, close, lift.

    ``lift=False`` grasps and keeps the cube on the floor: the "farm the contact reward" behaviour.
    ``hold_height``: lift until the cube's bottom is this high (m) and hold it there. ``None`` keeps commanding
    the grip 12 cm above the cube, so the cube rises until the arm runs out of reach, where the forearm tilts and
    the claw turns about it; a cube that cannot turn with the claw is then levered out (Grasper3D-v5, 40 held-out
    resets: lost after lifting 13 times; hold at 0.07: 3); one that can turn with it mostly stays (Grasper3D-v6: 2).
    """
    space = env.action_space
    assert isinstance(env.task, Grasper3DTask), f"grasper3d_policy drives the Grasper, got {type(env).__name__}"
    return grasper3d_actions(env.task, env.sim, space.low, space.high, lift, hold_height)[0]


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
