"""Why does a Grasper run stop at the grasp? Probe a saved run of benchmarks/convergence.py.

    python benchmarks/grasper_probe.py --env Grasper3D-v4 --variant warm --seed 3 [--episodes 30]

Runs the saved policy (with its VecNormalize statistics) on seeded episodes (reset seed 30,000, not the
study's held-out 10,000) three ways: as it is, and with the vertical grip command replaced by a constant
(0.3, 0.6) from the first grasp until the cube is 7 cm up; every other action component stays the policy's.
Each way runs deterministically (the policy's mean) and stochastically (its exploration noise). Prints a
Markdown table of mean return and final success, and the deterministic policy's mean vertical command
while grasped. If forcing the lift pays more, even under the policy's own noise, then the lift is not too
risky for the policy's grip; the policy has simply not found it.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import grasp_envs  # noqa: F401
from sb3_trpo_plus import TRPOPlus

ROOT = Path(__file__).resolve().parents[1]
PROBE_SEED = 30_000
RELEASE_HEIGHT = 0.07  # m: the forced command stops once the cube is this high


def probe(
    model: TRPOPlus, env: VecNormalize, episodes: int, deterministic: bool, forced_up: float | None
) -> tuple[float, float, float]:
    """Mean return, final success and (deterministic, unforced) mean vertical action while grasped."""
    arm = env.venv.envs[0].unwrapped  # type: ignore[attr-defined]
    returns, successes, vertical = [], [], []
    for episode in range(episodes):
        env.seed(PROBE_SEED + episode)
        obs: Any = env.reset()
        total, grasped_once, done = 0.0, False, np.array([False])
        while not done[0]:  # the TimeLimit ends it (the VecEnv then resets; infos[0] is the last step's)
            action, _ = model.predict(obs, deterministic=deterministic)
            grasped = arm._is_grasped(arm._contacts)
            grasped_once = grasped_once or grasped
            if grasped:
                vertical.append(float(np.clip(action[0, 2], -1.0, 1.0)))
            if forced_up is not None and grasped_once and arm.cube_height() < RELEASE_HEIGHT:
                action = action.copy()
                action[0, 2] = forced_up
            obs, reward, done, infos = env.step(action)
            total += float(reward[0])
        returns.append(total)
        successes.append(float(infos[0].get("is_success", False)))
    return float(np.mean(returns)), float(np.mean(successes)), float(np.mean(vertical)) if vertical else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Grasper3D-v4")
    parser.add_argument("--variant", default="warm")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=30)
    args = parser.parse_args()
    folder = ROOT / "benchmarks" / "results" / "convergence" / args.env / args.variant / f"seed{args.seed}"
    if not (folder / "model.zip").exists():
        raise SystemExit(f"{folder}: no model.zip (run benchmarks/convergence.py first; checkpoints are not committed)")
    env = VecNormalize.load(str(folder / "vecnormalize.pkl"), DummyVecEnv([lambda: gym.make(args.env)]))
    env.training, env.norm_reward = False, False
    model = TRPOPlus.load(folder / "model.zip", device="cpu")
    print(f"{args.env} {args.variant} seed {args.seed}, {args.episodes} episodes from reset seed {PROBE_SEED}\n")
    print("| policy | vertical command after the grasp | return | final success |")
    print("|---|---|---|---|")
    for deterministic in (True, False):
        for forced_up in (None, 0.3, 0.6):
            mean_return, success, vertical = probe(model, env, args.episodes, deterministic, forced_up)
            label = "deterministic" if deterministic else "stochastic"
            command = f"policy's (mean {vertical:+.2f})" if forced_up is None else f"{forced_up} until 7 cm"
            print(f"| {label} | {command} | {mean_return:.0f} | {success:.2f} |")


if __name__ == "__main__":
    main()
