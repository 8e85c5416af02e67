"""Grasper3D-v3: Grasper3D-v2 with a grasp reward paid for squeezing the cube, and the squeeze observed."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import utils
from numpy.typing import NDArray

from grasp_envs import grasper3d_v2
from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D, derived_docstring
from grasp_envs.scripted import grasper3d_policy

# Claw servo torque (N m) at which reward_squeeze saturates. Measured with the scripted grasp (Grasper3D-v2, 10
# seeded episodes, median torque while grasped): command 0.42 gives 0.21 N m, 0.5 gives 0.29, 0.7 gives 0.51, 1.0
# gives 0.78; the halves first touch the cube at a command of about 0.375.
SQUEEZE_TORQUE = 0.5
SCRIPTED_START_STEPS = (0, 100)  # a scripted start runs the scripted grasp for 0-99 steps (it grasps at steps 53-86)


def _v3_docstring(v2_doc: str) -> str:
    """v2's docstring with v3's squeeze term, observation, arguments and version entry."""
    replacements = {
        "## Description\n    Grasper3D-v1 (its claw, reward and observation) driven by end-effector commands:": (
            "## Description\n    Grasper3D-v2 with a reward for squeezing the grasped cube. Grasper3D-v1 (its claw,"
            " reward and\n    observation) driven by end-effector commands:"
        ),
        "`Box(-inf, inf, (31,), float64)`:": "`Box(-inf, inf, (32,), float64)`:",
        "    | 30 | left claw half touches the cube | unitless |\n": (
            "    | 30 | left claw half touches the cube | unitless |\n"
            "    | 31 | claw servo torque on `claw_right` (positive closes) | N m |\n"
        ),
        "    - `reward_lift` $= w_{lift} \\min(h / 0.05, 1)$ while grasped": (
            "    - `reward_squeeze` $= w_{squeeze} \\min(\\max(\\tau, 0) / 0.5, 1)$ while grasped, with $\\tau$ the claw"
            " servo's\n      torque (N m), `reward_squeeze_weight` (2): a firm grip, one that the policy's own"
            " exploration noise on\n      the claw command does not open when the arm rises\n"
            "    - `reward_lift` $= w_{lift} \\min(h / 0.05, 1)$ while grasped"
        ),
        "    | `reward_floor_weight` | `1.0` | weight of `reward_floor` (staged) |\n": (
            "    | `reward_floor_weight` | `1.0` | weight of `reward_floor` (staged) |\n"
            "    | `reward_squeeze_weight` | `2.0` | weight of `reward_squeeze` (staged) |\n"
            "    | `squeeze_torque` | `0.5` | claw servo torque at which `reward_squeeze` saturates (N m) |\n"
            "    | `scripted_start_prob` | `0.0` | probability that a reset goes on with the scripted grasp for a uniform"
            " number of steps (`scripted_start_steps`), so the episode starts somewhere along a demonstration (a"
            " training aid; evaluate with 0) |\n"
            "    | `scripted_start_steps` | `(0, 100)` | the range `[low, high)` of that number of scripted steps"
            " (e.g. `(50, 100)` starts around the grasp and the lift) |\n"
            "    | `scripted_start_hold_height` | `None` | where the scripted grasp of those starts holds the cube (height"
            " of its bottom, m); `None` keeps raising it until the arm runs out of reach, where it often slips out |\n"
        ),
    }
    return derived_docstring(
        v2_doc,
        "Grasper3D-v2",
        replacements,
        "\n    * v3: `reward_squeeze` and the claw torque observed. On v2 one TRPOPlus seed in four learnt to lift;"
        "\n      the others closed the claw just past the point where the halves touch the cube (commands 0.34-0.42,"
        "\n      contact at 0.375), a grip that the policy's claw noise opens while the arm rises, and nothing paid"
        "\n      for squeezing harder.\n    ",
    )


class Grasper3DEnv(grasper3d_v2.Grasper3DEnv):
    __doc__ = _v3_docstring(grasper3d_v2.Grasper3DEnv.__doc__ or "")

    observation_dim = 32  # v2's 31 and the claw torque

    def __init__(
        self,
        xml_file: str = "grasper3d_v1.xml",
        frame_skip: int = 2,
        default_camera_config: dict[str, Any] = DEFAULT_CAMERA_CONFIG_3D,
        reward_mode: str = "staged",
        reward_reach_weight: float = 1.0,
        reward_grasp_weight: float = 4.0,
        reward_lift_weight: float = 4.0,
        reward_hold_weight: float = 4.0,
        reward_control_weight: float | None = None,
        terminate_on_success: bool | None = None,
        reset_noise_scale: float = 0.1,
        lift_height: float = 0.05,
        reward_floor_weight: float = 1.0,
        max_grip_speed: float = grasper3d_v2.MAX_GRIP_SPEED,
        claw_rate: float | None = None,
        reward_squeeze_weight: float = 2.0,
        squeeze_torque: float = SQUEEZE_TORQUE,
        scripted_start_prob: float = 0.0,
        scripted_start_steps: tuple[int, int] = SCRIPTED_START_STEPS,
        scripted_start_hold_height: float | None = None,
        **kwargs: Any,
    ):
        if not squeeze_torque > 0:
            raise ValueError(f"squeeze_torque must be positive, got {squeeze_torque!r}")
        if not 0.0 <= scripted_start_prob <= 1.0:
            raise ValueError(f"scripted_start_prob must be in [0, 1], got {scripted_start_prob!r}")
        steps = tuple(scripted_start_steps) if isinstance(scripted_start_steps, (tuple, list)) else ()
        if not (len(steps) == 2 and all(isinstance(n, (int, np.integer)) for n in steps) and 0 <= steps[0] < steps[1]):
            raise ValueError(f"scripted_start_steps must be (low, high) with 0 <= low < high, got {scripted_start_steps!r}")
        low, high = steps
        if scripted_start_hold_height is not None and not scripted_start_hold_height > 0:
            raise ValueError(f"scripted_start_hold_height must be None or positive, got {scripted_start_hold_height!r}")
        super().__init__(
            xml_file, frame_skip, default_camera_config, reward_mode, reward_reach_weight, reward_grasp_weight,
            reward_lift_weight, reward_hold_weight, reward_control_weight, terminate_on_success, reset_noise_scale,
            lift_height, reward_floor_weight, max_grip_speed, claw_rate, **kwargs,
        )  # fmt: skip
        utils.EzPickle.__init__(
            self, xml_file, frame_skip, default_camera_config, reward_mode, reward_reach_weight, reward_grasp_weight,
            reward_lift_weight, reward_hold_weight, reward_control_weight, terminate_on_success, reset_noise_scale,
            lift_height, reward_floor_weight, max_grip_speed, claw_rate, reward_squeeze_weight, squeeze_torque,
            scripted_start_prob, scripted_start_steps, scripted_start_hold_height, **kwargs,
        )  # fmt: skip
        self._scripted_start_prob = float(scripted_start_prob)
        self._scripted_start_steps = (int(low), int(high))
        self._scripted_start_hold_height = scripted_start_hold_height
        self._reward_squeeze_weight = reward_squeeze_weight
        self._squeeze_torque = float(squeeze_torque)
        self._claw_actuator = int(self.model.actuator("claw").id)

    def claw_torque(self) -> float:
        """The claw servo's torque on ``claw_right`` (N m, positive closes)."""
        return float(self.data.actuator_force[self._claw_actuator])

    def _get_obs(self) -> NDArray[np.float64]:
        return np.append(super()._get_obs(), self.claw_torque())

    def _get_rew(self, action: NDArray[np.float64]) -> tuple[float, dict[str, Any]]:
        reward, info = super()._get_rew(action)
        if self._reward_mode == "staged":
            squeeze = min(max(self.claw_torque(), 0.0) / self._squeeze_torque, 1.0)
            info["reward_squeeze"] = self._reward_squeeze_weight * float(self._is_grasped(self._contacts)) * squeeze
            reward += info["reward_squeeze"]
        return reward, info

    def reset_model(self) -> NDArray[np.float64]:
        observation = super().reset_model()
        # random numbers are drawn only when the option is on, so default resets stay v3's
        if self._scripted_start_prob > 0 and self.np_random.uniform() < self._scripted_start_prob:
            for _ in range(int(self.np_random.integers(*self._scripted_start_steps))):
                action = grasper3d_policy(self, hold_height=self._scripted_start_hold_height)
                if self._simulate(self._checked_action(action)):  # unstable: start from scratch
                    return super().reset_model()
            observation = self._get_obs()
        return observation
