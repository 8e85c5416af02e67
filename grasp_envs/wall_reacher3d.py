"""WallReacher3D: reach a target behind a wall without touching it (thesis section 5.2.4)."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import utils
from numpy.typing import NDArray

from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D
from grasp_envs.reacher3d import FLOOR_Z, TARGET_HALF_SIZE, Reacher3DEnv

WALL_CAMERA_CONFIG: dict[str, Any] = {**DEFAULT_CAMERA_CONFIG_3D, "azimuth": 90.0, "elevation": -60.0}
ARM_GEOMS = ["upper_arm", "forearm"]


class WallReacher3DEnv(Reacher3DEnv):
    r"""
    ## Description
    Reacher3D with a wall (box of half-size 0.01 x 0.2 x 0.05 m, top at z = -0.1 m) standing on the floor
    across the table at x = 0. The target lies on one side; the arm starts pointing to the other side and
    must reach over the wall without touching it.

    ## Action Space
    `Box(-0.5, 0.5, (4,), float32)`: torques (gear 200) on `shoulder_y`, `shoulder_z`, `elbow_y`, `elbow_z`.

    ## Observation Space
    `Box(-inf, inf, (21,), float64)`:

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 0 | cos of `shoulder_y` | unitless |
    | 1 | cos of `shoulder_z` | unitless |
    | 2 | cos of `elbow_y` | unitless |
    | 3 | cos of `elbow_z` | unitless |
    | 4 | sin of `shoulder_y` | unitless |
    | 5 | sin of `shoulder_z` | unitless |
    | 6 | sin of `elbow_y` | unitless |
    | 7 | sin of `elbow_z` | unitless |
    | 8 | angular velocity of `shoulder_y` | rad/s |
    | 9 | angular velocity of `shoulder_z` | rad/s |
    | 10 | angular velocity of `elbow_y` | rad/s |
    | 11 | angular velocity of `elbow_z` | rad/s |
    | 12 | target x | m |
    | 13 | target y | m |
    | 14 | target z | m |
    | 15 | palm x - target x | m |
    | 16 | palm y - target y | m |
    | 17 | palm z - target z | m |
    | 18 | target on the -x side (one-hot) | unitless |
    | 19 | target on the +x side (one-hot) | unitless |
    | 20 | arm has touched the wall in this episode | unitless |

    ## Rewards
    `reward = reward_dist + reward_ctrl + reward_wall + reward_proximity`, computed after the physics step:

    - `reward_dist` $= -w_{dist} \lVert p_{palm} - p_{target} \rVert$, `reward_dist_weight` (default 1)
    - `reward_ctrl` $= -w_{ctrl} \lVert a \rVert^2$, `reward_control_weight` (default 1)
    - `reward_wall` $= -w_{wall} \cdot$ (number of arm-wall contacts), `reward_wall_weight` (default 1)
    - `reward_proximity` $= -w_{prox} \cdot [\lVert p_{palm} - p_{target} \rVert > d(p_{palm}, \text{wall})]$,
      `reward_proximity_weight` (default 1): the palm is closer to the wall than to the target

    `info` holds the terms, `distance`, `wall_contacts`, `is_success` (palm within `success_distance`,
    0.02 m, of the target and no wall contact so far in the episode) and `unstable`.

    ## Starting State
    The target lies on the floor in the disc of radius 0.1 m, at least 0.03 m from the wall's plane, on a
    random side. The arm starts horizontal, pointing to the other side (shoulder yaw 0 or pi), with joint
    noise $\mathcal{U}(-s, s)$, $s$ = `reset_noise_scale` (0.1 rad).

    ## Episode End
    No termination (except `info["unstable"]`); truncation after 100 steps (`max_episode_steps`).

    ## Arguments
    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `xml_file` | `"wall_reacher3d.xml"` | MuJoCo model |
    | `frame_skip` | `2` | physics steps of 0.01 s per action |
    | `default_camera_config` | oblique view showing the wall | camera of `render()` |
    | `reward_dist_weight` | `1.0` | weight of `reward_dist` |
    | `reward_control_weight` | `1.0` | weight of `reward_ctrl` |
    | `reward_wall_weight` | `1.0` | weight of `reward_wall` |
    | `reward_proximity_weight` | `1.0` | weight of `reward_proximity` |
    | `reset_noise_scale` | `0.1` | half-width of the initial joint-angle noise (rad) |
    | `success_distance` | `0.02` | palm-target distance counted as success (m) |

    ## Version History
    * v0: first release. Differs from the thesis: arm-wall contacts are found by geom name (the original
      used hard-coded ids that pointed at another geom, so its wall penalty was always zero); the wall is
      0.1 m high instead of 0.2 m (a 0.2 m wall reaches the shoulder, so the arm's root always touched it);
      reward after the physics step; cos/sin angles; side one-hot and a wall-touched flag observed.
    """

    _observation_dim = 21

    def __init__(
        self,
        xml_file: str = "wall_reacher3d.xml",
        frame_skip: int = 2,
        default_camera_config: dict[str, Any] = WALL_CAMERA_CONFIG,
        reward_dist_weight: float = 1.0,
        reward_control_weight: float = 1.0,
        reward_wall_weight: float = 1.0,
        reward_proximity_weight: float = 1.0,
        reset_noise_scale: float = 0.1,
        success_distance: float = 0.02,
        **kwargs: Any,
    ):
        utils.EzPickle.__init__(
            self, xml_file=xml_file, frame_skip=frame_skip, default_camera_config=default_camera_config,
            reward_dist_weight=reward_dist_weight, reward_control_weight=reward_control_weight,
            reward_wall_weight=reward_wall_weight, reward_proximity_weight=reward_proximity_weight,
            reset_noise_scale=reset_noise_scale, success_distance=success_distance, **kwargs,
        )  # fmt: skip
        self._init_reacher(reward_dist_weight, reward_control_weight, reset_noise_scale, success_distance)
        self._reward_wall_weight = reward_wall_weight
        self._reward_proximity_weight = reward_proximity_weight
        self._wall_touched = False
        self._target_side = 1
        super(Reacher3DEnv, self).__init__(
            xml_file, frame_skip, default_camera_config, observation_dim=self._observation_dim, **kwargs
        )
        self._wall_geom = self.geom_mask(["wall"])
        self._arm_geoms = self.geom_mask(ARM_GEOMS)

    def wall_contacts(self) -> int:
        return int(self.touching(self.contact_pairs(), self._arm_geoms, self._wall_geom).sum())

    def palm_to_wall_distance(self) -> float:
        """Euclidean distance from the palm to the wall box (0 inside)."""
        wall = self.data.geom("wall")
        offset = np.abs(self.site_pos("palm") - wall.xpos) - self.model.geom("wall").size
        return float(np.linalg.norm(np.maximum(offset, 0.0)))

    def _get_rew(self, action: NDArray[np.float64]) -> tuple[float, dict[str, Any]]:
        info: dict[str, Any] = self._reacher_terms(action)
        contacts = self.wall_contacts()
        self._wall_touched = self._wall_touched or contacts > 0
        info["wall_contacts"] = contacts
        info["reward_wall"] = -self._reward_wall_weight * contacts
        info["reward_proximity"] = -self._reward_proximity_weight * float(info["distance"] > self.palm_to_wall_distance())
        reward = info["reward_dist"] + info["reward_ctrl"] + info["reward_wall"] + info["reward_proximity"]
        return reward, info

    def _is_success(self) -> bool:
        return self.distance() < self._success_distance and not self._wall_touched

    def _get_obs(self) -> NDArray[np.float64]:
        side = np.array([self._target_side < 0, self._target_side > 0], dtype=np.float64)
        return np.concatenate([super()._get_obs(), side, [float(self._wall_touched)]])

    def _sample_target(self) -> NDArray[np.float64]:
        while True:
            xy = self.np_random.uniform(-0.1, 0.1, size=2)
            if np.linalg.norm(xy) <= 0.1 and abs(xy[0]) >= 0.03:
                return np.array([xy[0], xy[1], FLOOR_Z + TARGET_HALF_SIZE])

    def reset_model(self) -> NDArray[np.float64]:
        target = self._sample_target()
        self._target_side = 1 if target[0] > 0 else -1
        self._wall_touched = False
        self.data.mocap_pos[0] = target
        qpos = self._initial_qpos()
        qpos[1] += np.pi if self._target_side > 0 else 0.0  # shoulder yaw: point away from the target
        qvel = self.init_qvel + self.np_random.uniform(-0.005, 0.005, size=self.model.nv)
        self.set_state(qpos, qvel)
        self._wall_touched = self.wall_contacts() > 0
        return self._get_obs()
