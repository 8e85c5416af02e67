"""Rollout workers against collection in the learner: env steps/s of collection and of whole training, per backend.

    python -m benchmarks.workers [--env Grasper3D-v7] [--workers 1 2] [--envs-per-worker 32] [--n-steps 32]
                                 [--iterations 6] [--backends learner inprocess process ray]
                                 [--out benchmarks/results/workers.json]

Every contender trains TRPOPlus (100-100 tanh MLP, 10 CG iterations, 10 critic epochs, VecNormalize, one torch
thread) on ``workers x envs-per-worker`` envs for ``iterations`` iterations of ``n_steps``; the first iteration is a
warm-up and the medians of the others are reported. ``learner``: one batched VecEnv stepped by the learner
(``make_batch_env``, SB3's collection loop); ``inprocess``, ``process``, ``ray``: the pools of
``sb3_trpo_plus.rollouts`` (Ray on this machine, ``num_cpus`` = its cores). Per iteration: collection time (rollout
start to end, the learner's merge of the segments included), update time, the weight broadcast, the segment transfer
(collection wall time beyond the slowest worker) and the slowest worker's segment time.

The projection to many workers models one iteration as ``broadcast + segment + transfer x workers + merge x samples
+ update(samples)`` with ``update = fixed + per_sample x samples``, from the measured costs, each remote worker on its
own core: with ``n_steps`` fixed (the batch grows with the workers) and with the batch fixed (``n_steps`` shrinks).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize
from torch import nn

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.rollouts import InProcessRollouts, ProcessRollouts, RayRollouts, RolloutWorkers

POOLS: dict[str, type[RolloutWorkers]] = {"inprocess": InProcessRollouts, "process": ProcessRollouts, "ray": RayRollouts}
PROJECTED_WORKERS = [1, 2, 4, 8, 16, 32, 64, 100]


class _IterationTimer(BaseCallback):
    """Collection and update time of each iteration, and the pool's broadcast / transfer / worker times."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[dict[str, float]] = []
        self._start = self._end = 0.0

    def _on_rollout_start(self) -> None:
        now = time.perf_counter()
        if self.rows:
            self.rows[-1]["update_s"] = now - self._end
        self._start = now

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self._end = time.perf_counter()
        row = {"collect_s": self._end - self._start}
        pool = _pool_of(self.training_env)
        if pool is not None:
            timings = pool.last_timings
            row.update(broadcast_s=timings["broadcast_s"], transfer_s=timings["transfer_s"], worker_s=max(timings["worker_s"]))
        self.rows.append(row)

    def _on_training_end(self) -> None:
        if self.rows and "update_s" not in self.rows[-1]:
            self.rows[-1]["update_s"] = time.perf_counter() - self._end


def _pool_of(env: Any) -> RolloutWorkers | None:
    while env is not None and not isinstance(env, RolloutWorkers):
        env = getattr(env, "venv", None)
    return env


def measure(backend: str, env_id: str, workers: int, envs_per_worker: int, n_steps: int, iterations: int) -> dict[str, Any]:
    from grasp_envs import make_batch_env

    n_envs = workers * envs_per_worker
    venv: Any = (
        make_batch_env(env_id, n_envs, seed=0)
        if backend == "learner"
        else POOLS[backend](env_id, workers, envs_per_worker, seed=0)
    )
    env = VecNormalize(venv)
    model = TRPOPlus(
        "MlpPolicy",
        env,
        n_steps=n_steps,
        batch_size=n_steps * n_envs // 4,
        cg_max_steps=10,
        n_critic_updates=10,
        seed=0,
        policy_kwargs=dict(net_arch=[100, 100], activation_fn=nn.Tanh),
        device="cpu",
    )
    timer = _IterationTimer()
    try:
        model.learn(iterations * n_steps * n_envs, callback=timer)
    finally:
        env.close()
    rows = timer.rows[1:]  # the first iteration warms up (the policy's first broadcast, allocations)
    samples = n_steps * n_envs
    median = {key: statistics.median(row[key] for row in rows) for key in rows[0]}
    measured: dict[str, Any] = {
        "backend": backend,
        "workers": workers,
        "n_envs": n_envs,
        "samples": samples,
        "collect_steps_per_s": samples / median["collect_s"],
        "train_steps_per_s": samples / (median["collect_s"] + median["update_s"]),
        **{f"{key}_ms": 1e3 * value for key, value in median.items()},
    }
    if "worker_s_ms" in measured:
        waited = measured["worker_s_ms"] + measured["transfer_s_ms"] + measured["broadcast_s_ms"]
        measured["merge_ms"] = measured["collect_s_ms"] - waited
    return measured


def learner_costs(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Per-iteration costs for the projection, from the measured rows.

    ``update = fixed + per_sample x samples`` fitted over every row (the update does not depend on the backend); the
    merge per sample, the transfer per worker, the broadcast and the segment time per step of one worker's envs from
    the remote row (``ray``, else ``process``) with the most workers.
    """
    samples = np.array([row["samples"] for row in rows], dtype=float)
    update = np.array([row["update_s_ms"] / 1e3 for row in rows])
    if len(set(samples.tolist())) > 1:
        per_sample, fixed = np.polyfit(samples, update, 1)
    else:
        per_sample, fixed = float(np.median(update / samples)), 0.0
    remote = [row for row in rows if row["backend"] in ("ray", "process")]
    best = max(remote, key=lambda row: (row["workers"], row["backend"] == "ray"))
    return {
        "update_fixed_s": max(float(fixed), 0.0),
        "update_per_sample_s": float(per_sample),
        "merge_per_sample_s": max(best["merge_ms"], 0.0) / 1e3 / best["samples"],
        "transfer_per_worker_s": best["transfer_s_ms"] / 1e3 / best["workers"],
        "broadcast_s": best["broadcast_s_ms"] / 1e3,
        "segment_step_s": best["worker_s_ms"] / 1e3 / (best["samples"] / best["n_envs"]),
        "from": best["backend"],
    }


def project(costs: dict[str, Any], workers: int, envs_per_worker: int, n_steps: int) -> dict[str, Any]:
    """One iteration of ``workers`` remote workers with ``envs_per_worker`` envs each, ``n_steps`` steps."""
    samples = workers * envs_per_worker * n_steps
    learner = costs["update_fixed_s"] + (costs["update_per_sample_s"] + costs["merge_per_sample_s"]) * samples
    collection = costs["broadcast_s"] + costs["segment_step_s"] * n_steps + costs["transfer_per_worker_s"] * workers
    iteration = collection + learner
    return {
        "workers": workers,
        "n_steps": n_steps,
        "samples": samples,
        "iteration_s": iteration,
        "steps_per_s": samples / iteration,
        "learner_share": learner / iteration,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Grasper3D-v7")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--envs-per-worker", type=int, default=32)
    parser.add_argument("--n-steps", type=int, default=32)
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument(
        "--backends", nargs="+", default=["learner", "inprocess", "process", "ray"], choices=["learner", *POOLS]
    )
    parser.add_argument("--out", default="benchmarks/results/workers.json")
    args = parser.parse_args()
    th.set_num_threads(1)
    machine = {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "torch": th.__version__,
        "numpy": np.__version__,
    }
    if "ray" in args.backends:
        import ray

        from sb3_trpo_plus.rollouts.ray_cluster import use_loopback_for_local_ray

        use_loopback_for_local_ray()  # a Ray of this benchmark only, on 127.0.0.1
        ray.init(num_cpus=os.cpu_count(), include_dashboard=False, log_to_driver=False)
        machine["ray"] = ray.__version__
    rows = []
    for workers in args.workers:
        for backend in args.backends:
            row = measure(backend, args.env, workers, args.envs_per_worker, args.n_steps, args.iterations)
            rows.append(row)
            remote = (
                f", broadcast {row['broadcast_s_ms']:.1f} ms, transfer {row['transfer_s_ms']:.1f} ms, "
                f"slowest worker {row['worker_s_ms']:.0f} ms, merge {row['merge_ms']:.0f} ms"
                if "worker_s_ms" in row
                else ""
            )
            print(
                f"{backend:>9} x{workers}: {row['n_envs']} envs, collection {row['collect_steps_per_s']:,.0f} steps/s, "
                f"training {row['train_steps_per_s']:,.0f} steps/s, update {row['update_s_ms']:.0f} ms{remote}",
                flush=True,
            )
    costs = learner_costs(rows) if any(row["backend"] in ("ray", "process") for row in rows) else None
    fixed_steps: list[dict[str, Any]] = []
    fixed_batch: list[dict[str, Any]] = []
    if costs is not None:
        print(
            "costs: "
            + ", ".join(f"{key} {value:.3g}" if isinstance(value, float) else f"{key} {value}" for key, value in costs.items())
        )
        batch = PROJECTED_WORKERS[-1] * args.envs_per_worker * args.n_steps // 4
        for count in PROJECTED_WORKERS:
            fixed_steps.append(project(costs, count, args.envs_per_worker, args.n_steps))
            fixed_batch.append(project(costs, count, args.envs_per_worker, max(batch // (count * args.envs_per_worker), 1)))
        for title, projected in ((f"n_steps {args.n_steps}", fixed_steps), (f"batch {batch:,}", fixed_batch)):
            for row in projected:
                print(
                    f"projected ({title}) x{row['workers']:>3}: n_steps {row['n_steps']:>4}, {row['samples']:>7,} samples, "
                    f"{row['steps_per_s']:>9,.0f} env steps/s, learner {100 * row['learner_share']:.0f} % of the iteration"
                )
    result = {
        "machine": machine,
        "command": vars(args),
        "rows": rows,
        "costs": costs,
        "projection_fixed_n_steps": fixed_steps,
        "projection_fixed_batch": fixed_batch,
    }
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1))
    print(f"raw results: {args.out}")


if __name__ == "__main__":
    main()
