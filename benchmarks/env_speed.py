"""env.step time against raw mj_step time for the same frame_skip, for every grasp_envs task.

    python -m benchmarks.env_speed [--steps 20000] [--repeats 5] [--envs Grasper3D-v2 ...]

Prints a Markdown table (median of repeats) for docs/environments.md.
"""

from __future__ import annotations

import argparse
import platform
import time
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

import grasp_envs
from benchmarks.machine import cpu_name


def time_env_step(env_id: str, steps: int) -> float:
    env = gym.make(env_id)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    space = env.action_space
    assert isinstance(space, gym.spaces.Box), f"{env_id}: Box actions expected, got {space}"
    actions = rng.uniform(space.low, space.high, size=(steps, *space.shape))
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return (time.perf_counter() - start) / steps


def time_mj_step(env_id: str, steps: int) -> float:
    unwrapped: Any = gym.make(env_id).unwrapped  # a MujocoEnv
    model, data, frame_skip = unwrapped.model, unwrapped.data, unwrapped.frame_skip
    unwrapped.reset(seed=0)
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange.T
    controls = rng.uniform(low, high, size=(steps, model.nu))
    start = time.perf_counter()
    for ctrl in controls:
        data.ctrl[:] = ctrl
        mujoco.mj_step(model, data, nstep=frame_skip)
    return (time.perf_counter() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--envs", nargs="+", default=list(grasp_envs.ENV_IDS), choices=grasp_envs.ENV_IDS)
    args = parser.parse_args()
    print(
        f"machine: {cpu_name()}, python {platform.python_version()}, mujoco {mujoco.__version__}, gymnasium {gym.__version__}"
    )
    print("\n| env | frame_skip | raw mj_step (µs / env step) | env.step (µs) | overhead ratio | env steps/s |")
    print("|---|---|---|---|---|---|")
    for env_id in args.envs:
        raw, full = [], []
        for _ in range(args.repeats):  # interleaved repeats
            raw.append(time_mj_step(env_id, args.steps))
            full.append(time_env_step(env_id, args.steps))
        r, f = float(np.median(raw)), float(np.median(full))
        unwrapped: Any = gym.make(env_id).unwrapped  # a MujocoEnv
        frame_skip = unwrapped.frame_skip
        print(f"| {env_id} | {frame_skip} | {r * 1e6:.1f} | {f * 1e6:.1f} | {f / r:.2f} | {1 / f:,.0f} |")


if __name__ == "__main__":
    main()
