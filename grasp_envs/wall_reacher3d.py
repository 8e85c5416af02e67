"""WallReacher3D: reach a target behind a wall without touching it (thesis section 5.2.4)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D, ArmEnv, SimArrays, Start, TaskOptions, norm
from grasp_envs.options import amount, integer, option, path
from grasp_envs.reacher3d import FLOOR_Z, TARGET_HALF_SIZE, ReachingArmTask

WALL_CAMERA_CONFIG: dict[str, Any] = {**DEFAULT_CAMERA_CONFIG_3D, "azimuth": 90.0, "elevation": -60.0}
ARM_GEOMS = ["upper_arm", "forearm"]


@dataclass(frozen=True)
class WallReacher3DOptions(TaskOptions):
    """WallReacher3D's options (``WallReacher3DEnv``'s Arguments), each checked when they are made."""

    xml_file: str = option("wall_reacher3d.xml", path())
    frame_skip: int = option(2, integer(1))
    reward_dist_weight: float = option(1.0, amount())
    reward_control_weight: float = option(1.0, amount())
    reward_wall_weight: float = option(1.0, amount())
    reward_proximity_weight: float = option(1.0, amount())
    reset_noise_scale: float = option(0.1, amount())
    success_distance: float = option(0.02, amount(positive=True))


class WallReacher3DTask(ReachingArmTask):
    """WallReacher3D's step logic over ``n`` simulations.

    A task of its own (thesis 5.2.4), not a version of Reacher3D: it shares the 3D reacher's arm (actions, joint
    observation, palm-to-target distance) and its distance and control reward terms (``ReachingArmTask``), and adds
    the wall: its contact and proximity penalties, the target behind it, the success that needs no wall contact in
    the episode.
    """

    options: WallReacher3DOptions
    observation_dim = 21
    contact_pairs = tuple((geom, "wall") for geom in ARM_GEOMS)

    def setup(self, model: Any, n: int) -> None:
        super().setup(model, n)
        self._wall = self.geom_id("wall")
        self.wall_touched = np.zeros(n, dtype=bool)
        self.target_side = np.ones(n, dtype=np.int64)

    def wall_contacts(self, sim: SimArrays) -> NDArray[np.int64]:
        """Contacts between the arm's links and the wall, per simulation."""
        return self.contact_counts(sim).sum(axis=1).astype(np.int64)

    def palm_to_wall_distance(self, sim: SimArrays) -> NDArray[np.float64]:
        """Euclidean distance from the palm to the wall box (0 inside)."""
        offset = np.abs(sim.site_xpos[:, self._palm] - sim.geom_xpos[:, self._wall]) - self.model.geom_size[self._wall]
        return norm(np.maximum(offset, 0.0))

    def reward(self, sim: SimArrays, action: NDArray[np.float64]) -> tuple[NDArray[np.float64], dict[str, Any]]:
        info = self.reacher_terms(sim, action)
        contacts = self.wall_contacts(sim)
        self.wall_touched |= contacts > 0
        info["wall_contacts"] = contacts
        info["reward_wall"] = -self.options.reward_wall_weight * contacts
        proximity = info["distance"] > self.palm_to_wall_distance(sim)
        info["reward_proximity"] = -self.options.reward_proximity_weight * proximity
        reward = info["reward_dist"] + info["reward_ctrl"] + info["reward_wall"] + info["reward_proximity"]
        return reward, info

    def success(self, sim: SimArrays) -> NDArray[np.bool_]:
        return super().success(sim) & ~self.wall_touched

    def observe(self, sim: SimArrays) -> NDArray[np.float64]:
        side = np.stack([self.target_side < 0, self.target_side > 0], axis=1).astype(np.float64)
        return np.concatenate([super().observe(sim), side, self.wall_touched[:, None].astype(np.float64)], axis=1)

    def sample_target(self, rng: np.random.Generator) -> NDArray[np.float64]:
        while True:
            xy = rng.uniform(-0.1, 0.1, size=2)
            if np.linalg.norm(xy) <= 0.1 and abs(xy[0]) >= 0.03:
                return np.array([xy[0], xy[1], FLOOR_Z + TARGET_HALF_SIZE])

    def sample_start(self, rng: np.random.Generator) -> Start:
        mocap_pos = self.default_mocap_pos.copy()
        mocap_pos[0] = target = self.sample_target(rng)
        qpos = self.initial_qpos(rng)
        qpos[1] += np.pi if target[0] > 0 else 0.0  # shoulder yaw: point away from the target
        qvel = self.init_qvel + rng.uniform(-0.005, 0.005, size=self.model.nv)
        return qpos, qvel, mocap_pos

    def started(self, sim: SimArrays, ids: NDArray[np.int64]) -> None:
        self.target_side[ids] = np.where(sim.mocap_pos[ids, 0, 0] > 0, 1, -1)
        self.wall_touched[ids] = self.wall_contacts(sim)[ids] > 0


class WallReacher3DEnv(ArmEnv):
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
    Keywords only: the options (`WallReacher3DOptions`, checked when the env is made: a bad value raises `ValueError`
    naming it, an unknown keyword `TypeError`) and Gymnasium's rendering arguments.

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
    | `**kwargs` | | passed on to Gymnasium's `MujocoEnv`: `render_mode`, `width`, `height`, `camera_id`, ... |

    ## Version History
    * v0: first release. Differs from the thesis: arm-wall contacts are found by geom name (the original
      used hard-coded ids that pointed at another geom, so its wall penalty was always zero); the wall is
      0.1 m high instead of 0.2 m (a 0.2 m wall reaches the shoulder, so the arm's root always touched it);
      reward after the physics step; cos/sin angles; side one-hot and a wall-touched flag observed.
    """

    options_class = WallReacher3DOptions
    task_class = WallReacher3DTask
    default_camera = WALL_CAMERA_CONFIG
    task: WallReacher3DTask

    def distance(self) -> float:
        return float(self.task.distance(self.sim)[0])

    def wall_contacts(self) -> int:
        return int(self.task.wall_contacts(self.sim)[0])
