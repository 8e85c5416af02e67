"""Grasper3D-v5: Grasper3D-v4 that observes the task space only: the grip's velocity and the claw's orientation
instead of the arm's joint angles and velocities."""

from __future__ import annotations

import re
from functools import cached_property

import mujoco
import numpy as np
from numpy.typing import NDArray

from grasp_envs import grasper3d_v4
from grasp_envs.base import derived_docstring

# v4's rows kept by v5 (its rows 10, 16-31): everything that is not a joint angle or an arm joint velocity
KEPT_V4_ROWS = np.r_[10, 16:32]
# the rows v5 puts before them (its rows 0-8)
TASK_SPACE_ROWS = (
    "grip site velocity x | m/s",
    "grip site velocity y | m/s",
    "grip site velocity z | m/s",
    "forearm axis x (unit vector from the elbow along the forearm; -z when it points down) | unitless",
    "forearm axis y | unitless",
    "forearm axis z | unitless",
    "claw hinge axis x (unit vector; the halves close about it) | unitless",
    "claw hinge axis y | unitless",
    "claw hinge axis z | unitless",
)


def _v5_docstring(v4_doc: str) -> str:
    """v4's docstring with v5's observation and version entry."""
    header = "    | Num | Observation | Unit |\n    |-----|-------------|------|\n"
    v4_table = v4_doc[v4_doc.index(header) : v4_doc.index("\n\n", v4_doc.index(header))]
    v4_rows = dict(re.findall(r"^    \| (\d+) \| (.+) \|$", v4_table, flags=re.MULTILINE))
    rows = [*TASK_SPACE_ROWS, *(v4_rows[str(row)] for row in KEPT_V4_ROWS)]
    v5_table = header + "\n".join(f"    | {number} | {row} |" for number, row in enumerate(rows))
    replacements = {
        "## Description\n    Grasper3D-v3 (v2 with a reward for squeezing the grasped cube)": (
            "## Description\n    Grasper3D-v4 observing the task space only (the grip's velocity and the claw's"
            " orientation instead\n    of the arm's joint angles and velocities). Grasper3D-v3 (v2 with a reward for"
            " squeezing the grasped cube)"
        ),
        "`Box(-inf, inf, (32,), float64)`:": "`Box(-inf, inf, (26,), float64)`:",
        v4_table: v5_table,
    }
    return derived_docstring(
        v4_doc,
        "Grasper3D-v4",
        replacements,
        "\n    * v5: the observation is the task space's, as the action already was: the grip's velocity and the"
        "\n      forearm's and claw hinge's directions replace the arm's joint angles and velocities (Gymnasium"
        "\n      Robotics' Fetch tasks observe no joints either); model, controller, reward, success and time limit are"
        "\n      v4's. On v4, TRPOPlus seeds that lifted cubes in front of the arm reached cubes behind the shoulder"
        "\n      and did not close the claw there: the arm reaches them in other joint configurations, which the"
        "\n      joint-space observation makes look like a different task. Here two configurations that hold the"
        "\n      claw in the same place look the same.\n    ",
    )


class Grasper3DEnv(grasper3d_v4.Grasper3DEnv):
    __doc__ = _v5_docstring(grasper3d_v4.Grasper3DEnv.__doc__ or "")

    observation_dim = 26  # v4's arguments and defaults: no __init__ of its own

    @cached_property
    def _grip_site(self) -> int:
        return int(self.model.site("grip").id)

    @cached_property
    def _grip_jacobian(self) -> NDArray[np.float64]:  # made on first use: the base class observes while it initialises
        return np.zeros((3, self.model.nv))

    def grip_velocity(self) -> NDArray[np.float64]:
        """Linear velocity of the grip site in the world frame (m/s): its Jacobian times the joint velocities, as
        Gymnasium Robotics' Fetch observes its grip (``qvel`` is the step's last; MuJoCo's own ``cvel`` lags it
        by one physics step)."""
        mujoco.mj_jacSite(self.model, self.data, self._grip_jacobian, None, self._grip_site)
        return self._grip_jacobian @ self.data.qvel

    def _get_obs(self) -> NDArray[np.float64]:
        forearm = self.data.body("forearm").xmat.reshape(3, 3)  # columns: x along the forearm, z the hinge axis
        return np.concatenate([self.grip_velocity(), forearm[:, 0], forearm[:, 2], super()._get_obs()[KEPT_V4_ROWS]])
