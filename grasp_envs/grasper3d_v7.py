"""Grasper3D-v7: Grasper3D-v6 whose grip moves twice as fast (0.8 m/s at an action of 1), so that a cube behind the
shoulder is reached in time to be grasped and lifted within the 100 steps."""

from __future__ import annotations

from typing import Any

from gymnasium import utils

from grasp_envs import grasper3d_v6
from grasp_envs.base import derived_docstring

MAX_GRIP_SPEED = 0.8  # m/s of the grip site at an action of 1 (v2-v6: 0.4)


def _v7_docstring(v6_doc: str) -> str:
    """v6's docstring with v7's grip speed and version entry."""
    replacements = {
        "## Description\n    Grasper3D-v5 with a cube that can turn about the vertical.": (
            "## Description\n    Grasper3D-v6 with a grip that moves twice as fast. Grasper3D-v5 with a cube that can"
            " turn about the vertical."
        ),
        "$v = 0.4 a_{0:3}$ m/s": f"$v = {MAX_GRIP_SPEED} a_{{0:3}}$ m/s",
        "| `max_grip_speed` | `0.4` |": f"| `max_grip_speed` | `{MAX_GRIP_SPEED}` |",
    }
    return derived_docstring(
        v6_doc,
        "Grasper3D-v6",
        replacements,
        "\n    * v7: `max_grip_speed` 0.8 m/s (v2-v6: 0.4, 8 mm per step); model, observation, reward, success and"
        "\n      time limit are v6's. The arm starts stretched along +x and the cube lies anywhere around the shoulder:"
        "\n      on v6 ten trained policies, moving the grip at the speed limit, first grasped a cube in front of the"
        "\n      arm after 36-42 of the 100 steps and one behind the shoulder after 49-72 (medians over 40 held-out"
        "\n      resets each), and lifted 0.98 of the cubes in front by step 100 and 0.73 of those behind (0.83 by"
        "\n      step 150). Gymnasium Robotics' Fetch moves its gripper's target up to 5 cm per step.\n    ",
    )


class Grasper3DEnv(grasper3d_v6.Grasper3DEnv):
    __doc__ = _v7_docstring(grasper3d_v6.Grasper3DEnv.__doc__ or "")

    def __init__(self, max_grip_speed: float = MAX_GRIP_SPEED, **kwargs: Any):
        """v6's arguments (keywords), with v7's default ``max_grip_speed``."""
        super().__init__(max_grip_speed=max_grip_speed, **kwargs)
        utils.EzPickle.__init__(self, max_grip_speed=max_grip_speed, **kwargs)
