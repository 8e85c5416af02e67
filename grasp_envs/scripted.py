"""Hand-written feedback controllers that solve each task from the simulator state.

They prove that success is physically attainable (see ``tests/test_envs.py``) and give a reference
return for learning curves. Each is a callable ``policy(env) -> action`` on the *unwrapped* env.
Inverse kinematics by damped least squares on MuJoCo's Jacobians, then a joint-velocity servo.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import ArmEnv

_VELOCITY_GAIN = 25.0  # joint-velocity servo gain (1/s); armature 1, so torque = gain * velocity error


def _damped_least_squares(
    jacobian: NDArray[np.float64], error: NDArray[np.float64], damping: float = 1e-3
) -> NDArray[np.float64]:
    jjt = jacobian @ jacobian.T
    return jacobian.T @ np.linalg.solve(jjt + damping * np.eye(len(jjt)), error)


def _velocity_servo(env: ArmEnv, dofs: NDArray[np.int64], desired_velocity: NDArray[np.float64]) -> NDArray[np.float64]:
    """Actuator commands that drive the joints ``dofs`` towards ``desired_velocity`` (gravity compensated)."""
    gear = env.model.actuator_gear[: len(dofs), 0]
    torque = _VELOCITY_GAIN * (desired_velocity - env.data.qvel[dofs]) + env.data.qfrc_bias[dofs] + env.data.qvel[dofs]
    return torque / gear


def _site_jacobian(env: ArmEnv, site: str, dofs: NDArray[np.int64]) -> NDArray[np.float64]:
    jacp = np.zeros((3, env.model.nv))
    mujoco.mj_jacSite(env.model, env.data, jacp, None, env.model.site(site).id)
    return jacp[:, dofs]


def reach(
    env: ArmEnv, site: str, goal: NDArray[np.float64], dofs: NDArray[np.int64], speed: float = 8.0
) -> NDArray[np.float64]:
    """Commands moving ``site`` towards ``goal`` with the joints ``dofs``."""
    error = goal - env.data.site(site).xpos
    velocity = _damped_least_squares(_site_jacobian(env, site, dofs), speed * error)
    return _velocity_servo(env, dofs, np.clip(velocity, -10.0, 10.0))


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
        return np.clip(_velocity_servo(env, np.arange(4), np.clip(desired, -6.0, 6.0)), -0.5, 0.5)
    return np.clip(reach(env, "palm", target, np.arange(4)), -0.5, 0.5)


GRIP_COMMAND = 0.05  # a gentle squeeze: 5 N m on the claw holds the 14 g cube; full torque squirts it out
SERVO_GRIP_COMMAND = 0.5  # Grasper3D-v1's servo: aim at -0.1 rad, ~1 N m on the cube (more squeezes it out)
APPROACH_SPEED, LIFT_SPEED = 0.35, 0.25  # m/s of the grip site


def grasper3d_policy(env: ArmEnv, lift: bool = True) -> NDArray[np.float64]:
    """Open, align above the cube with the forearm down, descend, close, lift.

    ``lift=False`` grasps and keeps the cube on the floor: the "farm the contact reward" behaviour.
    """
    data, model = env.data, env.model
    cube = data.geom("cube").xpos.copy()
    grip = data.site("grip").xpos
    dofs = np.arange(5)
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
        goal, claw = cube + np.array([0.0, 0.0, 0.12 if lift else 0.0]), GRIP_COMMAND  # lift (or hold on the floor)
    elif aligned and grip[2] - low[2] < 0.006:
        goal, claw = low, GRIP_COMMAND  # close around the cube
    elif aligned:
        goal, claw = low, -0.5  # descend, claw open
    else:
        goal, claw = cube + np.array([0.0, 0.0, 0.06]), -0.5  # hover above the cube, open
    # Task: grip position (3 rows), claw closing axis horizontal (1 row), forearm pointing down (1 row)
    xmat = data.body("forearm").xmat.reshape(3, 3)
    axis, closing = xmat[:, 0], xmat[:, 1]
    jacr = np.zeros((3, model.nv))
    mujoco.mj_jacBody(model, data, None, jacr, model.body("forearm").id)
    up = np.array([0.0, 0.0, 1.0])
    jacobian = np.vstack(
        [
            _site_jacobian(env, "grip", dofs),
            np.cross(closing, up) @ jacr[:, dofs],
            0.2 * np.cross(axis, up) @ jacr[:, dofs],
        ]
    )
    approach = 15.0 * (goal - grip)
    max_speed = LIFT_SPEED if claw > 0 else APPROACH_SPEED
    approach *= min(1.0, max_speed / max(float(np.linalg.norm(approach)), 1e-9))
    error = np.concatenate([approach, [-4.0 * closing @ up], [0.2 * 4.0 * (-1.0 - axis @ up)]])
    velocity = np.clip(_damped_least_squares(jacobian, error, damping=1e-4), -10.0, 10.0)
    low, high = model.actuator_ctrlrange[:, 0], model.actuator_ctrlrange[:, 1]
    if servo:
        claw = SERVO_GRIP_COMMAND if claw > 0 else low[-1]
    return np.clip(np.concatenate([_velocity_servo(env, dofs, velocity), [claw]]), low, high)


SCRIPTED_POLICIES = {
    "Reacher2D-v0": reacher2d_policy,
    "Reacher2D-v1": reacher2d_policy,
    "Reacher3D-v0": reacher3d_policy,
    "Reacher3D-v1": reacher3d_policy,
    "WallReacher3D-v0": wall_reacher3d_policy,
    "Grasper3D-v0": grasper3d_policy,
    "Grasper3D-v1": grasper3d_policy,
}
