"""What an update costs: seconds of ``train()`` (the update) and of collection per 10k samples, for study variants.

    python -m benchmarks.update_cost --env HalfCheetah-v5 --variants generalized_reuse generalized_reuse_andrychowicz \
        ppo ppo_trpo_plus_settings --steps 40960 --repeats 3

Each repeat builds each variant's model as the study does (``benchmarks.builders.new_model``: its zoo settings, envs
and VecNormalize, one torch thread), trains it for ``--steps`` env steps and times every call of ``train()`` and of
``collect_rollouts()``; the variants take turns within a repeat, so that a change in the machine's speed falls on all
of them. The table gives the median over repeats of each variant's seconds per 10k samples, and each variant's update
time as a ratio of the first variant's (the ratio within each repeat, then its median).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch as th

from benchmarks.builders import new_model
from benchmarks.machine import cpu_name
from benchmarks.study import BUDGETS, LABELS, VARIANTS


def timed(function: Callable[..., Any], seconds: list[float]) -> Callable[..., Any]:
    """``function``, appending the wall time of each call to ``seconds``."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            seconds.append(time.perf_counter() - start)

    return wrapper


def measure(env_id: str, variant: str, steps: int, seed: int = 0) -> dict[str, float]:
    """Train ``variant`` on ``env_id`` for ``steps`` env steps: seconds of its updates and of its collection, per 10k
    samples."""
    th.set_num_threads(1)
    model = new_model(env_id, variant, seed)
    update: list[float] = []
    collect: list[float] = []
    model.train = timed(model.train, update)
    model.collect_rollouts = timed(model.collect_rollouts, collect)
    model.learn(steps)
    model.get_env().close()
    samples = model.num_timesteps
    return {
        "samples": samples,
        "updates": len(update),
        "update_per_10k": sum(update) * 10_000 / samples,
        "collect_per_10k": sum(collect) * 10_000 / samples,
    }


def summary(env_id: str, variants: Sequence[str], repeats: list[dict[str, dict[str, float]]]) -> list[str]:
    """The markdown table of ``repeats`` (each: variant -> ``measure``'s result)."""
    first = variants[0]
    lines = [
        f"{env_id}, {len(repeats)} repeats, medians:",
        "",
        "| variant | updates | update s / 10k samples | collection s / 10k samples | update vs the first |",
        "|---|---|---|---|---|",
    ]
    for variant in variants:
        rows = [repeat[variant] for repeat in repeats]
        ratio = statistics.median(repeat[variant]["update_per_10k"] / repeat[first]["update_per_10k"] for repeat in repeats)
        lines.append(
            f"| {LABELS[variant]} | {rows[0]['updates']} | {statistics.median(r['update_per_10k'] for r in rows):.2f} | "
            f"{statistics.median(r['collect_per_10k'] for r in rows):.2f} | {ratio:.2f} |"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--env", default="HalfCheetah-v5", choices=sorted(BUDGETS), help="one of the study's envs")
    parser.add_argument("--variants", nargs="+", choices=sorted(VARIANTS), required=True)
    parser.add_argument("--steps", type=int, default=40_960)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None, help="also write every repeat's figures to this JSON file")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.repeats < 1:
        parser.error("--steps and --repeats must be at least 1")
    repeats = [{variant: measure(args.env, variant, args.steps) for variant in args.variants} for _ in range(args.repeats)]
    print("\n".join(summary(args.env, args.variants, repeats)))
    if args.out is not None:
        machine = {"cpu": cpu_name(), "python": platform.python_version(), "torch": th.__version__}
        record = {"env": args.env, "steps": args.steps, "machine": machine, "repeats": repeats}
        args.out.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
