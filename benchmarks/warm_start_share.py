"""How much of the conjugate-gradient solution does the warm start carry? Every update against a zero start.

    python -m benchmarks.warm_start_share --env Grasper3D-v6 --variant warm_scripted25_late --steps 200000
    python -m benchmarks.warm_start_share --env Grasper3D-v6 --variant warm_scripted25_late --seed 0 --from-run --steps 100000

A model of the convergence study's ``--variant`` (benchmarks/study.yml: zoo settings, its switches and
training wrappers) trains for ``--steps`` with the CG warm start on, either new (seed ``--seed``) or, with
``--from-run``, from the saved checkpoint of that variant's run (its weights and VecNormalize statistics; the first
update after loading has no previous step). At every update that TRPOPlus warm-starts, CG is also solved from
zero on the same gradient and Fisher products, and the script records:

- ``start_gradient_cosine``: cosine between the previous step and the new gradient;
- ``start_share``: ||a x0|| / ||x||, the size of the start after CG's free rescaling to its line minimiser
  ``a x0`` (``a = x0.g / x0.F x0``, ``cg_warm_start_rescale``, the default; ``a = 1`` with ``--raw``, the thesis'
  unscaled previous step) relative to the warm-started solution;
- ``solution_cosine``: cosine between the warm-started and the zero-started solutions (1: the same direction);
- ``objective_gain``: how much lower the warm-started solution puts CG's objective ``x.F x / 2 - g.x`` than the
  zero-started one, relative to the zero start's (positive: the warm start solved better).

Training itself follows the warm-started solution, as TRPOPlus does; the zero-start solve only measures.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

import sb3_trpo_plus.algorithm.update as update_module
from benchmarks.builders import add_run_arguments, algorithm_class, new_model, normalized_training_envs
from benchmarks.runs import OUT, job_folder
from benchmarks.study import VARIANTS
from sb3_trpo_plus.algorithm.natural_gradient import ConjugateGradientResult, conjugate_gradient

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("start_gradient_cosine", "start_share", "solution_cosine", "objective_gain")


def _cosine(a: th.Tensor, b: th.Tensor) -> float:
    """The cosine TRPOPlus logs (train/cg_warm_start_cosine)."""
    denominator = float(th.linalg.vector_norm(a) * th.linalg.vector_norm(b))
    return float(th.dot(a, b)) / denominator if denominator > 0 else 0.0


def compare_starts(
    fvp: Any, gradient: th.Tensor, start: th.Tensor, warm: ConjugateGradientResult, max_iter: int, rescale: bool
) -> dict[str, float]:
    """The four figures above for one update: ``warm`` solved from ``start``, and a zero-started solve here."""
    zero = conjugate_gradient(fvp, gradient, None, max_iter=max_iter)
    scale = 1.0
    if rescale:
        curvature = float(th.dot(start, fvp(start)))
        scale = float(th.dot(start, gradient)) / curvature if curvature > 0 else 1.0

    def objective(result: ConjugateGradientResult) -> float:  # x.F x / 2 - g.x, x.F x from CG's recurrence
        return 0.5 * result.quadratic_form - float(th.dot(result.solution, gradient))

    zero_objective = objective(zero)
    return {
        "start_gradient_cosine": _cosine(start, gradient),
        "start_share": abs(scale)
        * float(th.linalg.vector_norm(start))
        / max(float(th.linalg.vector_norm(warm.solution)), 1e-30),
        "solution_cosine": _cosine(warm.solution, zero.solution),
        "objective_gain": (zero_objective - objective(warm)) / max(abs(zero_objective), 1e-30),
    }


def _model(env_id: str, variant: str, seed: int, from_run: bool) -> Any:
    if not from_run:
        return new_model(env_id, variant, seed)
    from stable_baselines3.common.vec_env import VecNormalize

    folder = job_folder(OUT, env_id, variant, seed)
    if not (folder / "model.zip").exists():
        raise FileNotFoundError(f"{folder} has no model.zip (checkpoints stay on the machine that trained them)")
    env = normalized_training_envs(env_id, variant, seed)
    if isinstance(env, VecNormalize):
        env = VecNormalize.load(str(folder / "vecnormalize.pkl"), env.venv)
    return algorithm_class(variant).load(folder / "model.zip", env=env, device="cpu")


def measure(env_id: str, variant: str, seed: int, steps: int, from_run: bool, raw: bool) -> dict[str, Any]:
    """Train ``steps`` with the warm start on (``raw``: unscaled) and return the figures of every warm-started update."""
    if VARIANTS[variant].algo != "trpo_plus":
        raise ValueError(f"variant {variant!r} is not trained by TRPOPlus (its algorithm: {VARIANTS[variant].algo})")
    th.set_num_threads(1)
    model = _model(env_id, variant, seed, from_run)
    model.cg_warm_start, model.cg_warm_start_rescale = True, not raw
    rows: list[dict[str, float]] = []
    solve = update_module.conjugate_gradient  # the solver natural_gradient_step calls

    def solve_and_compare(fvp: Any, b: th.Tensor, x0: th.Tensor | None = None, **kwargs: Any) -> Any:
        result = solve(fvp, b, x0, **kwargs)
        if x0 is not None and bool(th.any(x0 != 0)):
            rows.append(compare_starts(fvp, b, x0, result, kwargs["max_iter"], not raw))  # TRPOPlus passes cg_max_steps
        return result

    update_module.conjugate_gradient = solve_and_compare  # type: ignore[assignment]
    try:
        model.learn(steps, reset_num_timesteps=not from_run)
    finally:
        update_module.conjugate_gradient = solve
        model.get_env().close()
    return {
        "env": env_id,
        "variant": variant,
        "seed": seed,
        "from_run": from_run,
        "raw": raw,
        "steps": steps,
        "updates": rows,
    }


def summary(result: dict[str, Any]) -> str:
    rows = result["updates"]
    cells = [f"{np.median([row[key] for row in rows]):.3f}" for key in KEYS]
    weights = "the run's checkpoint" if result["from_run"] else "new"
    start = "raw" if result["raw"] else "rescaled"
    return f"| {result['variant']} | {result['seed']} | {weights} | {start} | {len(rows)} | " + " | ".join(cells) + " |"


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    add_run_arguments(parser, "Grasper3D-v6", "warm_scripted25_late")
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--from-run", action="store_true", help="start from the study run's saved checkpoint")
    parser.add_argument("--raw", action="store_true", help="the previous step unscaled (cg_warm_start_rescale off)")
    parser.add_argument("--out", type=Path, default=None, help="JSON of every update (default: results/warm_start/)")
    args = parser.parse_args(argv)
    result = measure(args.env, args.variant, args.seed, args.steps, args.from_run, args.raw)
    tag = ("from_run" if args.from_run else "new") + ("_raw" if args.raw else "")
    name = f"share_{args.env}_{args.variant}_s{args.seed}_{args.steps}_{tag}.json"
    out = args.out or ROOT / "benchmarks" / "results" / "warm_start" / name
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"{args.env}, {args.steps:,} steps with the CG warm start; medians over the warm-started updates")
    print("| variant | seed | weights | start | updates | " + " | ".join(KEYS) + " |")
    print("|---|---|---|---|---|" + "---|" * len(KEYS))
    print(summary(result))


if __name__ == "__main__":
    main()
