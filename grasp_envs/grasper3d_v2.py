"""Grasper3D-v2: Grasper3D-v1 driven by end-effector velocity commands instead of joint torques."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import utils
from gymnasium.spaces import Box
from numpy.typing import NDArray

from grasp_envs import grasper3d_v1
from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D, derived_docstring
from grasp_envs.control import grip_down_commands

MAX_GRIP_SPEED = 0.4  # m/s of the grip site at an action of 1
CLAW_OPEN_TARGET, CLAW_SERVO_SLOPE = -0.3, 0.4  # v1's claw servo aims at -0.3 + 0.4 c rad
CLAW_TARGET_RANGE = (-0.7, 0.1)  # what v1's servo can aim at (ctrl in [-1, 1])


def _v2_docstring(v1_doc: str) -> str:
    """v1's docstring with v2's action space, argument and version entry."""
    action_v1 = v1_doc.split("## Action Space\n")[1].split("\n\n")[0]
    replacements = {
        "## Description\n    Grasper3D-v0 with a claw that can hold the cube and a reward in which lifting dominates.\n": (
            "## Description\n    Grasper3D-v1 (its claw, reward and observation) driven by end-effector commands: the"
            " policy says\n    where the grip site should move and how the claw should close; a joint-level controller"
            " inside the\n    environment turns that into the five arm torques.\n"
        ),
        action_v1: (
            "    `Box(-1, 1, (4,), float32)`: the grip site's velocity $v = 0.4 a_{0:3}$ m/s (`max_grip_speed`) in\n"
            "    world x, y, z, then v1's claw command $c$ (the servo aims at $0.4 c - 0.3$ rad; positive closes). Each\n"
            "    step the environment solves the inverse kinematics for that velocity by damped least squares on MuJoCo's\n"
            "    Jacobians, with two more rows that turn the forearm to point down and keep the claw's closing axis\n"
            "    horizontal, and drives the five arm motors with a gravity-compensated joint-velocity servo (torques\n"
            "    clipped to v1's range; `grasp_envs.control.grip_down_commands`). The claw's yaw is left free."
        ),
        "| `lift_height` | `0.05` |": (
            "| `max_grip_speed` | `0.4` | grip-site speed at an action of 1 (m/s) |\n"
            "    | `claw_rate` | `None` | `None`: the claw action is v1's servo command; a number $r$: each step's claw"
            " action $c$ moves the servo's target by $r c$ rad (within [-0.7, 0.1]; the target is not observed) |\n"
            "    | `lift_height` | `0.05` |"
        ),
    }
    return derived_docstring(
        v1_doc,
        "Grasper3D-v1",
        replacements,
        "\n    * v2: end-effector velocity actions (4) instead of joint torques (6), as Gymnasium Robotics' Fetch"
        "\n      tasks and robosuite's operational-space controllers do; model, reward, observation and time limit"
        "\n      are v1's. With joint torques no policy got past reaching in 5M steps (v0) or 2.4M (v1, eleven designs):"
        "\n      a grasp needs five joints coordinated to point the claw down and descend within 2 cm of the cube,"
        "\n      which Gaussian exploration in torque space does not find.\n    ",
    )


class Grasper3DEnv(grasper3d_v1.Grasper3DEnv):
    __doc__ = _v2_docstring(grasper3d_v1.Grasper3DEnv.__doc__ or "")

    grip_priority = False  # the inverse kinematics' rows: one weighted stack (see grip_down_commands)

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
        max_grip_speed: float = MAX_GRIP_SPEED,
        claw_rate: float | None = None,
        **kwargs: Any,
    ):
        if not max_grip_speed > 0:
            raise ValueError(f"max_grip_speed must be positive, got {max_grip_speed!r}")
        if claw_rate is not None and not claw_rate > 0:
            raise ValueError(f"claw_rate must be positive or None, got {claw_rate!r}")
        self.max_grip_speed = float(max_grip_speed)
        self._claw_rate = claw_rate
        self._claw_target = CLAW_OPEN_TARGET
        super().__init__(
            xml_file, frame_skip, default_camera_config, reward_mode, reward_reach_weight, reward_grasp_weight,
            reward_lift_weight, reward_hold_weight, reward_control_weight, terminate_on_success, reset_noise_scale,
            lift_height, reward_floor_weight, **kwargs,
        )  # fmt: skip
        utils.EzPickle.__init__(
            self, xml_file, frame_skip, default_camera_config, reward_mode, reward_reach_weight, reward_grasp_weight,
            reward_lift_weight, reward_hold_weight, reward_control_weight, terminate_on_success, reset_noise_scale,
            lift_height, reward_floor_weight, max_grip_speed, claw_rate, **kwargs,
        )  # fmt: skip

    def _set_action_space(self) -> Box:
        self.action_space = Box(low=-1.0, high=1.0, shape=(4,), dtype=np.float32)
        return self.action_space

    def _simulate(self, action: NDArray[np.float64]) -> bool:
        arm = grip_down_commands(self, self.max_grip_speed * action[:3], self.grip_priority)
        claw = action[3]
        if self._claw_rate is not None:  # the action moves the servo's target angle; ctrl aims the servo there
            self._claw_target = float(np.clip(self._claw_target + self._claw_rate * claw, *CLAW_TARGET_RANGE))
            claw = (self._claw_target - CLAW_OPEN_TARGET) / CLAW_SERVO_SLOPE
        ctrl = np.clip(np.concatenate([arm, [claw]]), self._ctrl_low, self._ctrl_high)
        return super()._simulate(ctrl)

    def reset_model(self) -> NDArray[np.float64]:
        observation = super().reset_model()
        self._claw_target = float(self.data.qpos[self._claw_qpos])
        return observation
