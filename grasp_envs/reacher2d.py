"""Reacher2D: the thesis' planar two-link reacher (section 5.2.1, Figure 6.1). Every registered version is a preset."""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import utils
from numpy.typing import NDArray

from grasp_envs.base import ArmEnv, ArmTask, SimArrays, check_amount, check_near_bonus, near_bonus, norm

DEFAULT_CAMERA_CONFIG: dict[str, Any] = {"trackbodyid": 0, "distance": 0.9, "elevation": -90.0}


class Reacher2DTask(ArmTask):
    """Reacher2D's step logic over ``n`` simulations (options: ``Reacher2DEnv``)."""

    def __init__(
        self,
        xml_file: str,
        frame_skip: int,
        reward_dist_weight: float,
        reward_control_weight: float,
        reward_near_weight: float,
        near_scale: float,
        reset_noise_scale: float,
        success_distance: float,
    ):
        check_near_bonus(reward_near_weight, near_scale)
        for name, value in (("reward_dist_weight", reward_dist_weight), ("reward_control_weight", reward_control_weight)):
            check_amount(name, value)
        check_amount("reset_noise_scale", reset_noise_scale)
        check_amount("success_distance", success_distance, "positive number")
        super().__init__(xml_file, frame_skip, observation_dim=10)
        self.reward_dist_weight = reward_dist_weight
        self.reward_control_weight = reward_control_weight
        self.reward_near_weight = reward_near_weight
        self.near_scale = near_scale
        self.reset_noise_scale = reset_noise_scale
        self.success_distance = success_distance

    def setup(self, model: Any, n: int) -> None:
        super().setup(model, n)
        self._fingertip = self.site_id("fingertip")

    def fingertip_to_target(self, sim: SimArrays) -> NDArray[np.float64]:
        return sim.site_xpos[:, self._fingertip] - sim.mocap_pos[:, 0]

    def distance(self, sim: SimArrays) -> NDArray[np.float64]:
        return norm(self.fingertip_to_target(sim))

    def reward(self, sim: SimArrays, action: NDArray[np.float64]) -> tuple[NDArray[np.float64], dict[str, Any]]:
        distance = self.distance(sim)
        reward_dist = -self.reward_dist_weight * distance
        reward_ctrl = -self.reward_control_weight * np.square(action).sum(axis=1)
        reward_near = near_bonus(distance, self.reward_near_weight, self.near_scale)
        info = {"reward_dist": reward_dist, "reward_ctrl": reward_ctrl, "distance": distance, "reward_near": reward_near}
        return reward_dist + reward_ctrl + reward_near, info

    def success(self, sim: SimArrays) -> NDArray[np.bool_]:
        return self.distance(sim) < self.success_distance

    def observe(self, sim: SimArrays) -> NDArray[np.float64]:
        theta = sim.qpos[:, :2]
        parts = [np.cos(theta), np.sin(theta), sim.mocap_pos[:, 0, :2], sim.qvel[:, :2], self.fingertip_to_target(sim)[:, :2]]
        return np.concatenate(parts, axis=1)

    def sample_start(self, rng: np.random.Generator) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        noise = self.reset_noise_scale
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

    ## Version History
    Each id is a preset of the options above (`grasp_envs.registration.PRESETS`).

    * v1: `reward_near_weight=0.5` (the default). Final success (fingertip within 2 cm at the last step, 5 seeds,
      300k steps) 0.25-0.40 with v0's reward, 0.63-0.89 with the bonus (docs/results.md).
    * v0: `reward_near_weight=0`, the thesis' reward. First release. Differs from the thesis' Gym reacher: the reward
      is computed after the physics step (Gym's v2 bug fixed), the target is a mocap body (no slide joints in the
      state), success is reported.
    """

    task: Reacher2DTask
    task_class = Reacher2DTask

    def __init__(
        self,
        xml_file: str = "reacher2d.xml",
        frame_skip: int = 2,
        default_camera_config: dict[str, Any] = DEFAULT_CAMERA_CONFIG,
        reward_dist_weight: float = 1.0,
        reward_control_weight: float = 1.0,
        reward_near_weight: float = 0.5,
        near_scale: float = 0.05,
        reset_noise_scale: float = 0.1,
        success_distance: float = 0.02,
        **kwargs: Any,
    ):
        task = Reacher2DTask(
            xml_file, frame_skip, reward_dist_weight, reward_control_weight, reward_near_weight, near_scale,
            reset_noise_scale, success_distance,
        )  # fmt: skip
        utils.EzPickle.__init__(
            self, xml_file=xml_file, frame_skip=frame_skip, default_camera_config=default_camera_config,
            reward_dist_weight=reward_dist_weight, reward_control_weight=reward_control_weight,
            reward_near_weight=reward_near_weight, near_scale=near_scale, reset_noise_scale=reset_noise_scale,
            success_distance=success_distance, **kwargs,
        )  # fmt: skip
        ArmEnv.__init__(self, task, default_camera_config, **kwargs)

    def distance(self) -> float:
        return float(self.task.distance(self.sim)[0])
