"""Reacher3D: the arm hanging from the ceiling reaches a target on the table (thesis section 5.2.2). Every registered
version is a preset."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import DEFAULT_CAMERA_CONFIG_3D, ArmEnv, ArmTask, SimArrays, Start, TaskOptions, near_bonus, norm
from grasp_envs.options import amount, integer, option, path

if TYPE_CHECKING:
    from grasp_envs.wall_reacher3d import WallReacher3DOptions

ARM_JOINTS = ("shoulder_y", "shoulder_z", "elbow_y", "elbow_z")
FLOOR_Z = -0.2
TARGET_HALF_SIZE = 0.012


@dataclass(frozen=True)
class Reacher3DOptions(TaskOptions):
    """Reacher3D's options (``Reacher3DEnv``'s Arguments), each checked when they are made."""

    xml_file: str = option("reacher3d.xml", path())
    frame_skip: int = option(2, integer(1))
    reward_dist_weight: float = option(1.0, amount())
    reward_control_weight: float = option(1.0, amount())
    reward_near_weight: float = option(0.5, amount())
    near_scale: float = option(0.05, amount(positive=True))
    reset_noise_scale: float = option(0.1, amount())
    success_distance: float = option(0.02, amount(positive=True))


class ReachingArmTask(ArmTask):
    """The 4-DoF arm hanging from the ceiling that reaches a target on the table, over ``n`` simulations: what
    Reacher3D and WallReacher3D share (actions, joint observation, palm-to-target distance, the distance and control
    reward terms, success, the start of the arm), each task adding its own reward and target."""

    options: Reacher3DOptions | WallReacher3DOptions

    def setup(self, model: Any, n: int) -> None:
        super().setup(model, n)
        self._palm = self.site_id("palm")

    def target_pos(self, sim: SimArrays) -> NDArray[np.float64]:
        return sim.mocap_pos[:, 0]

    def palm_to_target(self, sim: SimArrays) -> NDArray[np.float64]:
        return sim.site_xpos[:, self._palm] - self.target_pos(sim)

    def distance(self, sim: SimArrays) -> NDArray[np.float64]:
        return norm(self.palm_to_target(sim))

    def reacher_terms(self, sim: SimArrays, action: NDArray[np.float64]) -> dict[str, Any]:
        distance = self.distance(sim)
        return {
            "reward_dist": -self.options.reward_dist_weight * distance,
            "reward_ctrl": -self.options.reward_control_weight * np.square(action).sum(axis=1),
            "distance": distance,
        }

    def success(self, sim: SimArrays) -> NDArray[np.bool_]:
        return self.distance(sim) < self.options.success_distance

    def observe(self, sim: SimArrays) -> NDArray[np.float64]:
        angles = sim.qpos[:, :4]
        parts = [np.cos(angles), np.sin(angles), sim.qvel[:, :4], self.target_pos(sim), self.palm_to_target(sim)]
        return np.concatenate(parts, axis=1)

    def sample_target(self, rng: np.random.Generator) -> NDArray[np.float64]:
        radius = 0.1 * np.sqrt(rng.uniform())
        angle = rng.uniform(-np.pi, np.pi)
        return np.array([radius * np.cos(angle), radius * np.sin(angle), FLOOR_Z + TARGET_HALF_SIZE])

    def initial_qpos(self, rng: np.random.Generator) -> NDArray[np.float64]:
        noise = self.options.reset_noise_scale
        return self.init_qpos + rng.uniform(-noise, noise, size=self.model.nq)

    def sample_start(self, rng: np.random.Generator) -> Start:
        mocap_pos = self.default_mocap_pos.copy()
        mocap_pos[0] = self.sample_target(rng)
        qpos = self.initial_qpos(rng)
        qvel = self.init_qvel + rng.uniform(-0.005, 0.005, size=self.model.nv)
        return qpos, qvel, mocap_pos


class Reacher3DTask(ReachingArmTask):
    """Reacher3D's step logic over ``n`` simulations: the reaching arm with the precision bonus ``reward_near``."""

    options: Reacher3DOptions
    observation_dim = 18

    def reward(self, sim: SimArrays, action: NDArray[np.float64]) -> tuple[NDArray[np.float64], dict[str, Any]]:
        info = self.reacher_terms(sim, action)
        info["reward_near"] = near_bonus(info["distance"], self.options.reward_near_weight, self.options.near_scale)
        return info["reward_dist"] + info["reward_ctrl"] + info["reward_near"], info


class Reacher3DEnv(ArmEnv):
    r"""
    ## Description
    A 4-DoF arm hangs from the ceiling (shoulder at the origin, floor at z = -0.2 m): shoulder hinges about
    y and z, elbow hinges about y and z, all unlimited (thesis Table 5.1). Upper arm and forearm are
    capsules of 0.1 m; the palm sits 0.11 m along the forearm. The palm must reach a 24 mm target cube
    lying on the table.

    ## Action Space
    `Box(-0.5, 0.5, (4,), float32)`: torques (gear 200) on `shoulder_y`, `shoulder_z`, `elbow_y`, `elbow_z`.

    ## Observation Space
    `Box(-inf, inf, (18,), float64)`:

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

    ## Rewards
    `reward = reward_dist + reward_ctrl + reward_near`, computed after the physics step (thesis eq. 5.1 and a bonus):

    - `reward_dist` $= -w_{dist} \lVert p_{palm} - p_{target} \rVert$, `reward_dist_weight` (default 1)
    - `reward_ctrl` $= -w_{ctrl} \lVert a \rVert^2$, `reward_control_weight` (default 1)
    - `reward_near` $= w_{near} (1 - \tanh(d / \sigma))$ with $d$ the palm-target distance,
      `reward_near_weight` (default 0.5; 0 in v0) and $\sigma$ = `near_scale` (default 0.05 m): bounded in
      $[0, w_{near}]$ and steepest at the target, so that the last centimetres pay

    `info` holds the terms, `distance`, `is_success` (palm-target distance below `success_distance`,
    0.02 m) and `unstable`.

    ## Starting State
    Arm horizontal along +x with joint noise $\mathcal{U}(-s, s)$, $s$ = `reset_noise_scale` (0.1 rad),
    velocities $\mathcal{U}(-0.005, 0.005)$. The target lies on the floor, uniform in the disc of radius
    0.1 m under the shoulder.

    ## Episode End
    No termination (except `info["unstable"]`); truncation after 100 steps (`max_episode_steps`, as the thesis).

    ## Arguments
    Keywords only: the options (`Reacher3DOptions`, checked when the env is made: a bad value raises `ValueError`
    naming it, an unknown keyword `TypeError`) and Gymnasium's rendering arguments.

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `xml_file` | `"reacher3d.xml"` | MuJoCo model |
    | `frame_skip` | `2` | physics steps of 0.01 s per action (control period 0.02 s) |
    | `default_camera_config` | oblique view | camera of `render()` |
    | `reward_dist_weight` | `1.0` | weight of `reward_dist` |
    | `reward_control_weight` | `1.0` | weight of `reward_ctrl` |
    | `reward_near_weight` | `0.5` | weight of `reward_near` (0: the thesis' reward) |
    | `near_scale` | `0.05` | distance scale $\sigma$ of `reward_near` (m) |
    | `reset_noise_scale` | `0.1` | half-width of the initial joint-angle noise (rad) |
    | `success_distance` | `0.02` | palm-target distance counted as success (m) |
    | `**kwargs` | | passed on to Gymnasium's `MujocoEnv`: `render_mode`, `width`, `height`, `camera_id`, ... |

    ## Version History
    Each id is a preset of the options above (`grasp_envs.registration.PRESETS`).

    * v1: `reward_near_weight=0.5` (the default). Every TRPO variant, and PPO, ends 1M steps at 0.97-1.00 success
      (5 seeds, docs/results.md).
    * v0: `reward_near_weight=0`, the thesis' reward. First release. Differs from the thesis: angles observed as
      cos/sin (unlimited hinges), reward after the physics step, target drawn in a disc of radius 0.1 m instead of
      the ±0.1 m square (the square's corners are 0.235 m from the shoulder, beyond the palm's 0.21 m reach), target
      is a mocap body.
    """

    options_class = Reacher3DOptions
    task_class = Reacher3DTask
    default_camera = DEFAULT_CAMERA_CONFIG_3D
    task: Reacher3DTask

    def distance(self) -> float:
        return float(self.task.distance(self.sim)[0])
