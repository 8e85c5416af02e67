"""Does the CG warm start reach the zero start's residual in fewer Fisher-vector products? Both starts, every update.

    python -m benchmarks.cg_residuals --envs Hopper-v5 --updates 40 --seed 0
    python -m benchmarks.cg_residuals --envs Grasper3D-v7 --updates 40 --seed 0 \\
        --set policy_update=natural_gradient projection_epochs=10 projection_minibatches=32 cg_max_steps=25 \\
        fisher_sub_sampling=4 --out benchmarks/results/cg_residuals_grasp.json --plot docs/images/cg_residuals_grasp.png

Each env trains its recipe (zoo_hyperparams/trpo_plus.yml, ``cg_warm_start`` on, the recipe's ``cg_max_steps``;
``--set KEY=VALUE`` overrides a recipe key on every env, the value a YAML scalar) for ``--updates`` updates. A recipe
with the projected trust region solves no CG: ``--set policy_update=natural_gradient projection_epochs=10
projection_minibatches=32`` measures its natural-gradient step. At every update that TRPOPlus warm-starts, the same
gradient and Fisher products are also solved from zero, and the relative residual ``||g - F x_k|| / ||g||`` after
every iteration of both solves is recorded. Training follows the warm-started solution, as TRPOPlus does; the
zero-start solve only measures. Each result records the recipe it trained (``recipe``, its values as ``repr``).

Per env the script prints the median relative residual after each iteration for both starts, and per residual level
(0.3, 0.1, 0.03, 0.01) the Fisher-vector products each start needs to reach it (the warm start's first product, for
``F x0``, counted); the raw histories go to benchmarks/results/cg_residuals.json (``--summary`` prints the summary of
that file again) and the plot to docs/images/cg_residuals.png.
"""

from __future__ import annotations

import argparse
import json
import platform
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

import sb3_trpo_plus.algorithm.update as update_module
from benchmarks.machine import cpu_name
from benchmarks.time_to_grasp import recipe_overrides
from sb3_trpo_plus.algorithm.natural_gradient import ConjugateGradientResult, conjugate_gradient

ROOT = Path(__file__).resolve().parents[1]


def products_to_reach(history: Sequence[float], target: float, start_cost: int) -> int | None:
    """Fisher-vector products until ``history`` (a residual per iteration, the start first) is at or below
    ``target``; None where it never is. The start costs ``start_cost`` products (1 for a warm start, 0 from zero)."""
    for iteration, residual in enumerate(history):
        if residual <= target:
            return start_cost + iteration
    return None


def measure(env_id: str, updates: int, seed: int, overrides: dict[str, Any] | None = None) -> dict[str, Any]:
    """Train ``env_id``'s recipe (``overrides`` on top) with the warm start for ``updates`` updates; both starts'
    residual histories, and the recipe as trained."""
    from sb3_trpo_plus import TRPOPlus, make_model, recipe

    th.set_num_threads(1)
    settings = {**(overrides or {}), "cg_warm_start": True}
    model = make_model(env_id, seed=seed, **settings)
    assert isinstance(model, TRPOPlus)
    rows: list[dict[str, Any]] = []
    solve = update_module.conjugate_gradient

    def solve_both(fvp: Any, b: th.Tensor, x0: th.Tensor | None = None, **kwargs: Any) -> ConjugateGradientResult:
        warm = solve(fvp, b, x0, **kwargs)
        if x0 is not None and bool(th.any(x0 != 0)):
            zero = conjugate_gradient(fvp, b, None, max_iter=kwargs["max_iter"])
            scale = max(float(th.linalg.vector_norm(b)), 1e-30)
            rows.append(
                {
                    "warm": [r / scale for r in warm.residual_norms],
                    "zero": [r / scale for r in zero.residual_norms],
                    "warm_products": warm.matvecs,
                    "zero_products": zero.matvecs,
                }
            )
        return warm

    update_module.conjugate_gradient = solve_both  # type: ignore[assignment]
    try:
        model.learn(updates * model.n_steps * model.n_envs)
    finally:
        update_module.conjugate_gradient = solve
        env = model.get_env()
        if env is not None:
            env.close()
    trained = {key: repr(value) for key, value in {**recipe(env_id), **settings}.items()}
    return {"env": env_id, "seed": seed, "cg_max_steps": model.cg_max_steps, "recipe": trained, "updates": rows}


LEVELS = (0.3, 0.1, 0.03, 0.01)


def summary(result: dict[str, Any]) -> list[str]:
    """The median relative residual per iteration of both starts, and per residual level the Fisher-vector products
    each start needs to reach it (the warm start's first product counted) over the updates where both reach it."""
    rows = result["updates"]
    depth = min(min(len(row["warm"]), len(row["zero"])) for row in rows)
    warm = np.median([row["warm"][:depth] for row in rows], axis=0)
    zero = np.median([row["zero"][:depth] for row in rows], axis=0)
    lines = [f"{result['env']}: {len(rows)} warm-started updates, cg_max_steps {result['cg_max_steps']}"]
    lines.append("iteration | " + " | ".join(str(i) for i in range(depth)))
    lines.append("zero start | " + " | ".join(f"{v:.3f}" for v in zero))
    lines.append("warm start | " + " | ".join(f"{v:.3f}" for v in warm))
    header = (
        "residual level",
        "updates",
        "products, zero start",
        "products, warm start",
        "warm - zero (mean)",
        "warm fewer",
        "warm more",
    )
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|---|---|---|---|---|---|---|")
    for level in LEVELS:
        pairs = [(products_to_reach(row["zero"], level, 0), products_to_reach(row["warm"], level, 1)) for row in rows]
        both = [(a, b) for a, b in pairs if a is not None and b is not None]
        if not both:
            continue
        difference = [b - a for a, b in both]
        lines.append(
            f"| {level} | {len(both)} | {np.median([a for a, _ in both]):.1f} | {np.median([b for _, b in both]):.1f} | "
            f"{np.mean(difference):+.2f} | {sum(d < 0 for d in difference)} | {sum(d > 0 for d in difference)} |"
        )
    return lines


def plot(results: Sequence[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 3.6), squeeze=False)
    for ax, result in zip(axes[0], results, strict=True):
        rows = result["updates"]
        for start, colour, offset in (("zero", "tab:blue", 0), ("warm", "tab:orange", 1)):
            depth = min(len(row[start]) for row in rows)
            curves = np.array([row[start][:depth] for row in rows])
            products = np.arange(depth) + offset  # the warm start's first residual costs one product
            ax.plot(products, np.median(curves, axis=0), color=colour, label=f"{start} start (median)")
            ax.fill_between(products, *np.percentile(curves, [25, 75], axis=0), color=colour, alpha=0.2)
        ax.set_yscale("log")
        ax.set_xlabel("Fisher-vector products")
        ax.set_ylabel("||g - F x|| / ||g||")
        ax.set_title(f"{result['env']} ({len(rows)} updates)")
        ax.legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", default=["Hopper-v5"])
    parser.add_argument("--updates", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "cg_residuals.json")
    parser.add_argument("--plot", type=Path, default=ROOT / "docs" / "images" / "cg_residuals.png")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="recipe overrides (YAML values)")
    parser.add_argument("--summary", action="store_true", help="print the summary of --out's results; train nothing")
    args = parser.parse_args(argv)
    overrides = recipe_overrides(parser, "--set", args.set)
    if args.summary:
        for result in json.loads(args.out.read_text())["results"]:
            print("\n".join(summary(result)) + "\n")
        return
    results = [measure(env_id, args.updates, args.seed, overrides) for env_id in args.envs]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    command = (
        "python -m benchmarks.cg_residuals --envs " + " ".join(args.envs) + f" --updates {args.updates} --seed {args.seed}"
    ) + "".join(f" {shlex.quote(pair)}" for pair in (["--set", *args.set] if args.set else []))
    machine = {"cpu": cpu_name(), "python": platform.python_version(), "torch": th.__version__}
    args.out.write_text(json.dumps({"command": command, "machine": machine, "results": results}) + "\n")
    plot(results, args.plot)
    for result in results:
        print("\n".join(summary(result)) + "\n")
    print(f"raw results: {args.out}; plot: {args.plot}")


if __name__ == "__main__":
    main()
