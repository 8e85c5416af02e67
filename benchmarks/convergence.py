"""Sample efficiency: TRPOPlus variants, sb3-contrib TRPO and SB3 PPO with the zoo hyperparameters.

    python benchmarks/convergence.py --env Reacher2D-v0 --steps 300000 --seeds 0 1 2 [--jobs 2]

Each (algorithm, seed) is one `trpo-plus train` run in its own process under
benchmarks/results/convergence/<env>/ and is skipped when its model already exists (resumable). Then
plots mean ± std over seeds (`trpo-plus plot`) and prints final success rate / return of the last 10% of
training episodes from the monitor files.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from sb3_trpo_plus.plotting import run_curve

VARIANTS = {
    "trpo_plus": ("trpo_plus", []),  # zoo file: k = 3
    "trpo_plus_warm": ("trpo_plus", ["-params", "cg_warm_start:True"]),
    "trpo": ("trpo", []),
    "ppo": ("ppo", []),
}


def run(env_id: str, variant: str, seed: int, steps: int, root: Path) -> Path:
    algo, extra = VARIANTS[variant]
    folder = root / variant / f"seed{seed}"
    if (folder / algo / f"{env_id}_1" / f"{env_id}.zip").exists():
        return folder / algo / f"{env_id}_1"
    command = [sys.executable, "-m", "sb3_trpo_plus", "train", "--algo", algo, "--env", env_id, "-n", str(steps),
               "--seed", str(seed), "-f", str(folder), "--eval-freq", "-1", "--num-threads", "1", *extra]  # fmt: skip
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return folder / algo / f"{env_id}_1"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Reacher2D-v0")
    parser.add_argument("--steps", type=int, default=300_000)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS))
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--out", default="benchmarks/results/convergence")
    args = parser.parse_args()
    root = Path(args.out) / args.env
    jobs = [(v, s) for s in args.seeds for v in args.variants]
    with ThreadPoolExecutor(args.jobs) as pool:
        runs = list(pool.map(lambda job: (job[0], run(args.env, job[0], job[1], args.steps, root)), jobs))
    summary = {}
    for variant in args.variants:
        finals_r, finals_s = [], []
        for name, folder in runs:
            if name != variant:
                continue
            _, returns, success = run_curve(folder)
            tail = max(len(returns) // 10, 1)
            finals_r.append(float(np.mean(returns[-tail:])))
            finals_s.append(float(np.mean(success[-tail:])) if success is not None else float("nan"))
        summary[variant] = {"final_return": finals_r, "final_success": finals_s}
        print(f"{variant:>16}: return {np.mean(finals_r):8.2f} ± {np.std(finals_r):.2f}   "
              f"success {np.mean(finals_s):.2f} ± {np.std(finals_s):.2f}   ({len(finals_r)} seeds)")  # fmt: skip
    (root / "summary.json").write_text(json.dumps({"steps": args.steps, "seeds": args.seeds, **summary}, indent=1))
    labels = [f"{variant}={folder}" for variant, folder in runs]
    subprocess.run([sys.executable, "-m", "sb3_trpo_plus", "plot", "--env", args.env, "--runs", *labels,
                    "-o", str(root / "learning_curves.png")], check=True)  # fmt: skip


if __name__ == "__main__":
    main()
