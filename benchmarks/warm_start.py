"""Which CG warm start works better: the raw previous step or its exact line-minimiser rescaling?

For each variant and seed, trains TRPOPlus and records per update the CG residual reached after
`cg_max_steps` iterations, the cosine between warm start and solution, line-search success, and the
final evaluation return. Results are cached per run in benchmarks/results/warm_start/ (resumable).

    python -m benchmarks.warm_start --env Reacher2D-v0 --steps 100000 --seeds 0 1 2
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecNormalize
from torch import nn

from sb3_trpo_plus import TRPOPlus

VARIANTS: dict[str, dict[str, Any]] = {
    "zero_start": dict(cg_warm_start=False),
    "warm_raw": dict(cg_warm_start=True, cg_warm_start_rescale=False),
    "warm_rescaled": dict(cg_warm_start=True, cg_warm_start_rescale=True),
}
KEYS = ("train/cg_residual", "train/cg_warm_start_cosine", "train/is_line_search_success", "train/cg_iterations")


class RecordTrainLogs(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.rows: list[dict[str, float]] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        values = self.model.logger.name_to_value
        if "train/cg_residual" in values:
            self.rows.append({k: float(values[k]) for k in KEYS})


def run(env_id: str, variant: str, seed: int, steps: int, cg_max_steps: int) -> dict:
    th.set_num_threads(1)
    env = VecNormalize(make_vec_env(env_id, n_envs=8, seed=seed))
    model = TRPOPlus(
        "MlpPolicy",
        env,
        n_steps=256,
        batch_size=256,
        cg_max_steps=cg_max_steps,
        seed=seed,
        policy_kwargs=dict(net_arch=[100, 100], activation_fn=nn.Tanh),
        **VARIANTS[variant],
    )
    recorder = RecordTrainLogs()
    model.learn(steps, callback=recorder)
    env.training, env.norm_reward = False, False
    mean_return, _ = evaluate_policy(model, env, n_eval_episodes=20)
    assert isinstance(mean_return, float)  # the mean (a list only with return_episode_rewards)
    rows = recorder.rows[1:]  # the first update has no previous step
    return {
        "env": env_id,
        "variant": variant,
        "seed": seed,
        "steps": steps,
        "cg_max_steps": cg_max_steps,
        "eval_return": float(mean_return),
        **{f"mean_{k.split('/')[1]}": float(np.mean([r[k] for r in rows])) for k in KEYS},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Reacher2D-v0")
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--cg-max-steps", type=int, default=10)
    parser.add_argument("--out", default="benchmarks/results/warm_start")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for seed in args.seeds:
        for variant in VARIANTS:
            path = out / f"{args.env}_{variant}_s{seed}_{args.steps}_cg{args.cg_max_steps}.json"
            if path.exists():
                continue
            result = run(args.env, variant, seed, args.steps, args.cg_max_steps)
            path.write_text(json.dumps(result, indent=1))
            print(json.dumps(result), flush=True)
    rows = [json.loads(p.read_text()) for p in sorted(out.glob(f"{args.env}_*_{args.steps}_cg{args.cg_max_steps}.json"))]
    print("\n| variant | runs | eval return | CG residual | warm-start cosine | line-search success |")
    print("|---|---|---|---|---|---|")
    for variant in VARIANTS:
        group = [r for r in rows if r["variant"] == variant]
        if group:
            cells = [
                _stat(group, k)
                for k in ("eval_return", "mean_cg_residual", "mean_cg_warm_start_cosine", "mean_is_line_search_success")
            ]
            print(f"| {variant} | {len(group)} | " + " | ".join(cells) + " |")


def _stat(group: list[dict], key: str) -> str:
    values = [r[key] for r in group]
    return f"{np.mean(values):.4g} ± {np.std(values):.2g}"


if __name__ == "__main__":
    main()
