"""How many PyTorch threads should the learner use? Training throughput with 1 thread against every core.

    python -m benchmarks.torch_threads --steps 200000 --repeats 3

Trains each rollout layout's recipe (``make_model``, as ``trpo-plus train`` builds it) for ``--steps`` env steps
with ``torch.set_num_threads(k)`` for each ``k`` of ``--threads`` (default: 1 and the machine's core count), the
layouts and thread counts interleaved within each repeat so that a drift of the machine touches them alike, and
reports the median env steps per second of each (layout, threads) and its ratio to 1 thread:

- ``worker``: Grasper3D-v7's recipe, one rollout worker process collecting while the learner updates (the default
  of ``trpo-plus train --env Grasper3D-v7``);
- ``batch``: the same recipe on the learner's own batched envs (``rollout_workers=None, overlap_collection=False``);
- ``dummy``: Reacher2D-v1's recipe in SB3's ``DummyVecEnv`` (an id without the batched engine).

The rollout worker always runs its policy on one thread; ``--sim-threads`` is the physics threads of the batched
engine. Writes ``benchmarks/results/torch_threads.json``. Measure with nothing else running.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.machine import cpu_name

OUT = Path(__file__).resolve().parent / "results" / "torch_threads.json"
LAYOUTS: dict[str, tuple[str, dict[str, Any]]] = {
    "worker": ("Grasper3D-v7", {}),
    "batch": ("Grasper3D-v7", {"rollout_workers": None, "overlap_collection": False, "vec_env": "batch"}),
    "dummy": ("Reacher2D-v1", {"vec_env": "dummy"}),
}


def steps_per_second(layout: str, threads: int, steps: int, sim_threads: int, seed: int) -> float:
    """Env steps per second of ``steps`` of training of ``layout``'s recipe with ``threads`` PyTorch threads."""
    import torch as th

    from sb3_trpo_plus import make_model

    env_id, settings = LAYOUTS[layout]
    th.set_num_threads(threads)
    model = make_model(env_id, seed=seed, sim_threads=sim_threads, **settings)
    env = model.get_env()
    assert env is not None
    try:
        model.learn(model.n_steps * model.n_envs)  # warm-up: the first update builds what later ones reuse
        start = time.perf_counter()
        model.learn(steps, reset_num_timesteps=False)
        elapsed = time.perf_counter() - start
        return (model.num_timesteps - model.n_steps * model.n_envs) / elapsed
    finally:
        env.close()


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.torch_threads", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--layouts", nargs="+", default=list(LAYOUTS), choices=list(LAYOUTS))
    parser.add_argument("--threads", type=int, nargs="+", default=sorted({1, os.cpu_count() or 1}))
    parser.add_argument("--steps", type=int, default=200_000, help="env steps timed per run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sim-threads", type=int, default=2, help="physics threads of the batched engine")
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args(argv)
    import torch as th

    rates: dict[str, dict[int, list[float]]] = {layout: {k: [] for k in args.threads} for layout in args.layouts}
    for repeat in range(args.repeats):
        for layout in args.layouts:
            for threads in args.threads:
                rate = steps_per_second(layout, threads, args.steps, args.sim_threads, seed=repeat)
                rates[layout][threads].append(rate)
                print(f"repeat {repeat} {layout:>6} threads {threads}: {rate:8.0f} env steps/s", flush=True)
    summary = {
        layout: {
            str(k): {"median": float(np.median(v)), "runs": v, "ratio_to_1": float(np.median(v) / np.median(per[1]))}
            for k, v in per.items()
        }
        for layout, per in rates.items()
        if 1 in per
    }
    result = {
        "command": " ".join(["python -m benchmarks.torch_threads", *(sys.argv[1:] if argv is None else argv)]),
        "cpu": cpu_name(),
        "cores": os.cpu_count(),
        "torch": th.__version__,
        "python": platform.python_version(),
        "steps": args.steps,
        "sim_threads": args.sim_threads,
        "layouts": summary,
    }
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    for layout, per in summary.items():
        row = ", ".join(f"{k} threads {v['median']:.0f} ({v['ratio_to_1']:.2f} x)" for k, v in per.items())
        print(f"{layout:>6}: {row}")


if __name__ == "__main__":
    main()
