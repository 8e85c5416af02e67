"""Grasper3D-v6: Grasper3D-v5 with a cube that turns about the vertical (a hinge beside its three slide joints),
so that it can turn with the claw that holds it, and its orientation observed."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
from gymnasium import utils
from numpy.typing import NDArray

from grasp_envs import grasper3d_v5
from grasp_envs.base import derived_docstring

CUBE_ROTATION_JOINT = "cube_rotation"
CUBE_ROTATION_DAMPING = 1e-4  # N m s/rad per axis; the cube's inertia is 1.3e-6 kg m^2 about each axis
# cube_rotation -> the joint that lets the cube turn: "yaw" about the world's vertical (it stays upright), "free" about
# every axis (it can also tip over; tried first: the claw tumbles it on the floor and learning was slower)
CUBE_ROTATIONS: dict[str, dict[str, Any]] = {
    "yaw": {"type": mujoco.mjtJoint.mjJNT_HINGE, "axis": [0.0, 0.0, 1.0]},
    "free": {"type": mujoco.mjtJoint.mjJNT_BALL},
}
# start_pose -> the arm's joint angles before the reset noise (shoulder_y, shoulder_z, elbow_y, elbow_z, forearm_roll):
# "stretched", the thesis' (horizontal along +x); "ready", the upper arm pitched 30 deg up and the forearm pointing
# down, the grip 8.7 cm out along +x and 7 cm above the cube's top face, as manipulation benchmarks start
# (Gymnasium Robotics' Fetch: the gripper above the table)
START_POSES: dict[str, tuple[float, ...]] = {
    "stretched": (0.0, 0.0, 0.0, 0.0, 0.0),
    "ready": (-np.pi / 6, 0.0, 2 * np.pi / 3, 0.0, 0.0),
}
ORIENTATION_ROWS = (
    "cube x axis x (unit vector along the cube's edge that starts along world x) | unitless",
    "cube x axis y | unitless",
    "cube x axis z | unitless",
    "cube z axis x (unit vector along the cube's edge that starts vertical; (0, 0, 1) unless `cube_rotation` is"
    ' `"free"`) | unitless',
    "cube z axis y | unitless",
    "cube z axis z | unitless",
)


def _v6_docstring(v5_doc: str) -> str:
    """v5's docstring with v6's cube, observation, argument and version entry."""
    last_row = "    | 25 | claw servo torque on `claw_right` (positive closes) | N m |"
    rows = "".join(f"\n    | {26 + i} | {row} |" for i, row in enumerate(ORIENTATION_ROWS))
    last_argument = "where it often slips out |"
    start = "## Starting State\n    Arm horizontal along +x, claw closed,"
    replacements = {
        "## Description\n    Grasper3D-v4 observing the task space only": (
            "## Description\n    Grasper3D-v5 with a cube that can turn about the vertical. Grasper3D-v4 observing the"
            " task space only"
        ),
        "a 24 mm cube (free to slide in x, y, z, not to rotate)": (
            "a 24 mm cube (free to slide in x, y, z and to turn about the vertical)"
        ),
        "`Box(-inf, inf, (26,), float64)`:": "`Box(-inf, inf, (32,), float64)`:",
        last_row: last_row + rows,
        "the cube rests on the floor, uniform in the disc": (
            "the cube rests on the floor, its edges along the world axes,\n    uniform in the disc"
        ),
        last_argument: last_argument
        + '\n    | `cube_rotation` | `"yaw"` | how the cube can turn: `"yaw"` about the vertical through its centre (it stays'
        ' upright), `"free"` about every axis (a ball joint: it can also tip over) |'
        + '\n    | `start_pose` | `"stretched"` | the arm\'s pose before the reset noise: `"stretched"` horizontal along +x'
        ' (the thesis\'), `"ready"` the upper arm 30° up and the forearm pointing down, the grip 8.7 cm out along +x'
        " and 7 cm above the cube's top |",
        start: "## Starting State\n    Arm horizontal along +x (`start_pose`), claw closed,",
    }
    return derived_docstring(
        v5_doc,
        "Grasper3D-v5",
        replacements,
        "\n    * v6: the cube can turn about the vertical (a hinge beside its slide joints, damping 1e-4 N m s/rad) and"
        "\n      its orientation is observed; action, controller, reward, success and time limit are v5's. The thesis'"
        "\n      cube only slides, which did not matter there (its episodes ended at the lift) but does when the cube must"
        "\n      stay up: the claw's yaw is free and drifts while it holds the cube, a cube that cannot turn with it is"
        "\n      levered out, and on v5 the scripted grasp lost 13 of 40 held-out cubes after lifting them (2 here) and"
        "\n      two trained policies lost 10 of 40 each (2 and 1 with the same weights here).\n    ",
    )


class Grasper3DEnv(grasper3d_v5.Grasper3DEnv):
    __doc__ = _v6_docstring(grasper3d_v5.Grasper3DEnv.__doc__ or "")

    observation_dim = 32  # v5's 26 and the cube's x and z axes

    def __init__(self, cube_rotation: str = "yaw", start_pose: str = "stretched", **kwargs: Any):
        """v5's arguments (keywords), ``cube_rotation`` and ``start_pose`` (see the class docstring)."""
        if cube_rotation not in CUBE_ROTATIONS:
            raise ValueError(f"cube_rotation must be one of {sorted(CUBE_ROTATIONS)}, got {cube_rotation!r}")
        if start_pose not in START_POSES:
            raise ValueError(f"start_pose must be one of {sorted(START_POSES)}, got {start_pose!r}")
        self._cube_rotation = cube_rotation  # read while the base class builds the model
        super().__init__(**kwargs)
        self.init_qpos[self._arm_qpos] = START_POSES[start_pose]
        utils.EzPickle.__init__(self, cube_rotation=cube_rotation, start_pose=start_pose, **kwargs)

    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """v5's model (``xml_file``) with the cube's rotation joint (``add_cube_rotation``)."""
        spec = mujoco.MjSpec.from_file(self.fullpath)
        add_cube_rotation(spec, self._cube_rotation)
        model = spec.compile()
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        return model, mujoco.MjData(model)

    def cube_axes(self) -> NDArray[np.float64]:
        """The cube's x and z axes in the world frame (the first and last columns of its rotation matrix)."""
        rotation = self.data.geom("cube").xmat.reshape(3, 3)
        return np.concatenate([rotation[:, 0], rotation[:, 2]])

    def _get_obs(self) -> NDArray[np.float64]:
        return np.concatenate([super()._get_obs(), self.cube_axes()])


def add_cube_rotation(spec: mujoco.MjSpec, cube_rotation: str = "yaw") -> None:
    """Let the model's cube turn (``CUBE_ROTATIONS``): a joint after its three slide joints (the cube is the last
    body, so every other coordinate keeps its index and the cube's orientation comes last in ``qpos``)."""
    spec.body("cube").add_joint(
        name=CUBE_ROTATION_JOINT, damping=CUBE_ROTATION_DAMPING, armature=0.0, **CUBE_ROTATIONS[cube_rotation]
    )
