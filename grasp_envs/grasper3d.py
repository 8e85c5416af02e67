"""Grasper3D: grasp a 24 mm cube and lift it (thesis section 5.2.3). One class; every registered version is a preset."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
from gymnasium.spaces import Box
from numpy.typing import NDArray

from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D, ArmEnv, ArmTask, SimArrays, asset_path, norm
from grasp_envs.control import grip_down_commands, point_jacobians
from grasp_envs.grasper3d_options import CLAWS, CUBE_ROTATIONS, START_POSES, Grasper3DOptions

ARM_JOINTS = ("shoulder_y", "shoulder_z", "elbow_y", "elbow_z", "forearm_roll")
CLAW_SIDES = ("right", "left")
CLAW_PARTS = ("outer_top", "inner_top", "outer_bottom", "inner_bottom")
FLOOR_Z = -0.2
CUBE_HALF_SIZE = 0.012

CLAW_OPEN_TARGET, CLAW_SERVO_SLOPE = -0.3, 0.4  # the servo claw aims at -0.3 + 0.4 c rad
CLAW_TARGET_RANGE = (-0.7, 0.1)  # what the servo can aim at (ctrl in [-1, 1])
# grasp_test "between": how far (m) the cube's centre may lie from the segment between the claw sites, in all
BETWEEN_TOLERANCE = 0.02
# grasp_test "per_axis": the same along the forearm and along the claw's hinge axis, each. The inner capsules span
# 1.25 cm either side of the sites along the forearm and are 6 mm thick, the cube's half-size is 1.2 cm: a cube held by
# the tips sits up to ~2.45 cm out, one pressed from beyond the tips >= 3.05 cm. Along the hinge axis the capsules sit
# at +-0.8 cm: any grip of a side face is within 2.6 cm.
PER_AXIS_TOLERANCE = 0.025

CUBE_ROTATION_JOINT = "cube_rotation"
CUBE_ROTATION_DAMPING = 1e-4  # N m s/rad per axis; the cube's inertia is 1.3e-6 kg m^2 about each axis
# observation="task" keeps these rows of the joint-space observation: everything but the arm's joint angles and
# joint velocities (the claw angle, the claw velocity, the cube, the claw sites relative to it, the contacts, and the
# claw torque where it is observed)
TASK_KEPT_JOINT_ROWS = np.r_[10, 16:32]
CLAW_GEOMS = tuple(f"claw_{side}_{part}" for side in CLAW_SIDES for part in CLAW_PARTS)  # right's four, then left's
# the contacts the task counts, each pair's in MuJoCo's contact list: every claw capsule with the cube (rows 0-7) and
# with the floor (8-15), every right capsule with every left one (16-31)
CONTACT_PAIRS = (
    tuple((geom, "cube") for geom in CLAW_GEOMS)
    + tuple((geom, "floor") for geom in CLAW_GEOMS)
    + tuple((right, left) for right in CLAW_GEOMS[:4] for left in CLAW_GEOMS[4:])
)
_BOTTOM_FLOOR_ROWS = np.array([8 + i for i, geom in enumerate(CLAW_GEOMS) if "bottom" in geom])

Array = NDArray[np.float64]
Flags = NDArray[np.bool_]


class Grasper3DTask(ArmTask):
    """Grasper3D's step logic over ``n`` simulations. The options whose ``None`` the claw or the reward mode decides
    (``xml_file``, ``observe_claw_torque``, ``reward_squeeze_weight``, ``reward_control_weight``,
    ``terminate_on_success``) read as the task's attributes with that decided."""

    options: Grasper3DOptions
    contact_pairs = CONTACT_PAIRS

    def __init__(self, options: Grasper3DOptions):
        super().__init__(options)
        self.observation_dim = (
            (31 if options.observation == "joint" else 25)
            + int(self.observe_claw_torque)
            + (6 if options.cube_rotation is not None else 0)
        )

    @property
    def xml_file(self) -> str:
        """The model: the ``xml_file`` option, or (``None``) the model of the claw."""
        return self.options.xml_file or CLAWS[self.options.claw]

    @property
    def observe_claw_torque(self) -> bool:
        """Whether the claw servo's torque is observed (``None``: with the servo claw)."""
        observe = self.options.observe_claw_torque
        return self.options.claw == "servo" if observe is None else observe

    @property
    def reward_squeeze_weight(self) -> float:
        """The weight of ``reward_squeeze`` (``None``: 2 with the servo claw, else 0)."""
        weight = self.options.reward_squeeze_weight
        return (2.0 if self.options.claw == "servo" else 0.0) if weight is None else weight

    @property
    def reward_control_weight(self) -> float:
        """The weight of ``reward_ctrl`` (``None``: 1 in thesis mode, else 0.1)."""
        weight = self.options.reward_control_weight
        return (1.0 if self.options.reward_mode == "thesis" else 0.1) if weight is None else weight

    @property
    def terminate_on_success(self) -> bool:
        """Whether success ends the episode (``None``: in thesis mode only)."""
        terminate = self.options.terminate_on_success
        return self.options.reward_mode == "thesis" if terminate is None else terminate

    # ------------------------------------------------------------------ the model
    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        if self.options.cube_rotation is not None:
            add_cube_rotation(spec, self.options.cube_rotation)

    def action_space(self, model: mujoco.MjModel) -> Box:
        if self.options.control == "grip_velocity":
            return Box(low=-1.0, high=1.0, shape=(4,), dtype=np.float32)
        return super().action_space(model)

    def setup(self, model: mujoco.MjModel, n: int) -> None:
        super().setup(model, n)
        self.arm_qpos = np.array([model.joint(j).qposadr[0] for j in ARM_JOINTS])
        self.arm_qvel = np.array([model.joint(j).dofadr[0] for j in ARM_JOINTS])
        self.cube_qpos = np.array([model.joint(f"cube_{a}").qposadr[0] for a in "xyz"])
        self.cube_dofs = np.array([model.joint(f"cube_{a}").dofadr[0] for a in "xyz"])
        self.cube_body_pos = model.body("cube").pos.copy()
        self.claw_qpos = int(model.joint("claw_right").qposadr[0])
        self.claw_left_qpos = int(model.joint("claw_left").qposadr[0])
        self.claw_qvel = int(model.joint("claw_right").dofadr[0])
        self.claw_actuator = int(model.actuator("claw").id)
        self.cube_geom = self.geom_id("cube")
        self.forearm_body = int(model.body("forearm").id)
        self.grip_site, self.palm_site = self.site_id("grip"), self.site_id("palm")
        self.claw_sites = self.site_id("claw_right"), self.site_id("claw_left")
        if self.options.start_pose != "stretched":
            self.init_qpos[self.arm_qpos] = START_POSES[self.options.start_pose]
        self.lift_bonus_paid = np.zeros(n, dtype=bool)
        self.claw_target = np.full(n, CLAW_OPEN_TARGET)
        self.contacts = self.no_contacts(n)

    @staticmethod
    def no_contacts(n: int) -> dict[str, NDArray[np.int64]]:
        return {key: np.zeros(n, dtype=np.int64) for key in ("right", "left", "floor", "claw_claw", "claw_floor", "between")}

    # ------------------------------------------------------------------ named quantities, (n, ...) each
    def cube_pos(self, sim: SimArrays) -> Array:
        return sim.geom_xpos[:, self.cube_geom]

    def cube_height(self, sim: SimArrays) -> Array:
        """Height of the cube's bottom face above the floor, from the cube geom (not its body frame)."""
        return sim.geom_xpos[:, self.cube_geom, 2] - CUBE_HALF_SIZE - FLOOR_Z

    def cube_axes(self, sim: SimArrays) -> Array:
        """The cube's x and z axes in the world frame (the first and last columns of its rotation matrix)."""
        rotation = sim.geom_xmat[:, self.cube_geom].reshape(-1, 3, 3)
        return np.concatenate([rotation[:, :, 0], rotation[:, :, 2]], axis=1)

    def claw_torque(self, sim: SimArrays) -> Array:
        """The claw servo's torque on ``claw_right`` (N m, positive closes)."""
        return sim.actuator_force[:, self.claw_actuator]

    def forearm_frame(self, sim: SimArrays) -> Array:
        """The forearm's rotation, ``(n, 3, 3)``: columns x along the forearm, z the claw's hinge axis."""
        return sim.xmat[:, self.forearm_body].reshape(-1, 3, 3)

    def grip_velocity(self, sim: SimArrays) -> Array:
        """Linear velocity of the grip site in the world frame (m/s): its Jacobian times the joint velocities, as
        Gymnasium Robotics' Fetch observes its grip (``qvel`` is the step's last; MuJoCo's own ``cvel`` lags it by one
        physics step)."""
        site = self.grip_site
        jacobian, _ = point_jacobians(sim, int(self.model.site_bodyid[site]), sim.site_xpos[:, site])
        return (jacobian @ sim.qvel[..., None])[..., 0]

    def claw_cube_contacts(self, sim: SimArrays) -> dict[str, NDArray[np.int64]]:
        """Number of capsules of each claw half touching the cube."""
        touching = self.contact_counts(sim)[:, :8] > 0
        return {"right": touching[:, :4].sum(axis=1), "left": touching[:, 4:].sum(axis=1)}

    def cube_off_claw_segment(self, sim: SimArrays) -> tuple[Array, Array]:
        """Where the cube's centre projects on the segment from the right to the left claw site (0 at the right site,
        1 at the left) and its offset from that projection (world frame, m)."""
        right, left = sim.site_xpos[:, self.claw_sites[0]], sim.site_xpos[:, self.claw_sites[1]]
        cube = self.cube_pos(sim)
        span = left - right
        t = np.einsum("ni,ni->n", cube - right, span) / np.einsum("ni,ni->n", span, span)
        return t, cube - right - t[:, None] * span

    def cube_off_claw_segment_in_forearm_frame(self, sim: SimArrays) -> tuple[Array, Array]:
        """``cube_off_claw_segment`` with the offset in the forearm's frame (x along the forearm, z the hinge axis)."""
        t, offset_world = self.cube_off_claw_segment(sim)
        return t, np.einsum("nji,nj->ni", self.forearm_frame(sim), offset_world)

    def cube_between_claws(self, sim: SimArrays) -> Flags:
        """Whether the cube's centre lies between the claw halves: its projection on the segment from the right to
        the left claw site falls inside the segment, and its offset from the segment is small (``grasp_test``:
        ``"between"`` at most 2 cm in all, a cube held by the top or bottom capsules only sits ~1 cm off the sites'
        plane and one pressed from above >= 3 cm; ``"per_axis"`` at most 2.5 cm along the forearm and along the
        claw's hinge axis, each)."""
        if self.options.grasp_test == "between":
            t, offset = self.cube_off_claw_segment(sim)
            return (t > 0.0) & (t < 1.0) & (norm(offset) < BETWEEN_TOLERANCE)
        t, offset = self.cube_off_claw_segment_in_forearm_frame(sim)
        close = (np.abs(offset[:, 0]) <= PER_AXIS_TOLERANCE) & (np.abs(offset[:, 2]) <= PER_AXIS_TOLERANCE)
        return (t > 0.0) & (t < 1.0) & close

    def contact_summary(self, sim: SimArrays) -> dict[str, NDArray[np.int64]]:
        """All contact counts the reward, observation and success need, from one read of the contact counts."""
        counts = self.contact_counts(sim)
        touching = counts[:, :8] > 0
        summary = {"right": touching[:, :4].sum(axis=1), "left": touching[:, 4:].sum(axis=1)}
        summary["floor"] = counts[:, _BOTTOM_FLOOR_ROWS].sum(axis=1).astype(np.int64)
        summary["claw_claw"] = np.minimum(counts[:, 16:32].sum(axis=1), 2).astype(np.int64)
        summary["claw_floor"] = (counts[:, 8:16] > 0).any(axis=1).astype(np.int64)
        if self.options.grasp_test == "touch":
            summary["between"] = np.zeros(sim.n, dtype=np.int64)
        else:
            summary["between"] = self.cube_between_claws(sim).astype(np.int64)
        return summary

    def is_grasped(self, contacts: dict[str, NDArray[np.int64]]) -> Flags:
        touched = (contacts["right"] > 0) & (contacts["left"] > 0)
        return touched if self.options.grasp_test == "touch" else touched & (contacts["between"] > 0)

    def reach_distance(self, sim: SimArrays) -> Array:
        """The distance ``reward_reach`` shrinks (m): grip site to cube centre, or the thesis' claw terms
        ``|right - cube| + |left - cube| - |left - right|``, zero exactly when the cube's centre lies on the segment
        between the claw sites: they pull the claw to straddle the cube, and to open for it, rather than towards a
        point that a closed claw would press onto the cube."""
        cube = self.cube_pos(sim)
        if self.options.reach_distance == "grip":
            return norm(sim.site_xpos[:, self.grip_site] - cube)
        right, left = sim.site_xpos[:, self.claw_sites[0]], sim.site_xpos[:, self.claw_sites[1]]
        return norm(right - cube) + norm(left - cube) - norm(left - right)

    def success(self, sim: SimArrays) -> Flags:
        return (self.cube_height(sim) >= self.options.lift_height) & self.is_grasped(self.contacts)

    # ------------------------------------------------------------------ stepping
    def controls(self, sim: SimArrays, action: Array, ids: NDArray[np.int64] | None = None) -> Array:
        options = self.options
        if options.control == "joint_torque":
            return action
        grip_velocity = float(options.max_grip_speed) * action[:, :3]
        arm = grip_down_commands(sim, grip_velocity, grip_priority=options.ik_mode == "priority")
        claw = action[:, 3]
        if options.claw_rate is not None:  # the action moves the servo's target angle; ctrl aims the servo there
            rows = slice(None) if ids is None else ids
            target = np.clip(self.claw_target[rows] + options.claw_rate * claw, *CLAW_TARGET_RANGE)
            self.claw_target[rows] = target
            claw = (target - CLAW_OPEN_TARGET) / CLAW_SERVO_SLOPE
        return np.clip(np.concatenate([arm, claw[:, None]], axis=1), self.ctrl_low, self.ctrl_high)

    # ------------------------------------------------------------------ reward
    def reward(self, sim: SimArrays, action: Array) -> tuple[Array, dict[str, Any]]:
        options, contacts = self.options, self.contacts
        height = self.cube_height(sim)
        ctrl = -self.reward_control_weight * np.square(action).sum(axis=1)
        cube = self.cube_pos(sim)
        grasped = self.is_grasped(contacts)
        n_cube = contacts["right"] + contacts["left"]
        info: dict[str, Any] = {"cube_height": height, "claw_cube_contacts": n_cube}
        if options.reward_mode == "thesis":
            right, left = sim.site_xpos[:, self.claw_sites[0]], sim.site_xpos[:, self.claw_sites[1]]
            lifted = (height >= options.lift_height) & (n_cube > 3)
            self.lift_bonus_paid = lifted
            terms = {
                "reward_dist": -norm(sim.site_xpos[:, self.palm_site] - cube)
                - norm(right - cube)
                - norm(left - cube)
                + norm(left - right),
                "reward_ctrl": ctrl,
                "reward_contact": n_cube.astype(np.float64),
                "reward_floor": -contacts["floor"].astype(np.float64),
                "reward_claw_collision": np.where(n_cube <= 4, -contacts["claw_claw"].astype(np.float64), 0.0),
                "reward_lift": np.where(lifted, 1000.0 + 1000.0 * height, 0.0),
            }
            info.update(terms)
            return sum(terms.values()), info
        solved = grasped & (height >= options.lift_height)
        terms = {
            "reward_reach": options.reward_reach_weight * (1.0 - np.tanh(10.0 * self.reach_distance(sim))),
            "reward_grasp": options.reward_grasp_weight * n_cube / 8.0,
            "reward_lift": options.reward_lift_weight
            * grasped
            * np.minimum(np.maximum(height, 0.0) / options.lift_height, 1.0),
            "reward_hold": options.reward_hold_weight * solved.astype(np.float64),
            "reward_ctrl": ctrl,
        }
        # the floor and squeeze terms are added one after the other, in this order, to the sum of the others
        if self.reward_squeeze_weight:
            squeeze = np.minimum(np.maximum(self.claw_torque(sim), 0.0) / float(options.squeeze_torque), 1.0)
        else:
            squeeze = np.zeros(sim.n)
        extra = {
            "reward_floor": -options.reward_floor_weight * contacts["claw_floor"],
            "reward_squeeze": self.reward_squeeze_weight * grasped * squeeze,
        }
        reward = sum(terms.values())
        for value in extra.values():
            reward = reward + value
        info.update(terms)
        info.update(extra)
        return reward, info

    def terminal(self, sim: SimArrays) -> Flags:
        if not self.terminate_on_success:
            return np.zeros(sim.n, dtype=bool)
        # thesis mode: the episode ends with the lift bonus (height and more than 3 capsules on the cube)
        return self.lift_bonus_paid.copy() if self.options.reward_mode == "thesis" else self.success(sim)

    # ------------------------------------------------------------------ observation and reset
    def joint_space_observation(self, sim: SimArrays) -> Array:
        qpos, qvel = sim.qpos, sim.qvel
        angles = qpos[:, self.arm_qpos]
        cube = self.cube_pos(sim)
        # the observation is computed first after every physics change (step and reset): read contacts once here
        self.contacts = contacts = self.contact_summary(sim)
        parts = [
            np.cos(angles),
            np.sin(angles),
            qpos[:, self.claw_qpos, None],
            qvel[:, self.arm_qvel],
            qvel[:, self.claw_qvel, None],
            cube,
            sim.site_xpos[:, self.palm_site] - cube,
            sim.site_xpos[:, self.claw_sites[0]] - cube,
            sim.site_xpos[:, self.claw_sites[1]] - cube,
            (contacts["right"] > 0)[:, None].astype(np.float64),
            (contacts["left"] > 0)[:, None].astype(np.float64),
        ]
        if self.observe_claw_torque:
            parts.append(self.claw_torque(sim)[:, None])
        return np.concatenate(parts, axis=1)

    def observe(self, sim: SimArrays) -> Array:
        if self.options.observation == "joint":
            observation = self.joint_space_observation(sim)
        else:
            forearm = self.forearm_frame(sim)
            kept = TASK_KEPT_JOINT_ROWS if self.observe_claw_torque else TASK_KEPT_JOINT_ROWS[:-1]
            parts = [self.grip_velocity(sim), forearm[:, :, 0], forearm[:, :, 2], self.joint_space_observation(sim)[:, kept]]
            observation = np.concatenate(parts, axis=1)
        if self.options.cube_rotation is not None:
            observation = np.concatenate([observation, self.cube_axes(sim)], axis=1)
        return observation

    def sample_start(self, rng: np.random.Generator) -> tuple[Array, Array, None]:
        noise = self.options.reset_noise_scale
        qpos = self.init_qpos.copy()
        qpos[self.arm_qpos] += rng.uniform(-noise, noise, size=len(ARM_JOINTS))
        claw = rng.uniform(-noise, noise)
        qpos[self.claw_qpos] = claw
        qpos[self.claw_left_qpos] = -claw
        radius = 0.1 * np.sqrt(rng.uniform())
        angle = rng.uniform(-np.pi, np.pi)
        cube = np.array([radius * np.cos(angle), radius * np.sin(angle), FLOOR_Z + CUBE_HALF_SIZE])
        qpos[self.cube_qpos] = cube - self.cube_body_pos
        qvel = self.init_qvel + rng.uniform(-0.005, 0.005, size=self.model.nv)
        qvel[self.cube_dofs] = 0.0
        return qpos, qvel, None

    def started(self, sim: SimArrays, ids: NDArray[np.int64]) -> None:
        self.lift_bonus_paid[ids] = False
        self.claw_target[ids] = sim.qpos[ids, self.claw_qpos]


class Grasper3DEnv(ArmEnv):
    r"""
    ## Description
    Reacher3D's arm (hanging from the ceiling, shoulder at the origin, floor at z = -0.2 m) plus a forearm roll hinge
    and a two-part claw (thesis 5.2.3): each half is a hinge about the forearm's z axis (range ±40°; with
    `claw="servo"` closing stops at 2°: `claw_right` in [-40°, 2°], `claw_left` in [-2°, 40°]) carrying four capsules
    (inner/outer, top/bottom, radius 6 mm); an equality constraint keeps the left half at minus the right half. The
    claw must grasp a 24 mm cube that rests on the floor and lift it at least 0.05 m.

    `gymnasium.make("Grasper3D-v7")` is the recommended version: the defaults below. `Grasper3D-v0` is the thesis'
    task; `-v1` to `-v6` are the design steps that made it learnable (Version History), each a preset of the options.

    ## Action Space
    `control="grip_velocity"` (default): `Box(-1, 1, (4,), float32)`: the grip site's velocity $v = 0.4 a_{0:3}$ m/s
    (`max_grip_speed`) in world x, y, z, then the claw command $c$. Each step the environment solves the inverse
    kinematics for that velocity on MuJoCo's Jacobians with the claw's closing axis kept horizontal and the forearm
    turned to point down, and drives the five arm motors with a gravity-compensated joint-velocity servo
    (`grasp_envs.control.grip_down_commands`). `ik_mode="priority"` (default): task-priority inverse kinematics, the
    forearm turns down only in the joint direction the grip and the closing axis leave free; `"weighted"`: one damped
    least-squares stack of five rows, where the grip stalls wherever the arm cannot move it with the forearm down.
    The claw's yaw is left free.

    `control="joint_torque"`: `Box(-0.5, 0.5, (6,), float32)` with `claw="torque"`, the thesis' action: torques on
    `shoulder_y`, `shoulder_z`, `elbow_y`, `elbow_z`, `forearm_roll` (gear 200) and on the claw (gear 100; positive
    closes); with `claw="servo"`,
    `Box([-0.5 -0.5 -0.5 -0.5 -0.5 -1. ], [0.5 0.5 0.5 0.5 0.5 1. ], (6,), float32)`: the last entry is the claw
    command $c$.

    The claw command $c$ with `claw="servo"` (default): a position servo on `claw_right` aims at the angle
    $0.4 c - 0.3$ rad (kp 10 N m/rad, force limited to 5 N m), so $c = 0$ holds the claw half open (33 mm between the
    tips, the cube is 24 mm), $c = -1$ opens it fully (-40°) and $c = 1$ closes it. With `claw_rate` $r$, each step's
    claw action moves the servo's target by $r c$ rad instead (within [-0.7, 0.1], starting at the claw's angle after
    the reset; the target is not observed). With `claw="torque"` and `control="grip_velocity"`, $c$ is the claw
    motor's command, clipped to [-0.5, 0.5] (gear 100: at most 50 N m).

    ## Observation Space
    `Box(-inf, inf, (N,), float64)`: N = 25 with `observation="task"` (default) or 31 with `observation="joint"`,
    plus 1 with `observe_claw_torque` and 6 with `cube_rotation` (32 for `Grasper3D-v7`). `observation="task"`, the
    rows of this table:

    | Num | Observation | Unit | When |
    |-----|-------------|------|------|
    | 0 | grip site velocity x | m/s | always |
    | 1 | grip site velocity y | m/s | always |
    | 2 | grip site velocity z | m/s | always |
    | 3 | forearm axis x (unit vector from the elbow along the forearm; -z when it points down) | unitless | always |
    | 4 | forearm axis y | unitless | always |
    | 5 | forearm axis z | unitless | always |
    | 6 | claw hinge axis x (unit vector; the halves close about it) | unitless | always |
    | 7 | claw hinge axis y | unitless | always |
    | 8 | claw hinge axis z | unitless | always |
    | 9 | claw opening angle `claw_right` (negative is open) | rad | always |
    | 10 | angular velocity of `claw_right` | rad/s | always |
    | 11 | cube x | m | always |
    | 12 | cube y | m | always |
    | 13 | cube z | m | always |
    | 14 | palm x - cube x | m | always |
    | 15 | palm y - cube y | m | always |
    | 16 | palm z - cube z | m | always |
    | 17 | right claw x - cube x | m | always |
    | 18 | right claw y - cube y | m | always |
    | 19 | right claw z - cube z | m | always |
    | 20 | left claw x - cube x | m | always |
    | 21 | left claw y - cube y | m | always |
    | 22 | left claw z - cube z | m | always |
    | 23 | right claw half touches the cube | unitless | always |
    | 24 | left claw half touches the cube | unitless | always |
    | 25 | claw servo torque on `claw_right` (positive closes) | N m | `observe_claw_torque` |
    | 26 | cube x axis x (unit vector along the cube's edge that starts along world x) | unitless | `cube_rotation` |
    | 27 | cube x axis y | unitless | `cube_rotation` |
    | 28 | cube x axis z | unitless | `cube_rotation` |
    | 29 | cube z axis x (along the edge that starts vertical; (0, 0, 1) unless `"free"`) | unitless | `cube_rotation` |
    | 30 | cube z axis y | unitless | `cube_rotation` |
    | 31 | cube z axis z | unitless | `cube_rotation` |

    `observation="joint"`: the arm's joint angles and velocities instead of the grip velocity and the axes:

    | Num | Observation | Unit | When |
    |-----|-------------|------|------|
    | 0 | cos of `shoulder_y` | unitless | always |
    | 1 | cos of `shoulder_z` | unitless | always |
    | 2 | cos of `elbow_y` | unitless | always |
    | 3 | cos of `elbow_z` | unitless | always |
    | 4 | cos of `forearm_roll` | unitless | always |
    | 5 | sin of `shoulder_y` | unitless | always |
    | 6 | sin of `shoulder_z` | unitless | always |
    | 7 | sin of `elbow_y` | unitless | always |
    | 8 | sin of `elbow_z` | unitless | always |
    | 9 | sin of `forearm_roll` | unitless | always |
    | 10 | claw opening angle `claw_right` (negative is open) | rad | always |
    | 11 | angular velocity of `shoulder_y` | rad/s | always |
    | 12 | angular velocity of `shoulder_z` | rad/s | always |
    | 13 | angular velocity of `elbow_y` | rad/s | always |
    | 14 | angular velocity of `elbow_z` | rad/s | always |
    | 15 | angular velocity of `forearm_roll` | rad/s | always |
    | 16 | angular velocity of `claw_right` | rad/s | always |
    | 17 | cube x | m | always |
    | 18 | cube y | m | always |
    | 19 | cube z | m | always |
    | 20 | palm x - cube x | m | always |
    | 21 | palm y - cube y | m | always |
    | 22 | palm z - cube z | m | always |
    | 23 | right claw x - cube x | m | always |
    | 24 | right claw y - cube y | m | always |
    | 25 | right claw z - cube z | m | always |
    | 26 | left claw x - cube x | m | always |
    | 27 | left claw y - cube y | m | always |
    | 28 | left claw z - cube z | m | always |
    | 29 | right claw half touches the cube | unitless | always |
    | 30 | left claw half touches the cube | unitless | always |
    | 31 | claw servo torque on `claw_right` (positive closes) | N m | `observe_claw_torque` |
    | 32 | cube x axis x | unitless | `cube_rotation` |
    | 33 | cube x axis y | unitless | `cube_rotation` |
    | 34 | cube x axis z | unitless | `cube_rotation` |
    | 35 | cube z axis x | unitless | `cube_rotation` |
    | 36 | cube z axis y | unitless | `cube_rotation` |
    | 37 | cube z axis z | unitless | `cube_rotation` |

    `claw="torque"` is the thesis' 50 N m claw motor (`grasper3d.xml`). With `cube_rotation`, the cube's orientation
    is observed. A row whose option is off (`observe_claw_torque=False`, or `None` with `claw="torque"`;
    `cube_rotation=None`) is left out; the rows after it move up. The task-space rows are those of Gymnasium
    Robotics' Fetch, which observes no joints: two arm configurations that hold the claw in the same place look the
    same.

    ## Rewards
    Computed after the physics step; every term is in `info` as `reward_<term>`.

    `reward_mode="staged"` (default): reach, then grasp, then lift, then hold; no term can be farmed: holding the
    cube up earns the most on *every* step, so the best return needs a grasp, a lift and a hold.

    - `reward_reach` $= w_{reach} (1 - \tanh(10 e))$, `reward_reach_weight` (1). `reach_distance="claw_segment"`
      (default): the thesis' claw terms $e = \lVert p_{right} - p_{cube} \rVert + \lVert p_{left} - p_{cube} \rVert
      - \lVert p_{left} - p_{right} \rVert \ge 0$, zero exactly when the cube's centre lies on the segment between
      the claw sites (straddled); `"grip"`: $e = \lVert p_{grip} - p_{cube} \rVert$
    - `reward_grasp` $= w_{grasp} \cdot n / 8$ with $n$ the claw capsules touching the cube (0..8),
      `reward_grasp_weight` (4): the thesis' contact shaping, bounded and smaller than the lift terms
    - `reward_lift` $= w_{lift} \min(\max(h, 0) / h_{lift}, 1)$ while grasped, `reward_lift_weight` (4); $h$ is the
      height of the cube's bottom face above the floor, measured from its geom, $h_{lift}$ = `lift_height` (0.05 m)
    - `reward_hold` $= w_{hold}$ while the task is solved (see Episode End), `reward_hold_weight` (4)
    - `reward_ctrl` $= -w_{ctrl} \lVert a \rVert^2$, `reward_control_weight` (0.1 in this mode)
    - `reward_floor` $= -w_{floor}$ while a claw capsule touches the floor, `reward_floor_weight` (1): an open claw
      pressed onto the floor straddles the cube but cannot close (its tips swing towards the floor)
    - `reward_squeeze` $= w_{squeeze} \min(\max(\tau, 0) / \tau_{squeeze}, 1)$ while grasped, with $\tau$ the claw
      servo's torque (N m) and $\tau_{squeeze}$ = `squeeze_torque` (0.5 N m), `reward_squeeze_weight` (2 with
      `claw="servo"`, 0 with `"torque"`): a firm grip, one that the policy's own exploration noise on the claw
      command does not open when the arm rises

    `reward_mode="thesis"`: the thesis' reward, with its bugs fixed (after the physics step, contacts by geom name,
    height from the cube geom):

    - `reward_dist` $= -\lVert p_{palm} - p_{cube} \rVert - \lVert p_{right} - p_{cube} \rVert
      - \lVert p_{left} - p_{cube} \rVert + \lVert p_{left} - p_{right} \rVert$
    - `reward_ctrl` $= -w_{ctrl} \lVert a \rVert^2$ (1 in this mode)
    - `reward_contact` = number of claw capsules touching the cube (0..8)
    - `reward_floor` = minus the number of contacts between the four bottom claw capsules and the floor (a capsule
      lying on the floor makes two, so it can exceed 4)
    - `reward_claw_collision` = minus the number of contacts between the claw halves, counted up to 2, only while at
      most 4 capsules touch the cube (always 0 with `claw="servo"`, whose halves do not collide)
    - `reward_lift` $= 1000 + 1000 h$ on every step with $h \ge$ `lift_height` (0.05 m) and more than 3 capsules on
      the cube; with `terminate_on_success` (the default in this mode) the episode ends there

    `info` also holds `cube_height` (m), `claw_cube_contacts` (capsules touching the cube, 0..8), `is_success` and
    `unstable`.

    ## Starting State
    Arm in `start_pose`: `"ready"` (default) the upper arm 30° up and the forearm pointing down, the grip 8.7 cm out
    along +x and 7 cm above the plane of the cube's top face; `"stretched"` horizontal along +x (the thesis'). Each of
    the five arm joint angles gets noise $\mathcal{U}(-s, s)$ with $s$ = `reset_noise_scale` (0.1 rad). The claw angle
    `claw_right` is drawn from $\mathcal{U}(-s, s)$ about 0 (closed: the tips 4 mm apart), `claw_left` set to minus it. With
    `claw="torque"` every draw lies within the ±40° range. With `claw="servo"` the model limits `claw_right` to
    [-40°, 2°], so a draw above 2° (0.035 rad: about a third of the resets at $s$ = 0.1) starts past the limit, and
    the first observation shows that angle; from the first step on MuJoCo's soft limit constraint pushes the claw
    back: with the claw command 0 (the servo aiming at -0.3 rad) it is inside the limit after one or two steps, with
    the full closing command 1 the limit alone brings it to within 0.2° of 2° in about five steps (measured on the
    first 40 seeded resets of `Grasper3D-v7`, 15 past the limit). Velocities $\mathcal{U}(-0.005, 0.005)$ on every
    degree of freedom (each claw half drawn on its own) but the cube's three slides, which start at rest; with
    `cube_rotation` the cube's turning joint gets the same noise. The cube rests on the floor, its edges along the
    world axes, uniform in the disc of radius 0.1 m under the shoulder.

    ## Episode End
    Success (`info["is_success"]`): $h \ge$ `lift_height` (0.05 m) while grasped. Grasped, by `grasp_test`:
    `"per_axis"` (default) both claw halves touch the cube and its centre projects inside the segment between the
    claw sites and lies at most 2.5 cm from it along the forearm and along the hinge axis, each; `"between"` the same
    within 2 cm in all; `"touch"` both halves touch the cube (which pressing it from above also gives).
    Termination: when `terminate_on_success` (default: only in `reward_mode="thesis"`), in staged mode on success,
    in thesis mode when the lift bonus is paid (height reached with more than 3 capsules on the cube, whichever
    `grasp_test`); always on `info["unstable"]`. Truncation after 100 steps (`max_episode_steps` of every registered
    id, through Gymnasium's `TimeLimit`; the class itself never truncates).

    ## Arguments
    Keywords only: the options (`Grasper3DOptions`, checked when the env is made: a bad value raises `ValueError`
    naming it, an unknown keyword `TypeError`) and Gymnasium's rendering arguments.

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `xml_file` | `None` | MuJoCo model; `None`: the model of `claw` |
    | `frame_skip` | `2` | physics steps of 0.01 s per action (an int >= 1) |
    | `default_camera_config` | oblique view | camera of `render()` |
    | `claw` | `"servo"` | `"servo"`: a force-limited position servo (`grasper3d_v1.xml`, Version History v1); `"torque"` |
    | `control` | `"grip_velocity"` | `"grip_velocity"` or `"joint_torque"` (Action Space) |
    | `ik_mode` | `"priority"` | `"priority"` or `"weighted"` inverse kinematics (`grip_velocity` only) |
    | `max_grip_speed` | `0.4` | grip-site speed at an action of 1 (m/s; `grip_velocity` only) |
    | `claw_rate` | `None` | `None`: the claw action is the servo command; $r$: it moves the servo's target (Action Space) |
    | `observation` | `"task"` | `"task"` or `"joint"` (Observation Space) |
    | `observe_claw_torque` | `None` | observe the claw servo's torque; `None`: with `claw="servo"` (needs it when `True`) |
    | `cube_rotation` | `"yaw"` | `None`: only slides; `"yaw"`: also turns about the vertical; `"free"`: about any axis |
    | `start_pose` | `"ready"` | the arm's pose before the reset noise: `"ready"` or `"stretched"` (Starting State) |
    | `reward_mode` | `"staged"` | `"staged"` or `"thesis"` |
    | `reach_distance` | `"claw_segment"` | what `reward_reach` shrinks: `"claw_segment"` or `"grip"` |
    | `grasp_test` | `"per_axis"` | `"per_axis"`, `"between"` or `"touch"` (Episode End) |
    | `reward_reach_weight` | `1.0` | weight of `reward_reach` (staged) |
    | `reward_grasp_weight` | `4.0` | weight of `reward_grasp` (staged) |
    | `reward_lift_weight` | `4.0` | weight of `reward_lift` (staged) |
    | `reward_hold_weight` | `4.0` | weight of `reward_hold` (staged) |
    | `reward_floor_weight` | `1.0` | weight of `reward_floor` (staged) |
    | `reward_squeeze_weight` | `None` | weight of `reward_squeeze` (staged; not 0 needs the servo); `None`: 2 (servo) or 0 |
    | `squeeze_torque` | `0.5` | claw servo torque at which `reward_squeeze` saturates (N m, > 0) |
    | `reward_control_weight` | `None` | weight of `reward_ctrl`; `None`: 0.1 (staged) or 1 (thesis) |
    | `terminate_on_success` | `None` | end the episode on success (thesis: on the lift bonus); `None`: in thesis mode only |
    | `reset_noise_scale` | `0.1` | half-width of the arm's and the claw's initial joint-angle noise (rad, >= 0) |
    | `lift_height` | `0.05` | height of the cube's bottom above the floor that counts as lifted (m, > 0) |
    | `**kwargs` | | passed on to Gymnasium's `MujocoEnv`: `render_mode`, `width`, `height`, `camera_id`, ... |

    Training aids are not options of the task: starting a share of the training episodes along the scripted grasp
    is the wrapper `grasp_envs.wrappers.ScriptedStarts`, applied to training envs only.

    ## Version History
    Each id is a preset of the options above (`grasp_envs.registration.PRESETS`); docs/changelog.md tells what each
    step measured.

    * v7: v6 with `start_pose="ready"`: the arm starts above the cubes. The recommended version.
    * v6: v5 with `cube_rotation="yaw"` (the thesis' cube only slides; the claw, turning while it holds it, levered
      it out).
    * v5: v4 with `observation="task"`.
    * v4: v3 with `ik_mode="priority"` and `grasp_test="per_axis"`.
    * v3: v2 with `reward_squeeze_weight=2` and `observe_claw_torque=True`.
    * v2: v1 with `control="grip_velocity"` (`ik_mode="weighted"`).
    * v1: `claw="servo"` (a force-limited position servo whose zero command holds the claw half open; the halves no
      longer collide at their common hinge and closing stops at 2°; lighter claw joints (armature 0.02, damping 0.5);
      forearm roll limited to ±90°; grip site 1 cm further out, at 0.155 m along the forearm),
      `reach_distance="claw_segment"`, `grasp_test="between"`, `reward_floor_weight=1`, grasp, lift and hold weights 4.
    * v0: the thesis' task, with `claw="torque"`, `control="joint_torque"`, `observation="joint"`, no claw torque
      observed, `cube_rotation=None`, `start_pose="stretched"`, `reach_distance="grip"`, `grasp_test="touch"`, grasp
      weight 1, lift and hold weights 2, no floor or squeeze term. Differs from the thesis: staged default reward (the
      thesis' per-step contact reward can be farmed: a TRPO agent that had learnt to lift went back to touching the
      cube for whole episodes); cube height from its geom; contacts by geom name; reward after the physics step;
      cos/sin angles, claw angle, cube-relative claw positions and claw-cube contacts observed; cube in a disc of
      radius 0.1 m.
    """

    options_class = Grasper3DOptions
    task_class = Grasper3DTask
    default_camera = DEFAULT_CAMERA_CONFIG_3D
    task: Grasper3DTask

    @property
    def control(self) -> str:
        """The ``control`` option: what an action commands."""
        return self.task.options.control

    @property
    def max_grip_speed(self) -> float:
        """The ``max_grip_speed`` option (m/s of the grip site at an action of 1)."""
        return float(self.task.options.max_grip_speed)

    # ------------------------------------------------------------------ the task's quantities for this simulation
    def cube_pos(self) -> NDArray[np.float64]:
        return self.data.geom("cube").xpos

    def cube_height(self) -> float:
        """Height of the cube's bottom face above the floor, from the cube geom (not its body frame)."""
        return float(self.task.cube_height(self.sim)[0])

    def claw_cube_contacts(self) -> dict[str, int]:
        """Number of capsules of each claw half touching the cube."""
        return {side: int(count[0]) for side, count in self.task.claw_cube_contacts(self.sim).items()}

    def cube_between_claws(self) -> bool:
        """Whether the cube's centre lies between the claw halves (``Grasper3DTask.cube_between_claws``)."""
        return bool(self.task.cube_between_claws(self.sim)[0])

    def cube_off_claw_segment_in_forearm_frame(self) -> tuple[float, NDArray[np.float64]]:
        t, offset = self.task.cube_off_claw_segment_in_forearm_frame(self.sim)
        return float(t[0]), offset[0]

    def is_grasped(self) -> bool:
        """Whether the claw holds the cube (``grasp_test``), as of the last observation."""
        return bool(self.task.is_grasped(self.task.contacts)[0])


def add_cube_rotation(spec: mujoco.MjSpec, cube_rotation: str = "yaw") -> None:
    """Let the model's cube turn (``CUBE_ROTATIONS``): a joint after its three slide joints (the cube is the last
    body, so every other coordinate keeps its index and the cube's orientation comes last in ``qpos``)."""
    spec.body("cube").add_joint(
        name=CUBE_ROTATION_JOINT, damping=CUBE_ROTATION_DAMPING, armature=0.0, **CUBE_ROTATIONS[cube_rotation]
    )


__all__ = ["Grasper3DEnv", "Grasper3DOptions", "Grasper3DTask", "add_cube_rotation", "asset_path"]
