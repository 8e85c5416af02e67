"""Where a rollout worker's segment goes: the recipe's collection of one segment, split into its phases.

    python -m benchmarks.collection_phases [--env Grasper3D-v7] [--sim-threads 1 2] [--segments 10] [--repeats 5]

Builds the recipe's rollout worker in this process (``n_envs`` envs on the batched engine, its scripted starts, the
recipe's policy at its initialisation), collects a few segments to warm up, then times ``--segments`` segments of
``n_steps`` steps, ``--repeats`` times, and prints per segment (medians of the repeats, ms): the whole collection,
the physics (``mujoco.batch`` steps of every simulation: the episodes' steps), the scripted starts' physics (steps
of some simulations: the unseen scripted steps after a reset), the task's controls (the grip IK), the contact counts
after each physics call (the screen and the contact lists it lets through), the task's transition (observation,
reward, success), the policy's forward passes (``sampling_forward``), and the rest (the VecEnv's and the segment's
bookkeeping, the scripted grasp's actions, resets). No profiler runs: each phase
is timed by a wrapper around its function. Writes the table and the raw numbers to
``benchmarks/results/collection_phases.json``.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cloudpickle
import numpy as np
import torch as th

from benchmarks.machine import cpu_name

PHASES = ("physics", "scripted", "controls", "contacts", "transition", "policy")


def timed(seconds: dict[str, float], phase: str, function: Callable[..., Any]) -> Callable[..., Any]:
    """``function``, adding the time of each call to ``seconds[phase]``."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            seconds[phase] += time.perf_counter() - start

    return wrapper


def measure(env_id: str, sim_threads: int, segments: int, repeats: int) -> dict[str, Any]:
    """Per repeat, the seconds per segment of the whole collection and of each phase."""
    from grasp_envs.batch import BatchVecEnv
    from sb3_trpo_plus.algorithm import segment
    from sb3_trpo_plus.application.recipes import make_model
    from sb3_trpo_plus.rollouts import RolloutWorkers, rollout_workers
    from sb3_trpo_plus.rollouts.worker import RolloutWorker, SegmentOrder

    th.set_num_threads(1)
    # the recipe's model with one in-process worker: its policy and its workers' envs, as training builds them
    model = make_model(env_id, seed=0, sim_threads=sim_threads, workers="inprocess:1")
    found = rollout_workers(model.get_env())  # type: ignore[arg-type]
    assert found is not None and isinstance(found[0], RolloutWorkers)
    envs = found[0].worker_envs
    n_envs, n_steps = envs.n_envs, int(model.n_steps)
    worker = RolloutWorker(0, envs, torch_seed=0)
    worker.set_policy(cloudpickle.dumps(model.policy))
    worker.reset(list(range(n_envs)), None)
    order = SegmentOrder(n_steps, float(model.gamma), model.policy.state_dict(), None)
    env = worker.env
    assert isinstance(env, BatchVecEnv), f"{env_id} collects on the batched engine"
    seconds = dict.fromkeys(PHASES, 0.0)
    physics, task = env.physics, env.task
    run, run_all, run_some = physics._run, timed(seconds, "physics", physics._run), timed(seconds, "scripted", physics._run)
    # every simulation stepped: an episode step; some of them: the scripted starts' steps after a reset
    physics._run = lambda ids: (run_all if ids is None else run_some)(ids)  # type: ignore[method-assign]
    physics._settle = timed(seconds, "contacts", physics._settle)  # type: ignore[method-assign]
    task.controls = timed(seconds, "controls", task.controls)  # type: ignore[method-assign]
    task.transition = timed(seconds, "transition", task.transition)  # type: ignore[method-assign]
    sampling_forward = segment.sampling_forward  # what collect_segment samples with, timed
    segment.sampling_forward = lambda policy: timed(seconds, "policy", sampling_forward(policy))  # type: ignore[assignment]
    for _ in range(3):  # warm-up: the first episodes' resets, torch's first calls
        worker.collect(order)
    rows = []
    for _ in range(repeats):
        for phase in PHASES:
            seconds[phase] = 0.0
        start = time.perf_counter()
        for _ in range(segments):
            worker.collect(order)
        total = time.perf_counter() - start
        row = {"collection": total / segments, **{phase: seconds[phase] / segments for phase in PHASES}}
        row["rest"] = row["collection"] - sum(row[phase] for phase in PHASES)
        rows.append(row)
    segment.sampling_forward = sampling_forward  # type: ignore[assignment]
    physics._run = run  # type: ignore[method-assign]
    worker.close()
    model.env.close()  # type: ignore[union-attr]
    return {"n_envs": n_envs, "n_steps": n_steps, "repeats": rows}


def table(results: dict[int, dict[str, Any]]) -> str:
    """A Markdown table: per phase, ms per segment (median of the repeats) and its share of the collection."""
    columns = ("collection", *PHASES, "rest")
    lines = [
        "| physics threads | env steps/s | " + " | ".join(columns) + " |",
        "|---|---|" + "---|" * len(columns),
    ]
    for threads, result in results.items():
        medians = {key: float(np.median([row[key] for row in result["repeats"]])) for key in columns}
        samples = result["n_envs"] * result["n_steps"]
        cells = [f"{1e3 * medians['collection']:.0f} ms"] + [
            f"{1e3 * medians[key]:.0f} ms ({medians[key] / medians['collection']:.0%})" for key in columns[1:]
        ]
        lines.append(f"| {threads} | {samples / medians['collection']:,.0f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Grasper3D-v7")
    parser.add_argument("--sim-threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--segments", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("benchmarks/results/collection_phases.json"))
    args = parser.parse_args(argv)
    results = {threads: measure(args.env, threads, args.segments, args.repeats) for threads in args.sim_threads}
    text = table(results)
    print(
        f"{args.env}, {results[args.sim_threads[0]]['n_envs']} envs x {results[args.sim_threads[0]]['n_steps']} "
        f"steps per segment, ms per segment (median of {args.repeats} repeats of {args.segments} segments)"
    )
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    machine = {"cpu": cpu_name(), "python": platform.python_version(), "torch": th.__version__}
    args.out.write_text(json.dumps({"env": args.env, "machine": machine, "results": results, "table": text}, indent=1) + "\n")


if __name__ == "__main__":
    main()
