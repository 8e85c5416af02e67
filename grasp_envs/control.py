"""Joint-level feedback control shared by the scripted controllers and the Grasper's grip-velocity actions.

Inverse kinematics by damped least squares on the arm's Jacobians, then a joint-velocity servo with gravity
(bias-force) compensation. Every function works on ``n`` simulations at once (``grasp_envs.base.SimArrays``, a
leading simulation axis on every array) and reads the state MuJoCo computed at the last physics call.
"""

from __future__ import annotations

import mujoco
import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import SimArrays

VELOCITY_GAIN = 25.0  # joint-velocity servo gain (1/s); armature 1, so torque = gain * velocity error
MAX_JOINT_SPEED = 10.0  # rad/s asked of any joint by the inverse kinematics
ARM_DOFS = np.arange(5)  # the Grasper's five arm joints, the first five degrees of freedom
ARM_DOFS.flags.writeable = False

Array = NDArray[np.float64]


def cross(a: Array, b: Array) -> Array:
    """Cross products over the last axis, in the operation order of MuJoCo's ``mju_cross`` (bit-equal results)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def chain_dofs(model: mujoco.MjModel, body: int) -> NDArray[np.int64]:
    """The degrees of freedom that move ``body``: its own and its ancestors', from the body up."""
    dofs: list[int] = []
    while body > 0:
        start = model.body_dofadr[body]
        dofs.extend(range(start, start + model.body_dofnum[body]))
        body = model.body_parentid[body]
    return np.array(dofs, dtype=np.int64)


def point_jacobians(sim: SimArrays, body: int, point: Array, dofs: NDArray[np.int64] | None = None) -> tuple[Array, Array]:
    """Translational and rotational Jacobians ``(n, 3, nv)`` of the world points ``point`` ``(n, 3)`` fixed to
    ``body``: MuJoCo's ``mj_jac``; with ``dofs``, only those columns, ``(n, 3, len(dofs))``. One ``MjData`` (a batch of
    one) calls it; a batch computes it for all simulations at once from the bound ``cdof`` and ``subtree_com``, in
    ``mj_jac``'s operation order (bit-equal, tested), for the asked columns only."""
    model = sim.model
    if sim.data is not None:
        jacp = np.zeros((1, 3, model.nv))
        jacr = np.zeros((1, 3, model.nv))
        mujoco.mj_jac(model, sim.data, jacp[0], jacr[0], point[0], body)
        return (jacp, jacr) if dofs is None else (jacp[:, :, dofs], jacr[:, :, dofs])
    key = (body, None if dofs is None else tuple(dofs.tolist()))
    columns = sim.chains.get(key)
    if columns is None:
        columns = sim.chains[key] = chain_columns(model, body, np.arange(model.nv) if dofs is None else dofs)
    chain, where, width = columns
    if dofs is None:
        jacp, jacr = np.zeros((sim.n, 3, width)), np.zeros((sim.n, 3, width))
    else:  # laid out as the one-MjData path's jacp[:, :, dofs], so that products with them round the same on both
        jacp, jacr = np.zeros((width, sim.n, 3)).transpose(1, 2, 0), np.zeros((width, sim.n, 3)).transpose(1, 2, 0)
    offset = point - sim.subtree_com[:, model.body_rootid[body]]
    motion = sim.cdof[:, chain]  # (n, k, 6): rotation then translation
    jacp[:, :, where] = (motion[..., 3:] + cross(motion[..., :3], offset[:, None, :])).transpose(0, 2, 1)
    jacr[:, :, where] = motion[..., :3].transpose(0, 2, 1)
    return jacp, jacr


def chain_columns(
    model: mujoco.MjModel, body: int, dofs: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64], int]:
    """The degrees of freedom among ``dofs`` that move ``body`` (``chain_dofs``), the columns of a Jacobian over
    ``dofs`` they fill, and how many columns it has."""
    column_of = {int(dof): column for column, dof in enumerate(np.asarray(dofs).tolist())}
    chain = np.array([dof for dof in chain_dofs(model, body).tolist() if dof in column_of], dtype=np.int64)
    return chain, np.array([column_of[dof] for dof in chain.tolist()], dtype=np.int64), len(column_of)


def site_jacobian(sim: SimArrays, site: int, dofs: NDArray[np.int64]) -> Array:
    """Translational Jacobian of a site with respect to the joints ``dofs``, ``(n, 3, len(dofs))``."""
    jacp, _ = point_jacobians(sim, int(sim.model.site_bodyid[site]), sim.site_xpos[:, site], dofs)
    return jacp


def damped_least_squares(jacobian: Array, error: Array, damping: float = 1e-3) -> Array:
    """``J^T (J J^T + damping I)^{-1} error`` per simulation: the joint motion that best produces ``error``.
    ``jacobian`` is ``(n, m, k)``, ``error`` ``(n, m)``."""
    jjt = jacobian @ jacobian.transpose(0, 2, 1)
    solved = np.linalg.solve(jjt + damping * np.eye(jjt.shape[-1]), error[..., None])
    return (jacobian.transpose(0, 2, 1) @ solved)[..., 0]


def damped_pseudo_inverse(jacobian: Array, damping: float = 1e-3) -> Array:
    """``J^T (J J^T + damping I)^{-1}`` per simulation, the matrix ``damped_least_squares`` applies to an error."""
    jjt = jacobian @ jacobian.transpose(0, 2, 1)
    return jacobian.transpose(0, 2, 1) @ np.linalg.inv(jjt + damping * np.eye(jjt.shape[-1]))


def velocity_servo(sim: SimArrays, dofs: NDArray[np.int64], desired_velocity: Array) -> Array:
    """Actuator commands (torque / gear) that drive the joints ``dofs`` towards ``desired_velocity`` ``(n, k)``.

    The first ``len(dofs)`` actuators must drive ``dofs`` in order. Gravity and Coriolis forces (``qfrc_bias``) and
    the joints' damping (1 N m s/rad) are compensated.
    """
    gear = sim.model.actuator_gear[: len(dofs), 0]
    qvel = sim.qvel[:, dofs]
    torque = VELOCITY_GAIN * (desired_velocity - qvel) + sim.qfrc_bias[:, dofs] + qvel
    return torque / gear


def reach(sim: SimArrays, site: int, goal: Array, dofs: NDArray[np.int64], speed: float = 8.0) -> Array:
    """Commands moving ``site`` towards ``goal`` ``(n, 3)`` with the joints ``dofs``."""
    error = goal - sim.site_xpos[:, site]
    velocity = damped_least_squares(site_jacobian(sim, site, dofs), speed * error)
    return velocity_servo(sim, dofs, np.clip(velocity, -MAX_JOINT_SPEED, MAX_JOINT_SPEED))


def grip_down_commands(sim: SimArrays, grip_velocity: Array, grip_priority: bool = False) -> Array:
    """Commands of the Grasper's five arm motors: the velocity servo driving ``grip_down_velocity``."""
    return velocity_servo(sim, ARM_DOFS, grip_down_velocity(sim, grip_velocity, grip_priority))


def grip_down_velocity(sim: SimArrays, grip_velocity: Array, grip_priority: bool = False) -> Array:
    """Velocities ``(n, 5)`` of the Grasper's five arm joints (rad/s) that move its grip site at ``grip_velocity``
    ``(n, 3)`` (m/s) while turning the forearm to point down and the claw's closing axis to lie horizontal.

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
    model = sim.model
    dofs = ARM_DOFS
    forearm = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "forearm")
    xmat = sim.xmat[:, forearm].reshape(-1, 3, 3)
    axis, closing = xmat[:, :, 0], xmat[:, :, 1]
    _, jacr = point_jacobians(sim, forearm, sim.xpos[:, forearm], dofs)
    up = np.zeros_like(axis)
    up[:, 2] = 1.0
    grip = site_jacobian(sim, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "grip"), dofs)
    closing_row = (cross(closing, up)[:, None, :] @ jacr)[:, 0]
    primary = np.concatenate([grip, closing_row[:, None, :]], axis=1)
    primary_error = np.concatenate([grip_velocity, -4.0 * closing[:, 2:3]], axis=1)
    down = (cross(axis, up)[:, None, :] @ jacr)[:, 0]
    down_error = 4.0 * (-1.0 - axis[:, 2])
    if grip_priority:
        inverse = damped_pseudo_inverse(primary, damping=1e-4)
        velocity = (inverse @ primary_error[..., None])[..., 0]
        null = np.eye(len(dofs)) - inverse @ primary
        down_null = down[:, None, :] @ null
        residual = down_error - (down[:, None, :] @ velocity[..., None])[:, 0, 0]
        velocity = velocity + (null @ damped_least_squares(down_null, residual[:, None], damping=1e-3)[..., None])[..., 0]
    else:
        jacobian = np.concatenate([primary, 0.2 * down[:, None, :]], axis=1)
        error = np.concatenate([primary_error, 0.2 * down_error[:, None]], axis=1)
        velocity = damped_least_squares(jacobian, error, damping=1e-4)
    return np.clip(velocity, -MAX_JOINT_SPEED, MAX_JOINT_SPEED)
