"""Grasper3D-v0: grasp a 24 mm cube and lift it (thesis section 5.2.3)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import utils
from numpy.typing import NDArray

from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D, ArmEnv

ARM_JOINTS = ("shoulder_y", "shoulder_z", "elbow_y", "elbow_z", "forearm_roll")
CLAW_SIDES = ("right", "left")
CLAW_PARTS = ("outer_top", "inner_top", "outer_bottom", "inner_bottom")
FLOOR_Z = -0.2
CUBE_HALF_SIZE = 0.012
REWARD_MODES = ("staged", "thesis")


class Grasper3DEnv(ArmEnv):
    r"""
    ## Description
    Reacher3D's arm plus a forearm roll hinge and a two-part claw (thesis 5.2.3): each half is a hinge about
    the forearm's z axis (range ±40°) carrying four capsules (inner/outer, top/bottom, radius 6 mm); an
    equality constraint keeps the left half at minus the right half, so 7 joints are driven by 6 motors.
    The claw must grasp a 24 mm cube (free to slide in x, y, z, not to rotate) and lift it at least
    0.05 m above the floor.

    ## Action Space
    `Box(-0.5, 0.5, (6,), float32)`: torques on `shoulder_y`, `shoulder_z`, `elbow_y`, `elbow_z`,
    `forearm_roll` (gear 200) and on the claw (`claw_right`, gear 100; positive closes).

    ## Observation Space
    `Box(-inf, inf, (31,), float64)`:

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 0 | cos of `shoulder_y` | unitless |
    | 1 | cos of `shoulder_z` | unitless |
    | 2 | cos of `elbow_y` | unitless |
    | 3 | cos of `elbow_z` | unitless |
    | 4 | cos of `forearm_roll` | unitless |
    | 5 | sin of `shoulder_y` | unitless |
    | 6 | sin of `shoulder_z` | unitless |
    | 7 | sin of `elbow_y` | unitless |
    | 8 | sin of `elbow_z` | unitless |
    | 9 | sin of `forearm_roll` | unitless |
    | 10 | claw opening angle `claw_right` (negative is open) | rad |
    | 11 | angular velocity of `shoulder_y` | rad/s |
    | 12 | angular velocity of `shoulder_z` | rad/s |
    | 13 | angular velocity of `elbow_y` | rad/s |
    | 14 | angular velocity of `elbow_z` | rad/s |
    | 15 | angular velocity of `forearm_roll` | rad/s |
    | 16 | angular velocity of `claw_right` | rad/s |
    | 17 | cube x | m |
    | 18 | cube y | m |
    | 19 | cube z | m |
    | 20 | palm x - cube x | m |
    | 21 | palm y - cube y | m |
    | 22 | palm z - cube z | m |
    | 23 | right claw x - cube x | m |
    | 24 | right claw y - cube y | m |
    | 25 | right claw z - cube z | m |
    | 26 | left claw x - cube x | m |
    | 27 | left claw y - cube y | m |
    | 28 | left claw z - cube z | m |
    | 29 | right claw half touches the cube | unitless |
    | 30 | left claw half touches the cube | unitless |

    ## Rewards
    Computed after the physics step; every term is in `info` as `reward_<term>`.

    `reward_mode="staged"` (default): reach, then grasp, then lift, then hold; no term can be farmed:
    holding the cube up earns the most on *every* step, so the best return needs a grasp, a lift and a hold.

    - `reward_reach` $= w_{reach} (1 - \tanh(10 \lVert p_{grip} - p_{cube} \rVert))$, `reward_reach_weight` (1)
    - `reward_grasp` $= w_{grasp} \cdot n / 8$ with $n$ the claw capsules touching the cube (0..8),
      `reward_grasp_weight` (1): the thesis' contact shaping, bounded and smaller than the lift terms
    - `reward_lift` $= w_{lift} \min(h / 0.05, 1)$ while both halves touch the cube, `reward_lift_weight` (2);
      $h$ is the height of the cube's bottom face above the floor, measured from its geom
    - `reward_hold` $= w_{hold}$ while the task is solved (see below), `reward_hold_weight` (2)
    - `reward_ctrl` $= -w_{ctrl} \lVert a \rVert^2$, `reward_control_weight` (default 0.1 here)

    `reward_mode="thesis"`: the thesis' reward, with its bugs fixed (after the physics step, contacts by
    geom name, height from the cube geom):

    - `reward_dist` $= -\lVert p_{palm} - p_{cube} \rVert - \lVert p_{right} - p_{cube} \rVert
      - \lVert p_{left} - p_{cube} \rVert + \lVert p_{left} - p_{right} \rVert$
    - `reward_ctrl` $= -w_{ctrl} \lVert a \rVert^2$ (default 1 here)
    - `reward_contact` = number of claw capsules touching the cube (0..8)
    - `reward_floor` = minus the number of bottom claw capsules touching the floor (0..4)
    - `reward_claw_collision` = minus the number of claw-claw contacts (at most 2), only while at most 4
      capsules touch the cube
    - `reward_lift` $= 1000 + 1000 h$ once $h \ge 0.05$ m with more than 3 capsules on the cube; the episode ends

    ## Starting State
    Arm horizontal along +x, claw closed, joint noise $\mathcal{U}(-s, s)$ with $s$ = `reset_noise_scale`
    (0.1 rad); the cube rests on the floor, uniform in the disc of radius 0.1 m under the shoulder.

    ## Episode End
    Success (`info["is_success"]`): $h \ge 0.05$ m while both claw halves touch the cube.
    Termination: when `terminate_on_success` (default: only in `reward_mode="thesis"`), on success, or in
    thesis mode when the lift bonus is paid (height reached with more than 3 capsules on the cube); on
    `info["unstable"]`. Truncation after 100 steps (`max_episode_steps`).

    ## Arguments
    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `xml_file` | `"grasper3d.xml"` | MuJoCo model |
    | `frame_skip` | `2` | physics steps of 0.01 s per action |
    | `default_camera_config` | oblique view | camera of `render()` |
    | `reward_mode` | `"staged"` | `"staged"` or `"thesis"` |
    | `reward_reach_weight` | `1.0` | weight of `reward_reach` (staged) |
    | `reward_grasp_weight` | `1.0` | weight of `reward_grasp` (staged) |
    | `reward_lift_weight` | `2.0` | weight of `reward_lift` (staged) |
    | `reward_hold_weight` | `2.0` | weight of `reward_hold` (staged) |
    | `reward_control_weight` | `None` | weight of `reward_ctrl`; `None`: 0.1 (staged) or 1 (thesis) |
    | `terminate_on_success` | `None` | end the episode on success; `None`: only in thesis mode |
    | `reset_noise_scale` | `0.1` | half-width of the initial joint-angle noise (rad) |
    | `lift_height` | `0.05` | height of the cube's bottom above the floor that counts as lifted (m) |

    ## Version History
    * v0: first release. Differs from the thesis: staged default reward (the thesis' per-step contact reward
      can be farmed: a TRPO agent that had learnt to lift went back to touching the cube for whole
      episodes); cube height from its geom (a naive port measures the body frame, ~0.2 m above the geom,
      so "lifted" is always true); contacts by geom name; reward after the physics step; cos/sin angles,
      claw angle, cube-relative claw positions and claw-cube contacts observed; cube in a disc of radius 0.1 m.
    """

    observation_dim = 31  # versions that observe more override it

    def __init__(
        self,
        xml_file: str = "grasper3d.xml",
        frame_skip: int = 2,
        default_camera_config: dict[str, Any] = DEFAULT_CAMERA_CONFIG_3D,
        reward_mode: str = "staged",
        reward_reach_weight: float = 1.0,
        reward_grasp_weight: float = 1.0,
        reward_lift_weight: float = 2.0,
        reward_hold_weight: float = 2.0,
        reward_control_weight: float | None = None,
        terminate_on_success: bool | None = None,
        reset_noise_scale: float = 0.1,
        lift_height: float = 0.05,
        **kwargs: Any,
    ):
        if reward_mode not in REWARD_MODES:
            raise ValueError(f"reward_mode must be one of {REWARD_MODES}, got {reward_mode!r}")
        utils.EzPickle.__init__(
            self, xml_file, frame_skip, default_camera_config, reward_mode, reward_reach_weight, reward_grasp_weight,
            reward_lift_weight, reward_hold_weight, reward_control_weight, terminate_on_success, reset_noise_scale,
            lift_height, **kwargs,
        )  # fmt: skip
        self._reward_mode = reward_mode
        self._reward_reach_weight = reward_reach_weight
        self._reward_grasp_weight = reward_grasp_weight
        self._reward_lift_weight = reward_lift_weight
        self._reward_hold_weight = reward_hold_weight
        thesis = reward_mode == "thesis"
        self._reward_control_weight = (1.0 if thesis else 0.1) if reward_control_weight is None else reward_control_weight
        self._terminate_on_success = thesis if terminate_on_success is None else terminate_on_success
        self._reset_noise_scale = reset_noise_scale
        self._lift_height = lift_height
        self._lift_bonus_paid = False
        self._contacts = {"right": 0, "left": 0, "floor": 0, "claw_claw": 0}
        ArmEnv.__init__(self, xml_file, frame_skip, default_camera_config, self.observation_dim, **kwargs)

        self._claw_geoms = {side: self.geom_mask([f"claw_{side}_{part}" for part in CLAW_PARTS]) for side in CLAW_SIDES}
        self._bottom_claw_geoms = self.geom_mask([f"claw_{s}_{p}" for s in CLAW_SIDES for p in CLAW_PARTS if "bottom" in p])
        self._cube_geom = self.geom_mask(["cube"])
        self._floor_geom = self.geom_mask(["floor"])
        self._arm_qpos = np.array([self.model.joint(j).qposadr[0] for j in ARM_JOINTS])
        self._arm_qvel = np.array([self.model.joint(j).dofadr[0] for j in ARM_JOINTS])
        self._claw_qpos = int(self.model.joint("claw_right").qposadr[0])
        self._claw_qvel = int(self.model.joint("claw_right").dofadr[0])
        self._cube_qpos = np.array([self.model.joint(f"cube_{a}").qposadr[0] for a in "xyz"])
        self._cube_body_pos = self.model.body("cube").pos.copy()
        self._cube_geom_view = self.data.geom("cube")

    # ------------------------------------------------------------------ named quantities
    def cube_pos(self) -> NDArray[np.float64]:
        return self._cube_geom_view.xpos

    def cube_height(self) -> float:
        """Height of the cube's bottom face above the floor, from the cube geom (not its body frame)."""
        return float(self.cube_pos()[2] - CUBE_HALF_SIZE - FLOOR_Z)

    def claw_cube_contacts(self) -> dict[str, int]:
        """Number of capsules of each claw half touching the cube."""
        pairs = self.contact_pairs()
        return {side: self.touching_geoms(pairs, self._claw_geoms[side], self._cube_geom) for side in CLAW_SIDES}

    def _contact_summary(self, pairs: NDArray[np.int32]) -> dict[str, int]:
        """All contact counts the reward, observation and success need, from one read of the contacts."""
        summary = {side: self.touching_geoms(pairs, self._claw_geoms[side], self._cube_geom) for side in CLAW_SIDES}
        summary["floor"] = int(self.touching(pairs, self._bottom_claw_geoms, self._floor_geom).sum())
        summary["claw_claw"] = min(int(self.touching(pairs, self._claw_geoms["right"], self._claw_geoms["left"]).sum()), 2)
        return summary

    def _is_grasped(self, contacts: dict[str, int]) -> bool:
        return contacts["right"] > 0 and contacts["left"] > 0

    def _reach_distance(self) -> float:
        """The distance ``reward_reach`` shrinks (m): grip site to cube centre."""
        return float(np.linalg.norm(self.site_pos("grip") - self.cube_pos()))

    def _is_success(self) -> bool:
        return self.cube_height() >= self._lift_height and self._is_grasped(self._contacts)

    # ------------------------------------------------------------------ reward
    def _get_rew(self, action: NDArray[np.float64]) -> tuple[float, dict[str, Any]]:
        contacts = self._contacts
        height = self.cube_height()
        ctrl = -self._reward_control_weight * float(np.square(action).sum())
        cube = self.cube_pos()
        grasped = self._is_grasped(contacts)
        info: dict[str, Any] = {"cube_height": height, "claw_cube_contacts": contacts["right"] + contacts["left"]}
        if self._reward_mode == "thesis":
            right, left = self.site_pos("claw_right"), self.site_pos("claw_left")
            n_cube = contacts["right"] + contacts["left"]
            lifted = height >= self._lift_height and n_cube > 3
            self._lift_bonus_paid = lifted
            terms = {
                "reward_dist": float(
                    -np.linalg.norm(self.site_pos("palm") - cube) - np.linalg.norm(right - cube)
                    - np.linalg.norm(left - cube) + np.linalg.norm(left - right)
                ),
                "reward_ctrl": ctrl,
                "reward_contact": float(n_cube),
                "reward_floor": -float(contacts["floor"]),
                "reward_claw_collision": -float(contacts["claw_claw"]) if n_cube <= 4 else 0.0,
                "reward_lift": 1000.0 + 1000.0 * height if lifted else 0.0,
            }  # fmt: skip
        else:
            solved = grasped and height >= self._lift_height
            terms = {
                "reward_reach": self._reward_reach_weight * (1.0 - float(np.tanh(10.0 * self._reach_distance()))),
                "reward_grasp": self._reward_grasp_weight * (contacts["right"] + contacts["left"]) / 8.0,
                "reward_lift": self._reward_lift_weight * float(grasped) * min(max(height, 0.0) / self._lift_height, 1.0),
                "reward_hold": self._reward_hold_weight * float(solved),
                "reward_ctrl": ctrl,
            }
        info.update(terms)
        return float(sum(terms.values())), info

    def _is_terminal(self) -> bool:
        if not self._terminate_on_success:
            return False
        # thesis mode: the episode ends with the lift bonus (height and more than 3 capsules on the cube)
        return self._lift_bonus_paid if self._reward_mode == "thesis" else self._is_success()

    # ------------------------------------------------------------------ observation and reset
    def _get_obs(self) -> NDArray[np.float64]:
        qpos, qvel = self.data.qpos, self.data.qvel
        angles = qpos[self._arm_qpos]
        cube = self.cube_pos()
        # the observation is computed first after every physics change (step and reset): read contacts once here
        self._contacts = contacts = self._contact_summary(self.contact_pairs())
        return np.concatenate(
            [
                np.cos(angles),
                np.sin(angles),
                [qpos[self._claw_qpos]],
                qvel[self._arm_qvel],
                [qvel[self._claw_qvel]],
                cube,
                self.site_pos("palm") - cube,
                self.site_pos("claw_right") - cube,
                self.site_pos("claw_left") - cube,
                [float(contacts["right"] > 0), float(contacts["left"] > 0)],
            ]
        )

    def reset_model(self) -> NDArray[np.float64]:
        self._lift_bonus_paid = False
        noise = self._reset_noise_scale
        qpos = self.init_qpos.copy()
        qpos[self._arm_qpos] += self.np_random.uniform(-noise, noise, size=len(ARM_JOINTS))
        claw = self.np_random.uniform(-noise, noise)
        qpos[self._claw_qpos] = claw
        qpos[self.model.joint("claw_left").qposadr[0]] = -claw
        radius = 0.1 * np.sqrt(self.np_random.uniform())
        angle = self.np_random.uniform(-np.pi, np.pi)
        cube = np.array([radius * np.cos(angle), radius * np.sin(angle), FLOOR_Z + CUBE_HALF_SIZE])
        qpos[self._cube_qpos] = cube - self._cube_body_pos
        qvel = self.init_qvel + self.np_random.uniform(-0.005, 0.005, size=self.model.nv)
        qvel[self._cube_qpos - self._cube_qpos[0] + int(self.model.joint("cube_x").dofadr[0])] = 0.0
        self.set_state(qpos, qvel)
        return self._get_obs()
