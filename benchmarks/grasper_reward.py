"""Does the Grasper3D-v0 default reward avoid the thesis reward's collapse? Long runs, resumable.

    python -m benchmarks.grasper_reward --algo trpo --reward-mode staged --seed 0 --steps 3000000 [--chunk 250000]
    python -m benchmarks.grasper_reward --env Grasper3D-v1 --algo trpo_plus --env-kwargs '{"reward_grasp_weight": 8}' \
        --model-kwargs '{"cg_warm_start": true}' --tag g8 --seed 0

Trains the Grasper's anchor setting (sb3-contrib TRPO or TRPOPlus, 8 envs, VecNormalize, 100-100 tanh
MLP, gamma 0.995, target_kl 0.01) in chunks; after each chunk it saves the model and VecNormalize
statistics and appends the chunk's training-episode statistics (lift rate = episodes whose final step
was a success, mean return) to benchmarks/results/grasper_reward/<run>.json (<run>: algo, reward mode,
--tag and seed, prefixed by the env id for versions other than v0). Rerunning continues from the
last chunk, so a run stopped midway loses at most one chunk.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from sb3_contrib import TRPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize
from torch import nn

import grasp_envs  # noqa: F401
from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.application.callbacks import EpisodeStats

ALGOS: dict[str, type[TRPO]] = {"trpo": TRPO, "trpo_plus": TRPOPlus}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=list(ALGOS), default="trpo")
    parser.add_argument("--env", default="Grasper3D-v0", choices=[f"Grasper3D-v{version}" for version in range(5)])
    parser.add_argument("--reward-mode", choices=["staged", "thesis"], default="staged")
    parser.add_argument("--env-kwargs", type=json.loads, default={}, help="JSON dict of further env kwargs")
    parser.add_argument("--model-kwargs", type=json.loads, default={}, help="JSON dict of further algorithm kwargs")
    parser.add_argument("--tag", default="", help="names the run when --env-kwargs/--model-kwargs are given")
    parser.add_argument(
        "--init-from", default=None, help="start from the policy in a `python -m benchmarks.convergence job` folder"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=3_000_000)
    parser.add_argument("--chunk", type=int, default=250_000)
    parser.add_argument("--out", default="benchmarks/results/grasper_reward")
    parser.add_argument("--plot", default=None, help="only plot every run under --out (recursively) to this PNG")
    parser.add_argument("--diagnose", action="store_true", help="only describe what the saved policy does")
    args = parser.parse_args()
    if args.plot:
        plot(Path(args.out), Path(args.plot))
        return
    th.set_num_threads(1)
    if (args.env_kwargs or args.model_kwargs or args.init_from) and not args.tag:
        parser.error("--env-kwargs, --model-kwargs and --init-from need a --tag that names the run")
    prefix = "" if args.env == "Grasper3D-v0" else f"{args.env}_"
    name = f"{prefix}{args.algo}_{args.reward_mode}{'_' + args.tag if args.tag else ''}_seed{args.seed}"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log_path, model_path, stats_path = out / f"{name}.json", out / f"{name}_model.zip", out / f"{name}_vecnormalize.pkl"
    log: dict[str, Any] = json.loads(log_path.read_text()) if log_path.exists() else {"settings": vars(args), "chunks": []}
    if args.diagnose:
        diagnose(
            ALGOS[args.algo], model_path, stats_path, {"reward_mode": args.reward_mode, **args.env_kwargs}, env_id=args.env
        )
        return
    env_kwargs = {"reward_mode": args.reward_mode, **args.env_kwargs}
    monitor = {"info_keywords": ("is_success",)}
    venv = make_vec_env(
        args.env, n_envs=8, seed=args.seed + 1000 * len(log["chunks"]), env_kwargs=env_kwargs, monitor_kwargs=monitor
    )
    algo = ALGOS[args.algo]
    if model_path.exists() and stats_path.exists():
        env = VecNormalize.load(str(stats_path), venv)
        model = algo.load(model_path, env=env)
    elif args.init_from:  # continue a `python -m benchmarks.convergence job`'s policy (its model.zip, vecnormalize.pkl)
        env = VecNormalize.load(str(Path(args.init_from) / "vecnormalize.pkl"), venv)
        model = algo.load(Path(args.init_from) / "model.zip", env=env)
        model.num_timesteps = 0
    else:
        env = VecNormalize(venv, gamma=0.995)
        policy_kwargs = dict(net_arch=[100, 100], activation_fn=nn.Tanh)
        model = algo(
            "MlpPolicy",
            env,
            n_steps=1024,
            batch_size=1024,
            gamma=0.995,
            gae_lambda=0.97,
            target_kl=0.01,
            cg_max_steps=10,
            seed=args.seed,
            policy_kwargs=policy_kwargs,
            **args.model_kwargs,
        )
    while model.num_timesteps < args.steps:
        stats = EpisodeStats()
        start = time.time()
        model.learn(args.chunk, callback=stats, reset_num_timesteps=False)
        model.save(model_path)
        env.save(str(stats_path))
        returns = [e[0] for e in stats.episodes]
        lifts = [e[1] for e in stats.episodes]
        log["chunks"].append(
            {
                "timesteps": int(model.num_timesteps),
                "episodes": len(stats.episodes),
                "lift_rate": float(np.mean(lifts)) if lifts else 0.0,
                "mean_return": float(np.mean(returns)) if returns else float("nan"),
                "mean_length": float(np.mean([e[2] for e in stats.episodes])) if stats.episodes else 0.0,
                "seconds": time.time() - start,
            }
        )
        log_path.write_text(json.dumps(log, indent=1))
        print(json.dumps(log["chunks"][-1]), flush=True)


def diagnose(
    algo: type[TRPO],
    model_path: Path,
    stats_path: Path,
    env_kwargs: dict[str, Any],
    episodes: int = 10,
    env_id: str = "Grasper3D-v0",
) -> None:
    """Deterministic episodes of the saved policy: where the grip is, how the claw is held, what it touches."""
    venv = make_vec_env(env_id, n_envs=1, seed=123, env_kwargs=env_kwargs)
    env = VecNormalize.load(str(stats_path), venv)
    env.training, env.norm_reward = False, False
    model = algo.load(model_path, env=env)
    assert isinstance(venv, DummyVecEnv)  # make_vec_env's default
    arm: Any = venv.envs[0].unwrapped
    rows: dict[str, list[float]] = {
        "grip-cube distance (m)": [],
        "right half touches": [],
        "left half touches": [],
        "claw angle (rad)": [],
        "claw action": [],
        "forearm axis z": [],
        "cube height (m)": [],
        "cube between the halves": [],
    }
    for _ in range(episodes):
        obs: Any = env.reset()
        for _ in range(100):
            action, _ = model.predict(obs, deterministic=True)
            obs, _, done, _ = env.step(action)
            contacts = arm.claw_cube_contacts()
            rows["grip-cube distance (m)"].append(float(np.linalg.norm(arm.site_pos("grip") - arm.cube_pos())))
            rows["right half touches"].append(float(contacts["right"] > 0))
            rows["left half touches"].append(float(contacts["left"] > 0))
            rows["claw angle (rad)"].append(float(arm.data.qpos[arm.model.joint("claw_right").qposadr[0]]))
            rows["claw action"].append(float(np.clip(action[0, -1], -1.0, 1.0)))
            rows["cube between the halves"].append(float(getattr(arm, "cube_between_claws", lambda: False)()))
            rows["forearm axis z"].append(float(arm.data.body("forearm").xmat[6]))
            rows["cube height (m)"].append(arm.cube_height())
            if done[0]:
                break
    for name, values in rows.items():
        print(f"{name:>24}: mean {np.mean(values):.3f}")


def plot(folder: Path, output: Path) -> None:
    """Lift rate and mean return of the training episodes against timesteps, one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (lift_ax, return_ax) = plt.subplots(1, 2, figsize=(11, 4))
    for path in sorted(folder.rglob("*.json")):
        chunks = json.loads(path.read_text())["chunks"]
        label = str(path.relative_to(folder).with_suffix(""))
        steps = [c["timesteps"] for c in chunks]
        lift_ax.plot(steps, [c["lift_rate"] for c in chunks], marker=".", label=label)
        return_ax.plot(steps, [c["mean_return"] for c in chunks], marker=".", label=label)
    lift_ax.set_ylabel("lift rate (training episodes)")
    lift_ax.set_ylim(-0.02, 1.02)
    return_ax.set_ylabel("mean training return")
    for ax in (lift_ax, return_ax):
        ax.set_xlabel("timesteps")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Grasper3D, anchor setting (8 envs, VecNormalize, 100-100 tanh, gamma 0.995)")
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
