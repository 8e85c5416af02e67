"""Joint-level feedback control shared by the scripted controllers and Grasper3D-v2's end-effector actions.

Inverse kinematics by damped least squares on MuJoCo's Jacobians, then a joint-velocity servo with gravity
(bias-force) compensation. Every function reads the simulator state of an unwrapped ``ArmEnv``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from grasp_envs.base import ArmEnv

VELOCITY_GAIN = 25.0  # joint-velocity servo gain (1/s); armature 1, so torque = gain * velocity error
MAX_JOINT_SPEED = 10.0  # rad/s asked of any joint by the inverse kinematics
_UP = np.array([0.0, 0.0, 1.0])


def damped_least_squares(
    jacobian: NDArray[np.float64], error: NDArray[np.float64], damping: float = 1e-3
) -> NDArray[np.float64]:
    """``J^T (J J^T + damping I)^{-1} error``: the joint motion that best produces ``error``."""
    jjt = jacobian @ jacobian.T
    return jacobian.T @ np.linalg.solve(jjt + damping * np.eye(len(jjt)), error)


def damped_pseudo_inverse(jacobian: NDArray[np.float64], damping: float = 1e-3) -> NDArray[np.float64]:
    """``J^T (J J^T + damping I)^{-1}``, the matrix ``damped_least_squares`` applies to an error."""
    jjt = jacobian @ jacobian.T
    return jacobian.T @ np.linalg.inv(jjt + damping * np.eye(len(jjt)))


def velocity_servo(env: ArmEnv, dofs: NDArray[np.int64], desired_velocity: NDArray[np.float64]) -> NDArray[np.float64]:
    """Actuator commands (torque / gear) that drive the joints ``dofs`` towards ``desired_velocity``.

    The first ``len(dofs)`` actuators must drive ``dofs`` in order. Gravity and Coriolis forces
    (``qfrc_bias``) and the joints' damping (1 N m s/rad) are compensated.
    """
    gear = env.model.actuator_gear[: len(dofs), 0]
    qvel = env.data.qvel[dofs]
    torque = VELOCITY_GAIN * (desired_velocity - qvel) + env.data.qfrc_bias[dofs] + qvel
    return torque / gear


def site_jacobian(env: ArmEnv, site: str, dofs: NDArray[np.int64]) -> NDArray[np.float64]:
    """Translational Jacobian of a site with respect to the joints ``dofs``, shape ``(3, len(dofs))``."""
    jacp = np.zeros((3, env.model.nv))
    mujoco.mj_jacSite(env.model, env.data, jacp, None, env.model.site(site).id)
    return jacp[:, dofs]


def reach(
    env: ArmEnv, site: str, goal: NDArray[np.float64], dofs: NDArray[np.int64], speed: float = 8.0
) -> NDArray[np.float64]:
    """Commands moving ``site`` towards ``goal`` with the joints ``dofs``."""
    error = goal - env.data.site(site).xpos
    velocity = damped_least_squares(site_jacobian(env, site, dofs), speed * error)
    return velocity_servo(env, dofs, np.clip(velocity, -MAX_JOINT_SPEED, MAX_JOINT_SPEED))


def grip_down_commands(env: ArmEnv, grip_velocity: NDArray[np.float64], grip_priority: bool = False) -> NDArray[np.float64]:
    """Commands of the Grasper's five arm motors: the velocity servo driving ``grip_down_velocity``."""
    return velocity_servo(env, np.arange(5), grip_down_velocity(env, grip_velocity, grip_priority))


def grip_down_velocity(env: ArmEnv, grip_velocity: NDArray[np.float64], grip_priority: bool = False) -> NDArray[np.float64]:
    """Velocities of the Grasper's five arm joints (rad/s) that move its grip site at ``grip_velocity`` (m/s)
    while turning the forearm to point down and the claw's closing axis to lie horizontal.

    The task has five rows for five joints: the grip velocity (3), the closing axis' vertical component
    driven to zero (1) and the forearm axis driven towards -z (1, weighted 0.2). The claw's yaw about the
    vertical stays free, as in the scripted grasp.

    ``grip_priority=True``: task-priority inverse kinematics (Nakamura 1991; Siciliano and Slotine 1991).
    The grip velocity and the horizontal closing axis are met first; the forearm turns down only within the
    one joint direction they leave free (their Jacobian's null space). With one stack of five rows, where the
    arm cannot move the grip with the forearm vertical the two compete and the grip stalls: the scripted
    grasp (20 seeded episodes) lifted the cube only 3.9 cm at 6.4 cm from the axis and grasped none of the
    three cubes within 4.3 cm of it (with priority: lifted 6 cm, and one of the three lifted 12 cm).
    """
    model, data = env.model, env.data
    dofs = np.arange(5)
    xmat = data.body("forearm").xmat.reshape(3, 3)
    axis, closing = xmat[:, 0], xmat[:, 1]
    jacr = np.zeros((3, model.nv))
    mujoco.mj_jacBody(model, data, None, jacr, model.body("forearm").id)
    up = _UP
    primary = np.vstack([site_jacobian(env, "grip", dofs), np.cross(closing, up) @ jacr[:, dofs]])
    primary_error = np.concatenate([grip_velocity, [-4.0 * closing @ up]])
    down, down_error = np.cross(axis, up) @ jacr[:, dofs], 4.0 * (-1.0 - axis @ up)
    if grip_priority:
        inverse = damped_pseudo_inverse(primary, damping=1e-4)
        velocity = inverse @ primary_error
        null = np.eye(len(dofs)) - inverse @ primary
        down_null = (down @ null)[None, :]
        velocity += null @ damped_least_squares(down_null, np.array([down_error - down @ velocity]), damping=1e-3)
    else:
        jacobian = np.vstack([primary, 0.2 * down])
        velocity = damped_least_squares(jacobian, np.append(primary_error, 0.2 * down_error), damping=1e-4)
    return np.clip(velocity, -MAX_JOINT_SPEED, MAX_JOINT_SPEED)
