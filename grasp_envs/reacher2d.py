"""Reacher2D: the thesis' planar two-link reacher (section 5.2.1, Figure 6.1). Every registered version is a preset."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import ArmEnv, ArmTask, SimArrays, Start, TaskOptions, near_bonus, norm
from grasp_envs.options import amount, integer, option, path

DEFAULT_CAMERA_CONFIG: dict[str, Any] = {"trackbodyid": 0, "distance": 0.9, "elevation": -90.0}


@dataclass(frozen=True)
class Reacher2DOptions(TaskOptions):
    """Reacher2D's options (``Reacher2DEnv``'s Arguments), each checked when they are made."""

    xml_file: str = option("reacher2d.xml", path())
    frame_skip: int = option(2, integer(1))
    reward_dist_weight: float = option(1.0, amount())
    reward_control_weight: float = option(1.0, amount())
    reward_near_weight: float = option(0.5, amount())
    near_scale: float = option(0.05, amount(positive=True))
    reset_noise_scale: float = option(0.1, amount())
    success_distance: float = option(0.02, amount(positive=True))


class Reacher2DTask(ArmTask):
    """Reacher2D's step logic over ``n`` simulations."""

    options: Reacher2DOptions
    observation_dim = 10

    def setup(self, model: Any, n: int) -> None:
        super().setup(model, n)
        self._fingertip = self.site_id("fingertip")

    def fingertip_to_target(self, sim: SimArrays) -> NDArray[np.float64]:
        return sim.site_xpos[:, self._fingertip] - sim.mocap_pos[:, 0]

    def distance(self, sim: SimArrays) -> NDArray[np.float64]:
        return norm(self.fingertip_to_target(sim))

    def reward(self, sim: SimArrays, action: NDArray[np.float64]) -> tuple[NDArray[np.float64], dict[str, Any]]:
        options = self.options
        distance = self.distance(sim)
        reward_dist = -options.reward_dist_weight * distance
        reward_ctrl = -options.reward_control_weight * np.square(action).sum(axis=1)
        reward_near = near_bonus(distance, options.reward_near_weight, options.near_scale)
        info = {"reward_dist": reward_dist, "reward_ctrl": reward_ctrl, "distance": distance, "reward_near": reward_near}
        return reward_dist + reward_ctrl + reward_near, info

    def success(self, sim: SimArrays) -> NDArray[np.bool_]:
        return self.distance(sim) < self.options.success_distance

    def observe(self, sim: SimArrays) -> NDArray[np.float64]:
        theta = sim.qpos[:, :2]
        parts = [np.cos(theta), np.sin(theta), sim.mocap_pos[:, 0, :2], sim.qvel[:, :2], self.fingertip_to_target(sim)[:, :2]]
        return np.concatenate(parts, axis=1)

    def sample_start(self, rng: np.random.Generator) -> Start:
        noise = self.options.reset_noise_scale
        qpos = self.init_qpos + rng.uniform(-noise, noise, size=self.model.nq)
        qvel = self.init_qvel + rng.uniform(-0.005, 0.005, size=self.model.nv)
        while True:
            goal = rng.uniform(-0.2, 0.2, size=2)
            if np.linalg.norm(goal) < 0.2:
                break
        mocap_pos = self.default_mocap_pos.copy()
        mocap_pos[0, :2] = goal
        return qpos, qvel, mocap_pos


class Reacher2DEnv(ArmEnv):
    r"""
    ## Description
    A two-link planar arm (links of 0.1 m, thesis Figure 6.1, Gym's classic reacher) moves its fingertip
    to a target drawn in a disc of radius 0.2 m around the shoulder.

    ## Action Space
    `Box(-1, 1, (2,), float32)`: torques (gear 200) on the shoulder hinge `joint0` and the elbow hinge `joint1`.

    ## Observation Space
    `Box(-inf, inf, (10,), float64)`:

    | Num | Observation | Unit |
    |-----|-------------|------|
    | 0 | cos of `joint0` | unitless |
    | 1 | cos of `joint1` | unitless |
    | 2 | sin of `joint0` | unitless |
    | 3 | sin of `joint1` | unitless |
    | 4 | target x | m |
    | 5 | target y | m |
    | 6 | angular velocity of `joint0` | rad/s |
    | 7 | angular velocity of `joint1` | rad/s |
    | 8 | fingertip x - target x | m |
    | 9 | fingertip y - target y | m |

    ## Rewards
    `reward = reward_dist + reward_ctrl + reward_near`, computed after the physics step:

    - `reward_dist` $= -w_{dist} \lVert p_{fingertip} - p_{target} \rVert$, `reward_dist_weight` (default 1)
    - `reward_ctrl` $= -w_{ctrl} \lVert a \rVert^2$, `reward_control_weight` (default 1, as the thesis)
    - `reward_near` $= w_{near} (1 - \tanh(d / \sigma))$ with $d$ the fingertip-target distance,
      `reward_near_weight` (default 0.5; 0 in v0) and $\sigma$ = `near_scale` (default 0.05 m): bounded in
      $[0, w_{near}]$ and steepest at the target, so that the last centimetres pay (with the thesis' reward alone they
      pay 0.01 per step, lost in the return's noise, and policies stop 2-5 cm short of the 2 cm success radius)

    `info` holds both terms, `distance`, `is_success` (distance below `success_distance`, 0.02 m) and `unstable`.

    ## Starting State
    Joint angles $\mathcal{U}(-s, s)$ around zero with $s$ = `reset_noise_scale` (0.1), velocities
    $\mathcal{U}(-0.005, 0.005)$, target uniform in the disc of radius 0.2 m (every target is reachable: the
    fingertip reaches 0.21 m).

    ## Episode End
    No termination (except `info["unstable"]`); truncation after 50 steps (`max_episode_steps`).

    ## Arguments
    Keywords only: the options (`Reacher2DOptions`, checked when the env is made: a bad value raises `ValueError`
    naming it, an unknown keyword `TypeError`) and Gymnasium's rendering arguments.

    | Parameter | Default | Description |
    |-----------|---------|-------------|
    | `xml_file` | `"reacher2d.xml"` | MuJoCo model (bare names are looked up in `grasp_envs/assets`) |
    | `frame_skip` | `2` | physics steps of 0.01 s per action |
    | `default_camera_config` | top view | camera of `render()` |
    | `reward_dist_weight` | `1.0` | weight of `reward_dist` |
    | `reward_control_weight` | `1.0` | weight of `reward_ctrl` |
    | `reward_near_weight` | `0.5` | weight of `reward_near` (0: the thesis' reward) |
    | `near_scale` | `0.05` | distance scale $\sigma$ of `reward_near` (m) |
    | `reset_noise_scale` | `0.1` | half-width of the initial joint-angle noise (rad) |
    | `success_distance` | `0.02` | fingertip-target distance counted as success (m) |
    | `**kwargs` | | passed on to Gymnasium's `MujocoEnv`: `render_mode`, `width`, `height`, `camera_id`, ... |

    ## Version History
    Each id is a preset of the options above (`grasp_envs.registration.PRESETS`).

    * v1: `reward_near_weight=0.5` (the default). Final success (fingertip within 2 cm at the last step, 5 seeds,
      300k steps) 0.25-0.40 with v0's reward, 0.63-0.89 with the bonus (docs/results.md).
    * v0: `reward_near_weight=0`, the thesis' reward. First release. Differs from the thesis' Gym reacher: the reward
      is computed after the physics step (Gym's v2 bug fixed), the target is a mocap body (no slide joints in the
      state), success is reported.
    """

    options_class = Reacher2DOptions
    task_class = Reacher2DTask
    default_camera = DEFAULT_CAMERA_CONFIG
    task: Reacher2DTask

    def distance(self) -> float:
        return float(self.task.distance(self.sim)[0])
