"""Grasper3D-v4: Grasper3D-v3 whose grip commands take priority over the forearm's orientation, and whose
grasp test accepts every grip by both claw halves."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from grasp_envs import grasper3d_v3
from grasp_envs.base import derived_docstring

# How far (m) the cube's centre may lie from the segment between the claw sites, along the forearm and along
# the claw's hinge axis, each. The inner capsules span 1.25 cm either side of the sites along the forearm and
# are 6 mm thick, the cube's half-size is 1.2 cm: a cube held by the tips sits up to ~2.45 cm out, one pressed
# from beyond the tips >= 3.05 cm. Along the hinge axis the capsules sit at +-0.8 cm: any grip of a side face
# is within 2.6 cm.
BETWEEN_TOLERANCE = 0.025


def _v4_docstring(v3_doc: str) -> str:
    """v3's docstring with v4's controller, grasp test and version entry."""
    replacements = {
        "## Description\n    Grasper3D-v2 with a reward for squeezing the grasped cube.": (
            "## Description\n    Grasper3D-v3 (v2 with a reward for squeezing the grasped cube) with a controller"
            " that always moves\n    the grip as commanded and a grasp test that accepts every grip by both halves."
        ),
        "Each\n    step the environment solves the inverse kinematics for that velocity by damped least squares on"
        " MuJoCo's\n    Jacobians, with two more rows that turn the forearm to point down and keep the claw's closing"
        " axis\n    horizontal,": (
            "Each\n    step the environment solves the inverse kinematics for that velocity by damped least squares on"
            " MuJoCo's\n    Jacobians, with the claw's closing axis kept horizontal; the forearm turns to point down"
            " only in the\n    joint direction these four rows leave free (task-priority inverse kinematics),"
        ),
        "    cube's centre lies between them (v0: any touch of both halves, which pressing from above also gives).": (
            "    cube's centre lies between them (v0: any touch of both halves, which pressing from above also gives):"
            "\n    it projects inside the segment between the claw sites and lies at most 2.5 cm from it along the"
            " forearm\n    and along the hinge axis, each (v1-v3: 2 cm in all)."
        ),
    }
    return derived_docstring(
        v3_doc,
        "Grasper3D-v3",
        replacements,
        "\n    * v4: task-priority inverse kinematics and a per-axis grasp test; reward, observation, model and time"
        "\n      limit are v3's. v2's controller solved one stack of five rows, so where the arm cannot move the grip"
        "\n      with the forearm pointing down, the command stalled: the scripted grasp raised the cube only 3.9 cm"
        "\n      at 6.4 cm from the shoulder's axis and grasped none of the three cubes within 4.3 cm of it (20 seeded"
        "\n      episodes; v4: 6 cm, and one of the three lifted 12 cm). v1's 2 cm tolerance"
        "\n      refused real grips: a cube held 8 cm up, hanging from the bottom capsules 1.9-2.2 cm off the claw"
        "\n      sites' plane, earned no lift and counted no success.\n    ",
    )


class Grasper3DEnv(grasper3d_v3.Grasper3DEnv):
    __doc__ = _v4_docstring(grasper3d_v3.Grasper3DEnv.__doc__ or "")

    grip_priority = True  # v3's arguments and defaults: no __init__ of its own

    def cube_between_claws(self) -> bool:
        """Whether the cube's centre lies between the claw halves: its projection on the segment from the right
        to the left claw site falls inside the segment, and its offset from the segment is at most 2.5 cm along
        the forearm and along the claw's hinge axis, each (a cube pressed from beyond the tips is >= 3 cm out
        along the forearm)."""
        t, offset = self.cube_off_claw_segment_in_forearm_frame()
        return 0.0 < t < 1.0 and abs(offset[0]) <= BETWEEN_TOLERANCE and abs(offset[2]) <= BETWEEN_TOLERANCE

    def cube_off_claw_segment_in_forearm_frame(self) -> tuple[float, NDArray[np.float64]]:
        """``_cube_off_claw_segment`` with the offset in the forearm's frame (x along the forearm, z the hinge axis)."""
        t, offset_world = self._cube_off_claw_segment()
        forearm = self.data.body("forearm").xmat.reshape(3, 3)  # columns: x along the forearm, z the hinge axis
        return t, forearm.T @ offset_world
