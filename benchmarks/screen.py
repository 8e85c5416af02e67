"""Short-budget screens of study variants against a baseline, from the convergence study's runs.

    python -m benchmarks.screen --envs HalfCheetah-v5 Hopper-v5 --variants generalized_reuse_ppo_policy \\
        --baseline plain --others generalized_reuse ppo --steps 327680 [--seeds 0 1 2] [--out FILE.md]

Each run is cut at its last evaluation within ``--steps`` (the runs of ``benchmarks.convergence`` evaluate every
budget / 25 steps, so a 1M run is screened at 327,680 steps from its 8th evaluation on). Per env and variant: the
seeds, the mean return at the cut and the area (mean of the evaluations up to the cut); then P(X > baseline) on the
area with rliable's 95 % stratified-bootstrap interval, per env and over the envs (rliable averages the per-env
probabilities). A variant screens on the seeds every variant of the table has reached the cut with.

Several ``--baseline`` variants are peers: on each env the baseline is the one with the larger mean area at the cut
(``--baseline ppo ppo_trpo_plus_settings``: the better PPO on each task), and the screen says which it is.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from benchmarks.report import interval_estimates, read_progress
from benchmarks.study import LABELS

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "convergence"


def cut(rows: list[dict[str, float]], steps: int) -> list[dict[str, float]] | None:
    """The evaluations within ``steps``; None when the run has not reached within one chunk of ``steps``."""
    within = [row for row in rows if row["timesteps"] <= steps]
    if not within or (len(within) == len(rows) and rows[-1]["timesteps"] < 0.95 * steps):
        return None
    return within


def area(rows: list[dict[str, float]]) -> float:
    """A run's area up to the cut: the mean of its evaluations' returns."""
    return float(np.mean([row["eval_return"] for row in rows]))


def screen(
    envs: Sequence[str],
    variants: Sequence[str],
    baseline: str | Sequence[str],
    steps: int,
    seeds: Sequence[int] | None,
    out: Path,
) -> list[str]:
    """The screen's markdown: one table of returns, one of P(X > baseline); several baselines are peers, the one with
    the larger mean area on each env its baseline."""
    from rliable import metrics

    peers = [baseline] if isinstance(baseline, str) else list(baseline)
    everyone = list(dict.fromkeys([*peers, *variants]))
    runs: dict[str, dict[str, dict[int, list[dict[str, float]]]]] = {}
    for env in envs:
        runs[env] = {}
        for variant in everyone:
            kept = {}
            for folder in sorted((out / env / variant).glob("seed*"), key=lambda f: int(f.name[4:])):
                seed, part = int(folder.name[4:]), cut(read_progress(folder), steps)
                if part is not None and (seeds is None or seed in seeds):
                    kept[seed] = part
            runs[env][variant] = kept
    lines = [
        f"Cut at {steps:,} env steps. Return at the cut: mean over seeds (min-max); area: mean of the evaluations up to "
        "the cut.",
        "",
        "| env | variant | seeds | return at the cut | area |",
        "|---|---|---|---|---|",
    ]
    mean_area: dict[tuple[str, str], float] = {}  # (env, variant) -> the mean area over its seeds at the cut
    for env in envs:
        for variant in everyone:
            kept = runs[env][variant]
            if not kept:
                lines.append(f"| {env} | {LABELS[variant]} | none yet | | |")
                continue
            final = [rows[-1]["eval_return"] for rows in kept.values()]
            areas = [area(rows) for rows in kept.values()]
            mean_area[env, variant] = float(np.mean(areas))
            lines.append(
                f"| {env} | {LABELS[variant]} | {' '.join(map(str, sorted(kept)))} | {np.mean(final):,.0f} "
                f"({min(final):,.0f}-{max(final):,.0f}) | {mean_area[env, variant]:,.0f} |"
            )
    # each env's baseline: the peer with the larger mean area (a peer without runs at the cut never is)
    chosen = {env: max(peers, key=lambda peer: mean_area.get((env, peer), -np.inf)) for env in envs}
    name = LABELS[peers[0]] if len(peers) == 1 else "the better of " + " and ".join(LABELS[peer] for peer in peers)
    if len(peers) > 1:
        lines += [
            "",
            "Baseline on each env (the larger mean area): " + "; ".join(f"{env}: {LABELS[chosen[env]]}" for env in envs) + ".",
        ]
    lines += ["", f"| P(X > {name}), area | " + " | ".join([*envs, "over the envs"]) + " |"]
    lines.append("|---|" + "---|" * (len(envs) + 1))
    for variant in [v for v in variants if v not in peers]:
        n = min(min(len(runs[env][variant]), len(runs[env][chosen[env]])) for env in envs)
        if n < 2:
            lines.append(f"| {LABELS[variant]} | " + " | ".join(["fewer than 2 seeds"] * (len(envs) + 1)) + " |")
            continue

        def scores(names: dict[str, str], tasks: Sequence[str], count: int = n) -> np.ndarray:
            matrix = np.zeros((count, len(tasks)))
            for j, env in enumerate(tasks):
                for i, rows in enumerate(list(runs[env][names[env]].values())[:count]):
                    matrix[i, j] = area(rows)
            return matrix

        cells = []
        for tasks in [[env] for env in envs] + [list(envs)]:
            pair = (scores(dict.fromkeys(envs, variant), tasks), scores(chosen, tasks))
            point, interval = interval_estimates({"pair": pair}, metrics.probability_of_improvement)
            low, high = (float(np.squeeze(interval["pair"][k])) for k in (0, 1))
            cells.append(f"{float(np.squeeze(point['pair'])):.2f} [{low:.2f}, {high:.2f}]")
        lines.append(f"| {LABELS[variant]} ({n} seeds) | " + " | ".join(cells) + " |")
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", nargs="+", required=True)
    parser.add_argument("--variants", nargs="+", required=True, help="the levers screened")
    parser.add_argument(
        "--baseline",
        nargs="+",
        required=True,
        help="the variant each lever is compared with; several: peers, the one with the larger mean area on each env",
    )
    parser.add_argument("--others", nargs="*", default=[], help="variants shown beside them (compared too)")
    parser.add_argument("--steps", type=int, required=True, help="the screen's budget (env steps)")
    parser.add_argument("--seeds", type=int, nargs="+", default=None, help="default: every seed that reached the cut")
    parser.add_argument("--runs", type=Path, default=OUT, help="the study's folder (default: benchmarks/results/convergence)")
    parser.add_argument("--out", type=Path, default=None, help="also write the tables to this markdown file")
    args = parser.parse_args(argv)
    unknown = sorted(set([*args.variants, *args.baseline, *args.others]) - set(LABELS))
    if unknown:
        parser.error(f"unknown variants {unknown}")
    lines = screen(args.envs, [*args.variants, *args.others], args.baseline, args.steps, args.seeds, args.runs)
    text = "\n".join(lines) + "\n"
    sys.stdout.write(text)
    if args.out is not None:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
