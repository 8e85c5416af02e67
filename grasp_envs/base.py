"""Shared machinery of the arm tasks: action checking, stable stepping, named MuJoCo look-ups."""

from __future__ import annotations

from os import path
from typing import Any

import mujoco
import numpy as np
from gymnasium import utils
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.spaces import Box
from numpy.typing import NDArray

ASSETS = path.join(path.dirname(__file__), "assets")

DEFAULT_CAMERA_CONFIG_3D: dict[str, Any] = {
    "distance": 0.75,
    "elevation": -30.0,
    "azimuth": 135.0,
    "lookat": np.array([0.0, 0.0, -0.12]),
}

_INSTABILITY_WARNINGS = np.array(
    [
        mujoco.mjtWarning.mjWARN_BADQPOS,
        mujoco.mjtWarning.mjWARN_BADQVEL,
        mujoco.mjtWarning.mjWARN_BADQACC,
        mujoco.mjtWarning.mjWARN_BADCTRL,
    ],
    dtype=np.int64,
)


def near_bonus(distance: float, weight: float, scale: float) -> float:
    """The reachers' precision term ``weight (1 - tanh(distance / scale))``: bounded in ``[0, weight]`` and steepest at
    the target, so that the last centimetres before it pay."""
    return weight * (1.0 - float(np.tanh(distance / scale)))


def check_near_bonus(weight: float, scale: float) -> None:
    if not scale > 0:
        raise ValueError(f"near_scale must be positive, got {scale}")
    if not weight >= 0:
        raise ValueError(f"reward_near_weight must be non-negative, got {weight}")


def asset_path(xml_file: str) -> str:
    """Absolute path of a model: an existing path is used as given, a bare name is looked up in our assets."""
    if path.isabs(xml_file) or path.exists(xml_file):
        return path.abspath(xml_file)
    return path.join(ASSETS, xml_file)


class ArmEnv(MujocoEnv, utils.EzPickle):
    """Base class of the thesis' arm tasks (not registered itself).

    Subclasses implement ``_get_obs``, ``_get_rew`` (returning ``(reward, {"reward_<term>": ...})``),
    ``_is_success`` and ``reset_model``. ``step`` validates and clips the action, simulates, and
    ends the episode with ``info["unstable"] = True`` if MuJoCo had to reset a diverging simulation.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}
    action_space: Box  # every arm task has continuous actions

    def __init__(
        self,
        xml_file: str,
        frame_skip: int,
        default_camera_config: dict[str, Any] | None,
        observation_dim: int,
        **kwargs: Any,
    ):
        if isinstance(frame_skip, bool) or not isinstance(frame_skip, int | np.integer) or frame_skip < 1:
            raise ValueError(f"frame_skip must be an integer >= 1, got {frame_skip!r}")
        observation_space = Box(low=-np.inf, high=np.inf, shape=(observation_dim,), dtype=np.float64)
        MujocoEnv.__init__(
            self,
            asset_path(xml_file),
            frame_skip,
            observation_space=observation_space,
            default_camera_config=default_camera_config,
            **kwargs,
        )
        self.metadata = {**ArmEnv.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        self._ctrl_low = self.model.actuator_ctrlrange[:, 0].copy()
        self._ctrl_high = self.model.actuator_ctrlrange[:, 1].copy()

    # ------------------------------------------------------------------ look-ups by name
    def geom_id(self, name: str) -> int:
        return int(self.model.geom(name).id)

    def geom_mask(self, names: list[str]) -> NDArray[np.bool_]:
        """Boolean mask over all geom ids, true for the named geoms (contact tests index it directly)."""
        mask = np.zeros(self.model.ngeom, dtype=bool)
        mask[[self.geom_id(n) for n in names]] = True
        return mask

    def site_pos(self, name: str) -> NDArray[np.float64]:
        return self.data.site(name).xpos

    def contact_pairs(self) -> NDArray[np.int32]:
        """Geom id pairs of the active contacts, shape ``(ncon, 2)`` (one vectorised read)."""
        return self.data.contact.geom[: self.data.ncon]

    @staticmethod
    def touching(pairs: NDArray[np.int32], mask_a: NDArray[np.bool_], mask_b: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """For each contact, whether it joins a geom of ``mask_a`` with a geom of ``mask_b``."""
        first, second = pairs[:, 0], pairs[:, 1]
        return (mask_a[first] & mask_b[second]) | (mask_a[second] & mask_b[first])

    @staticmethod
    def touching_geoms(pairs: NDArray[np.int32], mask_a: NDArray[np.bool_], mask_b: NDArray[np.bool_]) -> int:
        """Number of distinct geoms of ``mask_a`` in contact with any geom of ``mask_b``."""
        hits = np.zeros(len(mask_a), dtype=bool)
        hits[pairs[ArmEnv.touching(pairs, mask_a, mask_b)].ravel()] = True
        return int((hits & mask_a).sum())

    # ------------------------------------------------------------------ stepping
    def _checked_action(self, action: Any) -> NDArray[np.float64]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape:
            raise ValueError(
                f"{type(self).__name__}.step expects an action of shape {self.action_space.shape}, got {action.shape}"
            )
        if not np.all(np.isfinite(action)):
            raise ValueError(f"{type(self).__name__}.step got a non-finite action: {action}")
        return np.clip(action, self.action_space.low, self.action_space.high)

    def _step_mujoco_simulation(self, ctrl: NDArray[np.float64], n_frames: int) -> None:
        # Gymnasium's version also runs mj_rnePostConstraint (cacc, cfrc_*), which nothing here reads.
        self.data.ctrl[:] = ctrl
        mujoco.mj_step(self.model, self.data, nstep=n_frames)

    def _simulate(self, action: NDArray[np.float64]) -> bool:
        """Run ``frame_skip`` physics steps; return whether the simulation became unstable.

        MuJoCo itself resets ``mjData`` and counts a warning when positions, velocities, accelerations
        or controls become non-finite or huge: one vectorised read of the warning counters tells.
        """
        warnings_before = int(self.data.warning.number[_INSTABILITY_WARNINGS].sum())
        self.do_simulation(action, self.frame_skip)
        warnings_after = int(self.data.warning.number[_INSTABILITY_WARNINGS].sum())
        return warnings_after > warnings_before or not np.isfinite(self.data.qvel).all()

    def step(self, action: Any) -> tuple[NDArray[np.float64], float, bool, bool, dict[str, Any]]:  # type: ignore[override]
        action = self._checked_action(action)
        unstable = self._simulate(action)
        if unstable:
            # Put the physics back into a valid state; the episode ends here.
            mujoco.mj_resetData(self.model, self.data)
            mujoco.mj_forward(self.model, self.data)
        observation = self._get_obs()
        reward, info = self._get_rew(action)
        terminated = self._is_terminal()
        info["is_success"] = bool(self._is_success())
        info["unstable"] = unstable
        if unstable or not np.isfinite(reward) or not np.all(np.isfinite(observation)):
            info["unstable"] = True
            reward = 0.0
            info = {k: (0.0 if k.startswith("reward_") else v) for k, v in info.items()}
            observation = np.nan_to_num(observation, nan=0.0, posinf=0.0, neginf=0.0)
            terminated = True
        if self.render_mode == "human":
            self.render()
        # truncation is left to the TimeLimit wrapper added by `gymnasium.make`
        return observation, float(reward), bool(terminated), False, info

    # ------------------------------------------------------------------ hooks
    def _get_obs(self) -> NDArray[np.float64]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _get_rew(self, action: NDArray[np.float64]) -> tuple[float, dict[str, Any]]:  # pragma: no cover - abstract
        raise NotImplementedError

    def _is_success(self) -> bool:  # pragma: no cover - abstract
        raise NotImplementedError

    def _is_terminal(self) -> bool:
        return False

    def _get_reset_info(self) -> dict[str, Any]:
        return {"is_success": bool(self._is_success()), "unstable": False}
