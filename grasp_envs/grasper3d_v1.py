"""Grasper3D-v1: Grasper3D-v0 with a force-limited position-servo claw and a staged reward that pays for lifting."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import utils
from numpy.typing import NDArray

from grasp_envs import grasper3d_v0
from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D, derived_docstring

BETWEEN_TOLERANCE = 0.02  # m, see Grasper3DEnv.cube_between_claws


def _v1_docstring(v0_doc: str) -> str:
    """v0's docstring with v1's claw, grasp term, weights, success rule and version entry."""
    action_v0 = v0_doc.split("## Action Space\n")[1].split("\n\n")[0]
    replacements = {
        "## Description\n": (
            "## Description\n    Grasper3D-v0 with a claw that can hold the cube and a reward in which lifting dominates.\n\n"
        ),
        action_v0: (
            "    `Box([-0.5 -0.5 -0.5 -0.5 -0.5 -1. ], [0.5 0.5 0.5 0.5 0.5 1. ], (6,), float32)`: torques on `shoulder_y`,\n"
            "    `shoulder_z`, `elbow_y`, `elbow_z`, `forearm_roll` (gear 200), then a claw command $c$: a position servo\n"
            "    on `claw_right` aims at the angle $0.4 c - 0.3$ rad (kp 10 N m/rad, force limited to 5 N m), so $c = 0$\n"
            "    holds the claw half open (34 mm between the tips, the cube is 24 mm), $c = -1$ opens it fully (-40°) and\n"
            "    $c = 1$ closes it (positive closes)."
        ),
        "`reward_grasp_weight` (1): the thesis' contact shaping": "`reward_grasp_weight` (4): the thesis' contact shaping",
        "    - `reward_reach` $= w_{reach} (1 - \\tanh(10 \\lVert p_{grip} - p_{cube} \\rVert))$, `reward_reach_weight` (1)": (
            "    - `reward_reach` $= w_{reach} (1 - \\tanh(10 e))$, `reward_reach_weight` (1), with the thesis' claw terms\n"
            "      $e = \\lVert p_{right} - p_{cube} \\rVert + \\lVert p_{left} - p_{cube} \\rVert"
            " - \\lVert p_{left} - p_{right} \\rVert \\ge 0$,\n"
            "      zero exactly when the cube's centre lies on the segment between the claw sites (straddled)"
        ),
        "while both halves touch the cube, `reward_lift_weight` (2)": "while grasped, `reward_lift_weight` (4)",
        "`reward_hold_weight` (2)\n": (
            "`reward_hold_weight` (4)\n"
            "    - `reward_floor` $= -w_{floor}$ while a claw capsule touches the floor, `reward_floor_weight` (1): an open\n"
            "      claw pressed onto the floor straddles the cube but cannot close (its tips swing towards the floor)\n"
        ),
        'Success (`info["is_success"]`): $h \\ge 0.05$ m while both claw halves touch the cube.': (
            'Success (`info["is_success"]`): $h \\ge 0.05$ m while grasped: both claw halves touch the cube and the\n'
            "    cube's centre lies between them (v0: any touch of both halves, which pressing from above also gives)."
        ),
        '| `xml_file` | `"grasper3d.xml"` |': '| `xml_file` | `"grasper3d_v1.xml"` |',
        "| `reward_lift_weight` | `2.0` |": "| `reward_lift_weight` | `4.0` |",
        "| `reward_hold_weight` | `2.0` |": "| `reward_hold_weight` | `4.0` |",
        "| `reward_grasp_weight` | `1.0` |": "| `reward_grasp_weight` | `4.0` |",
        "| `lift_height` | `0.05` | height of the cube's bottom above the floor that counts as lifted (m) |\n": (
            "| `lift_height` | `0.05` | height of the cube's bottom above the floor that counts as lifted (m) |\n"
            "    | `reward_floor_weight` | `1.0` | weight of `reward_floor` (staged) |\n"
        ),
    }
    return derived_docstring(
        v0_doc,
        "Grasper3D-v0",
        replacements,
        "\n    * v1: a claw that can hold the cube: a force-limited position servo (v0's 50 N m torque motor squeezes"
        "\n      the 14 g cube out of the slanted claw) whose zero command holds the claw half open; the halves no"
        "\n      longer collide at their common hinge (in v0 they always did, so small torques could not open the"
        "\n      claw) and closing stops at 2°; lighter claw joints (armature 0.02, damping 0.5); forearm roll limited"
        "\n      to ±90° (the claw is symmetric; learned policies spun the unlimited roll at 6-10 rad/s); grip site"
        "\n      1 cm further out (0.155 m along the forearm), where the closing tips meet the cube. Reward: reaching"
        "\n      means straddling the cube (the thesis' claw terms), lifting needs the cube between the halves, a claw"
        "\n      on the floor costs, grasp weight 4 (v0: 1), lift and hold weights 4 (v0: 2), so that reaching (about"
        "\n      85 per episode in v0, where the scripted lift earns 92) no longer competes with lifting. Observation"
        "\n      and time limit are v0's.\n    ",
    )


class Grasper3DEnv(grasper3d_v0.Grasper3DEnv):
    __doc__ = _v1_docstring(grasper3d_v0.Grasper3DEnv.__doc__ or "")

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
        **kwargs: Any,
    ):
        super().__init__(
            xml_file, frame_skip, default_camera_config, reward_mode, reward_reach_weight, reward_grasp_weight,
            reward_lift_weight, reward_hold_weight, reward_control_weight, terminate_on_success, reset_noise_scale,
            lift_height, **kwargs,
        )  # fmt: skip
        utils.EzPickle.__init__(
            self, xml_file, frame_skip, default_camera_config, reward_mode, reward_reach_weight, reward_grasp_weight,
            reward_lift_weight, reward_hold_weight, reward_control_weight, terminate_on_success, reset_noise_scale,
            lift_height, reward_floor_weight, **kwargs,
        )  # fmt: skip
        self._reward_floor_weight = reward_floor_weight
        self._all_claw_geoms = self._claw_geoms["right"] | self._claw_geoms["left"]

    def _contact_summary(self, pairs: NDArray[np.int32]) -> dict[str, int]:
        summary = super()._contact_summary(pairs)
        summary["claw_floor"] = int(self.touching(pairs, self._all_claw_geoms, self._floor_geom).any())
        summary["between"] = int(self.cube_between_claws())
        return summary

    def _get_rew(self, action: NDArray[np.float64]) -> tuple[float, dict[str, Any]]:
        reward, info = super()._get_rew(action)
        if self._reward_mode == "staged":
            info["reward_floor"] = -self._reward_floor_weight * self._contacts["claw_floor"]
            reward += info["reward_floor"]
        return reward, info

    def cube_between_claws(self) -> bool:
        """Whether the cube's centre lies between the claw halves: its projection on the segment from the
        right to the left claw site falls inside the segment, at most 2 cm away from it (a cube held by the top
        or bottom capsules only sits ~1 cm off the sites' plane; a cube pressed from above sits >= 3 cm away)."""
        t, offset = self._cube_off_claw_segment()
        return 0.0 < t < 1.0 and float(np.linalg.norm(offset)) < BETWEEN_TOLERANCE

    def _cube_off_claw_segment(self) -> tuple[float, NDArray[np.float64]]:
        """Where the cube's centre projects on the segment from the right to the left claw site (0 at the right
        site, 1 at the left) and its offset from that projection (world frame, m)."""
        right, left, cube = self.site_pos("claw_right"), self.site_pos("claw_left"), self.cube_pos()
        span = left - right
        t = float((cube - right) @ span / (span @ span))
        return t, cube - right - t * span

    def _reach_distance(self) -> float:
        """The thesis' claw terms: |right - cube| + |left - cube| - |left - right| (m), zero exactly when the cube's
        centre lies on the segment between the claw sites: it pulls the claw to straddle the cube, and to open
        for it, rather than towards a point that a closed claw would press onto the cube."""
        right, left, cube = self.site_pos("claw_right"), self.site_pos("claw_left"), self.cube_pos()
        return float(np.linalg.norm(right - cube) + np.linalg.norm(left - cube) - np.linalg.norm(left - right))

    def _is_grasped(self, contacts: dict[str, int]) -> bool:
        return super()._is_grasped(contacts) and contacts["between"] > 0
