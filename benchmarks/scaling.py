"""Rollout-collection throughput with DummyVecEnv, SubprocVecEnv, rollout worker processes and the batched engine at
1, 2, 4, 8, 16 envs.

    python -m benchmarks.scaling [--envs Grasper3D-v0 Reacher2D-v0] [--samples 8192] [--repeats 3]
                                 [--counts 1 4 16 64] [--vec-envs DummyVecEnv Batch-1-thread Batch-2-threads]

Times TRPOPlus' ``collect_rollouts`` (policy inference, env stepping, buffer, callbacks) for ``--samples``
env steps; prints env steps/s, the speed-up over one env in one process, and the ratio of the
per-step collection time to the raw ``env.step`` time ("vs 1 worker": against one rollout worker process,
``ProcessRollouts`` with ``num_workers=1``, at the same number of envs); for the batched engine (``grasp_envs.make_batch_env``,
1 to 16 threads) also the share of the collection time spent in ``mujoco.batch``'s physics steps. Writes a plot
like the thesis' Figures 5.14-5.16 and the raw numbers to benchmarks/results/.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

import grasp_envs  # noqa: F401
from benchmarks.env_speed import time_env_step
from benchmarks.machine import cpu_name
from grasp_envs import BatchVecEnv, make_batch_env
from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.rollouts import ProcessRollouts

COUNTS = (1, 2, 4, 8, 16)


# label -> (VecEnv class, kwargs): one process; one process per env; rollout workers (processes that each step
# n_envs / num_workers envs and collect whole segments with a copy of the policy)
VEC_ENVS: dict[str, tuple[type, dict | None]] = {
    "DummyVecEnv": (DummyVecEnv, None),
    "SubprocVecEnv": (SubprocVecEnv, {"start_method": "forkserver"}),
    "Process-1-worker": (ProcessRollouts, {"num_workers": 1}),
    "Process-2-workers": (ProcessRollouts, {"num_workers": 2}),
    # the batched engine: every simulation in one mujoco.batch.Batch, physics on n_threads threads
    **{f"Batch-{n}-thread{'s' * (n > 1)}": (BatchVecEnv, {"n_threads": n}) for n in (1, 2, 4, 8, 16)},
}


class PhysicsTimer:
    """Times the calls of a batched env's ``mujoco.batch.Batch.step``: the physics of the collection."""

    def __init__(self, env: BatchVecEnv):
        self.seconds = 0.0
        batch, original = env.batch, env.batch.step

        def timed(*args: Any, **kwargs: Any) -> None:
            start = time.perf_counter()
            try:
                original(*args, **kwargs)
            finally:
                self.seconds += time.perf_counter() - start

        batch.step = timed


def collection_rate(env_id: str, label: str, n_envs: int, samples: int, repeats: int) -> tuple[list[float], list[float]]:
    """Env steps/s of ``repeats`` collections (after one warm-up), and for the batched engine the physics' share of
    each (empty otherwise)."""
    vec_env_cls, kwargs = VEC_ENVS[label]
    env: VecEnv
    physics: PhysicsTimer | None = None
    if vec_env_cls is BatchVecEnv:
        env = make_batch_env(env_id, n_envs, seed=0, **(kwargs or {}))
        physics = PhysicsTimer(env.unwrapped)  # type: ignore[arg-type]
    elif vec_env_cls is ProcessRollouts:
        workers = (kwargs or {})["num_workers"]
        env = ProcessRollouts(env_id, workers, n_envs // workers, seed=0)
    else:
        env = make_vec_env(env_id, n_envs=n_envs, seed=0, vec_env_cls=vec_env_cls, vec_env_kwargs=kwargs)
    n_steps = max(samples // n_envs, 1)
    model = TRPOPlus(
        "MlpPolicy",
        env,
        n_steps=n_steps,
        batch_size=n_steps * n_envs,
        seed=0,
        policy_kwargs=dict(net_arch=[100, 100]),
        device="cpu",
    )
    model._setup_learn(10**9, None)
    callback = CallbackList([])
    callback.init_callback(model)
    model_env = model.get_env()
    assert model_env is not None
    rates, shares = [], []
    for _ in range(repeats + 1):
        if physics is not None:
            physics.seconds = 0.0
        start = time.perf_counter()
        model.collect_rollouts(model_env, callback, model.rollout_buffer, n_steps)
        elapsed = time.perf_counter() - start
        rates.append(n_steps * n_envs / elapsed)
        if physics is not None:
            shares.append(physics.seconds / elapsed)
    env.close()
    return rates[1:], shares[1:]  # first repeat is warm-up


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=["Grasper3D-v0", "Reacher2D-v0"])
    parser.add_argument("--samples", type=int, default=8192)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--counts", type=int, nargs="+", default=list(COUNTS), help="numbers of envs")
    parser.add_argument("--vec-envs", nargs="+", default=list(VEC_ENVS), choices=list(VEC_ENVS))
    parser.add_argument("--out", default="benchmarks/results")
    parser.add_argument("--name", default=None, help="file stem of the results (default: scaling[_<counts>])")
    args = parser.parse_args()
    th.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict = {
        "machine": {"cpu": cpu_name(), "cores": os.cpu_count(), "python": platform.python_version(), "torch": th.__version__},
        "samples": args.samples,
        "repeats": args.repeats,
        "envs": {},
    }
    for env_id in args.envs:
        raw = time_env_step(env_id, 5000)
        rows = {}
        for n in args.counts:  # interleave the vec envs at each size
            for label in args.vec_envs:
                if n % (VEC_ENVS[label][1] or {}).get("num_workers", 1):
                    continue  # the envs do not split evenly over the workers
                rates, shares = collection_rate(env_id, label, n, args.samples, args.repeats)
                rows[f"{label}-{n}"] = {"vec_env": label, "n_envs": n, "steps_per_s": float(np.median(rates)), "all": rates}
                if shares:
                    rows[f"{label}-{n}"]["physics_share"] = float(np.median(shares))
        first = min(args.counts)
        base = rows[f"{args.vec_envs[0]}-{first}"]["steps_per_s"]
        print(f"\n## {env_id} (raw env.step {raw * 1e6:.0f} µs = {1 / raw:,.0f} steps/s in one process)")
        print(
            f"| vec env | n_envs | env steps/s | speed-up vs {args.vec_envs[0]} at {first} | vs 1 worker | "
            "collection time / raw env.step | physics share |"
        )
        print("|---|---|---|---|---|---|---|")
        for row in sorted(rows.values(), key=lambda r: (list(VEC_ENVS).index(r["vec_env"]), r["n_envs"])):
            row["speedup"] = row["steps_per_s"] / base
            one_worker = rows.get(f"Process-1-worker-{row['n_envs']}", row)["steps_per_s"]
            row["speedup_vs_one_worker"] = row["steps_per_s"] / one_worker
            row["ratio_to_raw_env_step"] = (1 / row["steps_per_s"]) / raw
            print(
                f"| {row['vec_env']} | {row['n_envs']} | {row['steps_per_s']:,.0f} | {row['speedup']:.2f} | "
                f"{row['speedup_vs_one_worker']:.2f} | {row['ratio_to_raw_env_step']:.2f} | "
                + (f"{row['physics_share']:.0%} |" if "physics_share" in row else "- |")
            )
        results["envs"][env_id] = {"raw_env_step_s": raw, "rows": rows}
    stem = args.name or ("scaling" if args.counts == list(COUNTS) else "scaling_" + "_".join(map(str, args.counts)))
    (out / f"{stem}.json").write_text(json.dumps(results, indent=1))
    plot(results, out / f"{stem}.png")
    print(f"\nraw results: {out / f'{stem}.json'}, plot: {out / f'{stem}.png'}")


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = results["envs"]
    fig, axes = plt.subplots(1, len(envs), figsize=(5.5 * len(envs), 4), squeeze=False)
    for ax, (env_id, data) in zip(axes[0], envs.items(), strict=True):
        for label in dict.fromkeys(r["vec_env"] for r in data["rows"].values()):
            rows = sorted((r for r in data["rows"].values() if r["vec_env"] == label), key=lambda r: r["n_envs"])
            ax.plot([r["n_envs"] for r in rows], [r["steps_per_s"] for r in rows], marker="o", label=label)
        ax.axhline(1 / data["raw_env_step_s"], color="grey", linestyle="--", label="raw env.step, 1 process")
        ax.set_xscale("log", base=2)
        ax.set_xlabel("environments")
        ax.set_ylabel("rollout env steps / s")
        ax.set_title(f"{env_id} ({results['machine']['cores']} cores)")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
