"""How far does one policy update move the policy? The true KL of each update of PPO and TRPOPlus.

    python -m benchmarks.update_kl --env Grasper3D-v4 --variants ppo_scripted25 warm_scripted25 --steps 300000

Each variant of the convergence study (benchmarks/study.yml: zoo settings plus the variant's
switches and training wrappers) is trained from seed 0 for ``--steps``; around every call of
``train()`` the script keeps the action distribution on the update's own batch before the update and
compares it with the one after: mean KL(new ‖ old) over the batch's states (the direction of TRPO's
trust region), and the mean policy std.
TRPO's logged ``train/kl_divergence_loss`` is this KL divided by the action dimension (SB3's KL of a
diagonal Gaussian is per action dimension, docs/algorithm.md), so ``target_kl`` 0.01 allows 0.01 * D per
state; PPO logs only ``approx_kl``, an estimate from the sampled actions averaged over all epochs. This
script measures both the same way, per state.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from benchmarks.builders import new_model
from benchmarks.study import VARIANTS

ROOT = Path(__file__).resolve().parents[1]


def policy_kl(p: th.distributions.Normal, q: th.distributions.Normal) -> float:
    """Mean over states of KL(p ‖ q) for diagonal Gaussians (summed over action dimensions)."""
    return float(th.distributions.kl_divergence(p, q).sum(-1).mean())


def measure(env_id: str, variant: str, steps: int, seed: int = 0) -> dict[str, Any]:
    """Train one variant for ``steps`` and return the KL and std of each policy update."""
    th.set_num_threads(1)
    algo = VARIANTS[variant].algo
    model = new_model(env_id, variant, seed)
    kls: list[float] = []
    stds: list[float] = []
    logged: list[float] = []  # the algorithm's own KL figure: TRPO's per-dimension KL, PPO's approx_kl
    logged_key = "train/approx_kl" if algo == "ppo" else "train/kl_divergence_loss"
    original_train = model.train

    def distribution(obs: th.Tensor) -> th.distributions.Normal:
        with th.no_grad():
            return model.policy.get_distribution(obs).distribution

    def train_and_measure() -> None:
        # a copy: the buffer's first get() reorders its arrays in place (env-major), so read the states once
        obs = th.as_tensor(model.rollout_buffer.observations.reshape(-1, *model.observation_space.shape).copy())
        before = distribution(obs)
        original_train()
        after = distribution(obs)
        kls.append(policy_kl(after, before))
        stds.append(float(after.stddev.mean()))
        logged.append(float(model.logger.name_to_value[logged_key]))

    model.train = train_and_measure
    model.learn(steps)
    model.get_env().close()
    return {
        "env": env_id,
        "variant": variant,
        "algo": algo,
        "steps": steps,
        "seed": seed,
        "kl": kls,
        "std": stds,
        "logged_kl": logged,
    }


def summary(result: dict[str, Any]) -> str:
    kl = np.asarray(result["kl"])
    third = max(len(kl) // 3, 1)
    return (
        f"| {result['variant']} | {len(kl)} | {np.median(kl[:third]):.4f} | {np.median(kl[-third:]):.4f} | "
        f"{kl.max():.4f} | {np.median(result['logged_kl']):.4f} | {result['std'][-1]:.3f} |"
    )


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="Grasper3D-v4")
    parser.add_argument("--variants", nargs="+", default=["ppo_scripted25", "warm_scripted25"])
    parser.add_argument("--steps", type=int, default=300_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "update_kl.json")
    args = parser.parse_args(argv)
    results = [measure(args.env, variant, args.steps, args.seed) for variant in args.variants]
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print(f"{args.env}, seed {args.seed}, {args.steps:,} steps; KL(new ‖ old) per state, each update on its batch")
    print(
        "| variant | updates | median KL, first third | median KL, last third | max KL | median logged KL | std at the end |"
    )
    print("|---|---|---|---|---|---|---|")
    for result in results:
        print(summary(result))


if __name__ == "__main__":
    main()
