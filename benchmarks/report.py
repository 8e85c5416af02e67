"""The convergence study's report: figures, tables, rliable aggregates, and the export of trained agents.

    python -m benchmarks.convergence report     # docs/results-tables.md, docs/images/, docs/results.md's block
    python -m benchmarks.convergence agents     # the best TRPOPlus run of each env into trained_agents/

``report`` writes the generated tables page, docs/results-tables.md, whole (per env: learning curves, every
variant's table, the target seed by seed, per-update diagnostics; then the rliable aggregates), and fills the one
marked block of the findings page, docs/results.md: an index of the tables page and the shipped agents.

Reads only the committed per-run CSVs (benchmarks/results/convergence/<env>/<variant>/seed<k>/progress.csv and
reevaluation.csv), so the report can be rebuilt on any machine; ``export_agents`` also needs the runs' saved models.
Each variant is named by its study.yml label.
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import unicodedata
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.protocol import (
    CONFIRMATION_EPISODES,
    CONFIRMATION_SEEDS,
    EVAL_EPISODES,
    REEVALUATION_EPISODES,
    REEVALUATION_SEED,
    reevaluations,
    seed_verdict,
)
from benchmarks.runs import job_folder, read_progress, read_reevaluation
from benchmarks.study import (
    BUDGET_COMPARISONS,
    BUDGETS,
    COMPARISONS,
    LABELS,
    RETURN_TARGETS,
    ROOT,
    STUDY_VARIANTS,
    TARGET_HELD,
    TARGET_WITHIN,
    TARGETS,
    VARIANTS,
    BudgetComparison,
    hyperparameters,
)
from grasp_envs import RECOMMENDED_GRASPER

# the findings page's generated block (an index of the tables page, the shipped agents); the rest of it is written by hand
BEGIN, END = "<!-- convergence-report:begin -->", "<!-- convergence-report:end -->"
TABLES_PAGE = "results-tables.md"  # the generated tables page, written whole, beside the findings page
COMMAND = "python -m benchmarks.convergence report"
AGENT_EPISODES = 20
BOOTSTRAP_SEED = 0
# the reset seed of the shipped agents' AGENT_EPISODES-episode evaluation, also the first reset seed of the 100-episode
# re-evaluations (protocol.REEVALUATION_SEED); not a reset seed of training (a run's seed + 100,000 per resumption,
# + the env's index) nor of the study's 20-episode evaluations (protocol.EVAL_SEED)
AGENT_SEED = 20_000
# the keys export_agents writes in an agents.json entry; merged_entry keeps the entry's others (added by hand)
EXPORTED_KEYS = (
    "variant",
    "seed",
    "timesteps",
    "study_eval_success",
    "success_rate",
    "mean_reward",
    "episodes",
    "eval_seed",
    "platform",
    "env_kwargs",
    "video",
)


def complete_runs(out: Path, env_id: str, variant: str) -> dict[int, list[dict[str, float]]]:
    """{seed: rows} of the runs of (env, variant) that reached the env's budget, in the order of the seeds."""
    runs = {}
    for folder in sorted((out / env_id / variant).glob("seed*"), key=lambda f: int(f.name[4:])):  # seed2 < seed10
        rows = read_progress(folder)
        if rows and rows[-1]["timesteps"] >= BUDGETS[env_id]:
            runs[int(folder.name[4:])] = rows
    return runs


def target_of(env_id: str) -> tuple[str, float]:
    """The evaluation column an env's target is read in and its value: the success rate, or for a task without a
    success flag (Gymnasium's locomotion) the return."""
    if env_id in TARGETS:
        return "eval_success", TARGETS[env_id]
    return "eval_return", RETURN_TARGETS[env_id]


def steps_to_target(rows: list[dict[str, float]], target: float, key: str = "eval_success") -> tuple[float, float]:
    """(timesteps, training seconds) of the first evaluation with ``key`` >= target; nan if never."""
    for row in rows:
        if row[key] >= target:
            return row["timesteps"], row["train_seconds"]
    return float("nan"), float("nan")


def _curve(rows: list[dict[str, float]], key: str, grid: np.ndarray) -> np.ndarray:
    steps = np.array([0.0] + [row["timesteps"] for row in rows])
    start = 0.0 if key == "eval_success" else rows[0][key]
    return np.interp(grid, steps, np.array([start] + [row[key] for row in rows]))


def figure(
    env_id: str,
    runs: dict[str, dict[int, list[dict[str, float]]]],
    path: Path,
    budget: float | None = None,
    labels: dict[str, str] | None = None,
) -> None:
    """Learning curves of ``runs`` ({variant: {seed: rows}}) over ``budget`` env steps (by default the env's), each
    named by ``labels`` (by default the variants' study labels)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    shown = sum(1 for seeds in runs.values() if seeds)
    legend = 0.18 * shown + 0.2  # inches below the plots: one line per variant, so that long labels never cover a curve
    fig, axes = plt.subplots(1, 2, figsize=(11, 4 + legend))
    grid = np.linspace(0, BUDGETS[env_id] if budget is None else budget, 101)
    labels = LABELS if labels is None else labels
    colors = [plt.get_cmap("tab10")(i) for i in range(10)]
    for i, (variant, seeds) in enumerate((v, s) for v, s in runs.items() if s):
        color, style = colors[i % 10], ("-", "--", ":")[i // 10 % 3]  # past ten variants the colours repeat dashed
        for ax, key in zip(axes, ("eval_return", "eval_success"), strict=True):
            curves = np.array([_curve(rows, key, grid) for rows in seeds.values()])
            mean, std = curves.mean(axis=0), curves.std(axis=0)
            ax.plot(grid, mean, color=color, linestyle=style, label=f"{labels[variant]} ({len(seeds)})")
            ax.fill_between(grid, mean - std, mean + std, color=color, alpha=0.2)
    axes[0].set_ylabel(f"evaluation return ({EVAL_EPISODES} episodes)")
    axes[1].set_ylabel("evaluation success rate")
    key, target = target_of(env_id)
    axes[0 if key == "eval_return" else 1].axhline(target, color="k", linestyle=":", linewidth=1)
    axes[1].set_ylim(-0.05, 1.05)
    for ax in axes:
        ax.set_xlabel("env steps")
        ax.grid(alpha=0.3)
    fig.legend(*axes[1].get_legend_handles_labels(), loc="lower center", fontsize=8, frameon=False)
    fig.suptitle(f"{env_id}: deterministic evaluation, mean ± std over seeds")
    fig.tight_layout(rect=(0.0, legend / (4 + legend), 1.0, 1.0))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt(values: list[float], digits: int = 2) -> str:
    finite = [v for v in values if np.isfinite(v)]
    if not finite:
        return "—"
    return f"{np.mean(finite):.{digits}f} ± {np.std(finite):.{digits}f}"


def _median_reached(values: list[float], scale: float, unit: str) -> str:
    reached = [v for v in values if np.isfinite(v)]
    if not reached:
        return f"never (0/{len(values)})"
    return f"{np.median(reached) / scale:.{0 if unit == 's' else 2}f}{unit} ({len(reached)}/{len(values)})"


def tables(env_id: str, runs: dict[str, dict[int, list[dict[str, float]]]]) -> list[str]:
    key, target = target_of(env_id)
    if key == "eval_return":
        return return_tables(runs, target)
    lines = [
        f"| variant | seeds | final success | best success | final return | steps to {target:.0%} | "
        f"train time to {target:.0%} | train time (total) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for variant, seeds in runs.items():
        if not seeds:
            continue
        rows = list(seeds.values())
        reached = [steps_to_target(r, target) for r in rows]
        lines.append(
            f"| {LABELS[variant]} | {len(rows)} | {_fmt([r[-1]['eval_success'] for r in rows])} | "
            f"{_fmt([max(x['eval_success'] for x in r) for r in rows])} | {_fmt([r[-1]['eval_return'] for r in rows])} | "
            f"{_median_reached([s for s, _ in reached], 1e6, 'M')} | {_median_reached([t for _, t in reached], 1, 's')} | "
            f"{_fmt([r[-1]['train_seconds'] for r in rows], 0)} s |"
        )
    return lines


def return_tables(runs: dict[str, dict[int, list[dict[str, float]]]], target: float) -> list[str]:
    """The table of a task scored by its return: final and best evaluation return, the area under the return curve
    (the mean over the evaluations: sample efficiency), and the steps and training time to ``target``."""
    lines = [
        f"| variant | seeds | final return | best return | return area | steps to {target:g} | train time to {target:g} "
        "| train time (total) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for variant, seeds in runs.items():
        if not seeds:
            continue
        rows = list(seeds.values())
        reached = [steps_to_target(r, target, "eval_return") for r in rows]
        lines.append(
            f"| {LABELS[variant]} | {len(rows)} | {_fmt([r[-1]['eval_return'] for r in rows], 0)} | "
            f"{_fmt([max(x['eval_return'] for x in r) for r in rows], 0)} | "
            f"{_fmt([float(np.mean([x['eval_return'] for x in r])) for r in rows], 0)} | "
            f"{_median_reached([s for s, _ in reached], 1e6, 'M')} | {_median_reached([t for _, t in reached], 1, 's')} | "
            f"{_fmt([r[-1]['train_seconds'] for r in rows], 0)} s |"
        )
    return lines


def _steps(timesteps: float) -> str:
    return f"{timesteps / 1e6:g}M" if timesteps >= 1e6 else f"{timesteps / 1e3:g}k"


def _seed_count(chosen: set[int], total: int) -> str:
    """``3 of 5 (0, 2, 4)``: how many of ``total`` seeds are ``chosen``, and which, unless none or all."""
    named = f" ({', '.join(map(str, sorted(chosen)))})" if 0 < len(chosen) < total else ""
    return f"{len(chosen)} of {total}{named}"


def _evaluations_within(rows: list[dict[str, float]], timesteps: float) -> int:
    """How many of a run's evaluations count as within ``timesteps``: those up to it, and the first past it when none
    is at it (a chunk ends on a whole rollout, so a 300k budget's last evaluation can come at 301,056 steps)."""
    n = sum(row["timesteps"] <= timesteps for row in rows)
    return n if n and rows[n - 1]["timesteps"] == timesteps else min(n + 1, len(rows))


def target_table(env_id: str, runs: dict[str, dict[int, list[dict[str, float]]]], out: Path) -> list[str]:
    """The target, seed by seed: which seeds reach it within ``TARGET_WITHIN`` and, on the envs of
    ``TARGET_HELD``, stay at or above it at every evaluation after that (both: the target met), how many of those
    evaluations are, and how many of the checkpoints after it are on ``REEVALUATION_EPISODES`` episodes where
    ``python -m benchmarks.convergence reevaluate`` evaluated them again (its default reset seed)."""
    target, within = TARGETS[env_id], TARGET_WITHIN[env_id]
    held = env_id in TARGET_HELD
    header = f"| variant | seeds | ≥ {target:.0%} within {_steps(within)} |"
    if held:
        header += (
            f" ≥ {target:.0%} at every evaluation after {_steps(within)} | both | evaluations after {_steps(within)}"
            f" ≥ {target:.0%} | on {REEVALUATION_EPISODES} episodes: checkpoints after {_steps(within)} ≥ {target:.0%} |"
            f" every checkpoint after {_steps(within)} ≥ {target:.0%} on {REEVALUATION_EPISODES} episodes, or on"
            f" {REEVALUATION_EPISODES + len(CONFIRMATION_SEEDS) * CONFIRMATION_EPISODES} where those fall below |"
        )
    lines = [header, "|---" * header.count(" | ") + "|---|"]
    for variant, seeds in runs.items():
        if not seeds:
            continue
        split = {s: _evaluations_within(rows, within) for s, rows in seeds.items()}
        reached = {s for s, n in split.items() if any(r["eval_success"] >= target for r in seeds[s][:n])}
        cells = [LABELS[variant], str(len(seeds)), _seed_count(reached, len(seeds))]
        if held:
            after = {s: [r["eval_success"] for r in seeds[s][n:]] for s, n in split.items()}
            stayed = {s for s, values in after.items() if all(v >= target for v in values)}
            again = {}
            for s in seeds:
                last_within = seeds[s][split[s] - 1]["timesteps"]
                rows = reevaluations(out, env_id, variant, s, REEVALUATION_EPISODES, REEVALUATION_SEED, last_within)
                if rows:
                    again[s] = [r["eval_success"] for r in rows]
            passed = sum(v >= target for values in after.values() for v in values)
            again_passed = sum(v >= target for values in again.values() for v in values)
            again_cell = "—"
            if again:
                every = {s for s, values in again.items() if all(v >= target for v in values)}
                again_cell = (
                    f"{again_passed} of {sum(map(len, again.values()))} (seeds {', '.join(map(str, again))}; "
                    f"every one: {_seed_count(every, len(again))})"
                )
            verdicts = {
                s: seed_verdict(read_reevaluation(out, env_id, variant, s), [r["timesteps"] for r in seeds[s][n:]], target)
                for s, n in split.items()
            }
            confirmation_cell = "—"  # the confirmation protocol's verdicts
            if any(verdict is not None for verdict in verdicts.values()):
                confirmation_cell = _seed_count({s for s, v in verdicts.items() if v}, len(seeds)) + " pass"
                for word, value in (("fail", False), ("not yet decided", None)):
                    if which := [str(s) for s in sorted(verdicts) if verdicts[s] is value]:
                        confirmation_cell += f"; {word}: {', '.join(which)}"
            cells += [
                _seed_count(stayed, len(seeds)),
                _seed_count(reached & stayed, len(seeds)),
                f"{passed} of {sum(map(len, after.values()))}",
                again_cell,
                confirmation_cell,
            ]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def diagnostics_table(runs: dict[str, dict[int, list[dict[str, float]]]]) -> list[str]:
    keys = [
        "kl_overshoot",
        "line_search_steps",
        "cg_residual",
        "cg_relative_residual",
        "step_gradient_cosine",
        "warm_start_cosine",
        "replay_ess",
    ]
    lines = ["| variant | " + " | ".join(keys) + " |", "|---" * (len(keys) + 1) + "|"]
    for variant, seeds in runs.items():
        if not seeds:
            continue
        cells = []
        for key in keys:
            values = [float(np.nanmean([row.get(key, np.nan) for row in rows])) for rows in seeds.values()]
            cells.append(_fmt(values, 3))
        lines.append(f"| {LABELS[variant]} | " + " | ".join(cells) + " |")
    return lines


def success_score(rows: list[dict[str, float]], kind: str) -> float:
    """A run's evaluation success: at the end of the budget (``final``) or its mean over the run (``area``)."""
    successes = [row["eval_success"] for row in rows]
    return successes[-1] if kind == "final" else float(np.mean(successes))


def interval_estimates(score_dict: dict[str, Any], statistic: Any) -> Any:
    """rliable's point estimates and 95 % stratified-bootstrap intervals (2,000 resamples), repeatable."""
    from rliable import library as rly

    # rliable's StratifiedBootstrap draws from numpy's global generator (and arch's from random_state):
    # seed both, so that regenerating the report gives the same intervals
    np.random.seed(BOOTSTRAP_SEED)
    return rly.get_interval_estimates(score_dict, statistic, reps=2000, random_state=np.random.RandomState(BOOTSTRAP_SEED))


THESIS_PAIRS = (
    ("replay", "plain"),
    ("warm", "plain"),
    ("both", "plain"),
    ("both", "replay"),
    ("both", "warm"),
    ("replay", "trpo"),
    ("replay", "ppo"),
    ("plain", "trpo"),
)
"""The probabilities of improvement of the thesis' study (its variants: ``STUDY_VARIANTS``)."""

REUSE_VARIANTS = ("generalized_reuse", "plain", "trpo", "ppo")
REUSE_PAIRS = (("generalized_reuse", "plain"), ("generalized_reuse", "trpo"), ("generalized_reuse", "ppo"))
"""Generalized sample reuse against plain TRPOPlus, sb3-contrib TRPO and PPO."""


def rliable_section(
    all_runs: dict[str, dict[str, dict[int, list[dict[str, float]]]]],
    min_seeds: int = 5,
    extra_pairs: Sequence[tuple[str, str]] = (),
    variants: Sequence[str] = STUDY_VARIANTS,
    pairs: Sequence[tuple[str, str]] = THESIS_PAIRS,
) -> list[str]:
    """IQM with stratified-bootstrap 95 % CIs and probability of improvement over the envs where every one of
    ``variants`` finished ``min_seeds`` seeds (by default the thesis' study variants; the diagnosis variants have
    runs on one env only), for ``pairs`` of them.

    ``extra_pairs`` (e.g. a diagnosis variant against the study variant it modifies) join the probability-of-
    improvement table where both have ``min_seeds`` finished seeds on every env of the section.
    """
    from rliable import metrics

    envs = [env for env in all_runs if min(len(all_runs[env].get(v, {})) for v in variants) >= min_seeds]  # finished
    if not envs:
        return [f"No env has {min_seeds} finished seeds of every variant yet."]
    n_seeds = min(len(all_runs[env][v]) for env in envs for v in variants)

    def scores(variant: str, kind: str) -> np.ndarray:
        matrix = np.zeros((n_seeds, len(envs)))
        for j, env in enumerate(envs):
            for i, rows in enumerate(list(all_runs[env][variant].values())[:n_seeds]):
                matrix[i, j] = success_score(rows, kind)
        return matrix

    lines = [
        f"Tasks: {', '.join(envs)}; {n_seeds} seeds per variant; score = evaluation success rate "
        "(final: at the end of the budget; area: mean over the 25 evaluations, i.e. sample efficiency). "
        "IQM and 95 % stratified-bootstrap confidence intervals from rliable (2,000 resamples).",
        "",
        "| variant | IQM final success [95 % CI] | IQM success area [95 % CI] |",
        "|---|---|---|",
    ]

    estimates = {}
    for kind in ("final", "area"):
        score_dict = {v: scores(v, kind) for v in variants}
        point, interval = interval_estimates(score_dict, lambda x: np.array([metrics.aggregate_iqm(x)]))
        estimates[kind] = (point, interval)
    for v in variants:
        cells = []
        for kind in ("final", "area"):
            point, interval = estimates[kind]
            cells.append(f"{point[v][0]:.3f} [{interval[v][0][0]:.3f}, {interval[v][1][0]:.3f}]")
        lines.append(f"| {LABELS[v]} | {cells[0]} | {cells[1]} |")
    pairs = [(a, b) for a, b in pairs if a in variants and b in variants]
    pairs += [(a, b) for a, b in extra_pairs if all(len(all_runs[env].get(v, {})) >= n_seeds for env in envs for v in (a, b))]
    if pairs:
        lines += ["", "| P(X > Y), success area | estimate [95 % CI] |", "|---|---|"]
        pair_scores = {f"{a},{b}": (scores(a, "area"), scores(b, "area")) for a, b in pairs}
        point, interval = interval_estimates(pair_scores, metrics.probability_of_improvement)
        for a, b in pairs:
            key = f"{a},{b}"
            lines.append(
                f"| {LABELS[a]} > {LABELS[b]} | {float(np.squeeze(point[key])):.2f} "
                f"[{float(np.squeeze(interval[key][0])):.2f}, {float(np.squeeze(interval[key][1])):.2f}] |"
            )
    return lines


def area_score(env_id: str, rows: list[dict[str, float]]) -> float:
    """A run's learning speed in its env's own measure: the mean over its evaluations of the success rate, or of the
    return where the task has no success flag."""
    key, _ = target_of(env_id)
    return float(np.mean([row[key] for row in rows]))


def improvement_section(
    all_runs: dict[str, dict[str, dict[int, list[dict[str, float]]]]],
    pairs: Sequence[tuple[str, str]],
    min_seeds: int = 5,
) -> list[str]:
    """Probability of improvement P(X > Y) on the area of each task's own measure (success rate, or return), per task
    and over the tasks where both variants of every pair finished ``min_seeds`` seeds. P(X > Y) compares runs within
    a task only (rliable averages the per-task probabilities), so tasks scored in different units pool."""
    from rliable import metrics

    variants = sorted({v for pair in pairs for v in pair})
    envs = [env for env in all_runs if min(len(all_runs[env].get(v, {})) for v in variants) >= min_seeds]
    if not envs:
        return [f"No env has {min_seeds} finished seeds of every variant yet."]
    n_seeds = min(len(all_runs[env][v]) for env in envs for v in variants)

    def scores(variant: str, tasks: Sequence[str]) -> np.ndarray:
        matrix = np.zeros((n_seeds, len(tasks)))
        for j, env in enumerate(tasks):
            for i, rows in enumerate(list(all_runs[env][variant].values())[:n_seeds]):
                matrix[i, j] = area_score(env, rows)
        return matrix

    groups = [("every task", envs)] + [(env, [env]) for env in envs]
    lines = [
        f"Tasks: {', '.join(envs)}; {n_seeds} seeds per variant; score = area under the task's own curve (mean over "
        "the evaluations of the success rate, or of the return on a task without a success flag). 95 % "
        "stratified-bootstrap confidence intervals from rliable (2,000 resamples).",
        "",
        "| P(X > Y), area | " + " | ".join(name for name, _ in groups) + " |",
        "|---|" + "---|" * len(groups),
    ]
    for a, b in pairs:
        cells = []
        for _, tasks in groups:
            pair = {"pair": (scores(a, tasks), scores(b, tasks))}
            point, interval = interval_estimates(pair, metrics.probability_of_improvement)
            low, high = float(np.squeeze(interval["pair"][0])), float(np.squeeze(interval["pair"][1]))
            cells.append(f"{float(np.squeeze(point['pair'])):.2f} [{low:.2f}, {high:.2f}]")
        lines.append(f"| {LABELS[a]} > {LABELS[b]} | " + " | ".join(cells) + " |")
    return lines


def runs_within(out: Path, env_id: str, variant: str, budget: int) -> dict[int, list[dict[str, float]]]:
    """{seed: rows} of the runs of (env, variant) that reached ``budget``, each cut to its evaluations within it
    (``_evaluations_within``), in the order of the seeds."""
    runs = {}
    for folder in sorted((out / env_id / variant).glob("seed*"), key=lambda f: int(f.name[4:])):
        rows = read_progress(folder)
        if rows and rows[-1]["timesteps"] >= budget:
            runs[int(folder.name[4:])] = rows[: _evaluations_within(rows, budget)]
    return runs


def median_steps(rows_by_seed: Sequence[list[dict[str, float]]], target: float) -> float:
    """The median over seeds of the env steps to the first evaluation at ``target``, a seed that never reached it
    counting as infinitely many (so that the median is infinite once half the seeds never reached it)."""
    return float(np.median([np.nan_to_num(steps_to_target(rows, target)[0], nan=np.inf) for rows in rows_by_seed]))


def budget_comparison_section(out: Path, comparison: BudgetComparison, image: Path, page: Path) -> list[str]:
    """study.yml's budget comparison: both sides' runs cut to ``comparison.budget`` steps (a table, their learning
    curves in ``image``), the ratio of their median steps to the target, and P(variant > baseline) by the success area
    with rliable's 95 % interval, over as many seeds of each as both have (the first, in seed order)."""
    from rliable import metrics

    sides = {"variant": (comparison.env, comparison.variant), "baseline": (comparison.baseline_env, comparison.baseline)}
    runs = {side: runs_within(out, env_id, name, comparison.budget) for side, (env_id, name) in sides.items()}
    labels = {side: f"{LABELS[name]} on {env_id}" for side, (env_id, name) in sides.items()}
    budget, target = comparison.budget, TARGETS[comparison.env]
    if not all(runs.values()):
        missing = [labels[side] for side, seeds in runs.items() if not seeds]
        return [f"No run to {_steps(budget)} yet of {' and of '.join(missing)}."]
    figure(comparison.env, runs, image, budget=budget, labels=labels)
    lines = [
        f"Both sides' runs cut at {budget:,} env steps (their evaluations within it).",
        "",
        f"![learning curves to {_steps(budget)}]({Path(os.path.relpath(image, page.parent)).as_posix()})",
        "",
        f"| variant | seeds | success at {_steps(budget)} | success area to {_steps(budget)} | steps to {target:.0%} | "
        f"train time to {target:.0%} |",
        "|---|---|---|---|---|---|",
    ]
    for side, seeds in runs.items():
        rows = list(seeds.values())
        reached = [steps_to_target(r, target) for r in rows]
        lines.append(
            f"| {labels[side]} | {_seed_ranges(list(seeds))} | {_fmt([r[-1]['eval_success'] for r in rows])} | "
            f"{_fmt([success_score(r, 'area') for r in rows])} | {_median_reached([s for s, _ in reached], 1e6, 'M')} | "
            f"{_median_reached([t for _, t in reached], 1, 's')} |"
        )
    medians = {side: median_steps(list(seeds.values()), target) for side, seeds in runs.items()}
    n = min(len(seeds) for seeds in runs.values())
    scores = tuple(np.array([[success_score(rows, "area")] for rows in list(runs[side].values())[:n]]) for side in sides)
    point, interval = interval_estimates({"pair": scores}, metrics.probability_of_improvement)
    low, high = (float(np.squeeze(bound)) for bound in interval["pair"])
    ratio = medians["variant"] / medians["baseline"] if np.isfinite(medians["baseline"]) else float("nan")
    return [
        *lines,
        "",
        f"Median steps to {target:.0%} over every seed (a seed that never reached it counts as never): "
        f"{medians['variant'] / 1e6:.2f}M against {medians['baseline'] / 1e6:.2f}M, {ratio:.2f} times the baseline's. "
        f"P(the first > the second), success area to {_steps(budget)}, over the first {n} seeds of each: "
        f"{float(np.squeeze(point['pair'])):.2f} [{low:.2f}, {high:.2f}] (rliable, 2,000 resamples).",
    ]


def anchor(heading: str) -> str:
    """The id the docs give a heading (Python-Markdown's toc slugify, which mkdocs uses)."""
    text = unicodedata.normalize("NFKD", heading).encode("ascii", "ignore").decode("ascii")
    return re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", text).strip().lower())


def _seed_ranges(seeds: Sequence[int]) -> str:
    """``0-9, 12``: sorted seeds with runs of consecutive ones as ranges."""
    spans: list[list[int]] = []
    for seed in sorted(seeds):
        if spans and seed == spans[-1][1] + 1:
            spans[-1][1] = seed
        else:
            spans.append([seed, seed])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in spans)


def tables_header(findings: str = "results.md") -> list[str]:
    """The top of the generated tables page: what it is, which command writes it, from what."""
    return [
        "# Results: generated tables",
        "",
        f"<!-- Generated by `{COMMAND}` (benchmarks/report.py): edit the code, not this page. -->",
        "",
        f"This page is generated: `{COMMAND}` writes it, and the figures `docs/images/results_*.png`, from the"
        " committed per-run CSVs (`benchmarks/results/convergence/<env>/<variant>/seed<k>/progress.csv` and"
        f" `reevaluation.csv`). What the tables show is on [Results]({findings}); the machines and versions of the"
        f" runs are under [Machine and versions]({findings}#machine-and-versions).",
        "",
        f"Per env: the learning curves (deterministic evaluation on {EVAL_EPISODES} episodes, mean ± std over seeds);"
        " every variant's final and best success, final return, median steps and train time to the env's target, and"
        " its total train time (mean ± std over seeds); the target, seed by seed; the per-update diagnostics. Then the"
        " rliable aggregates.",
        "",
        "The diagnostics: `kl_overshoot`, the largest KL between successive policies among the updates between two"
        " evaluations over `target_kl` (generalized reuse steps within its own radius, `target_kl / B²`, a quarter of"
        " it at B = 2, or less with `reuse_kl_vary`); `line_search_steps`, the backtracking line search's tries per"
        " update (1: the full step); `cg_residual` and `cg_relative_residual`, the conjugate gradient's final residual"
        " ‖Fx - g‖ and that over ‖g‖; `step_gradient_cosine`, the cosine between the step and the gradient;"
        " `warm_start_cosine`, between the warm start and the step; `replay_ess`, Kish's effective sample size of the"
        " surrogate's sample weights over the number of samples (the batch weights times the importance ratios under"
        " generalized reuse, 0.83 at B = 2 when every ratio is 1; the replayed samples' importance weights under the"
        " replay memory; 1: on-policy).",
        "",
    ]


def tables_index(
    envs: Sequence[tuple[str, Sequence[int]]], aggregates: Sequence[tuple[str, str]], page: str = TABLES_PAGE
) -> list[str]:
    """The findings page's links to the sections of the generated tables page: (env, its seeds with finished runs),
    then (title, heading) of the rliable aggregates."""
    lines = ["| env | budget (env steps) | seeds |", "|---|---|---|"]
    for env_id, seeds in envs:
        cell = _seed_ranges(seeds) if seeds else "no run to the budget yet"
        lines.append(f"| [{env_id}]({page}#{anchor(env_id)}) | {BUDGETS[env_id]:,} | {cell} |")
    links = "; ".join(f"[{title}]({page}#{anchor(heading)})" for title, heading in aggregates)
    return [*lines, "", f"rliable aggregates: {links}.", ""]


def write_report(out: Path, docs: Path, tables_page: Path | None = None) -> None:
    """Write the generated tables page (``tables_page``, by default ``TABLES_PAGE`` beside ``docs``) whole, the figures
    (``images/`` beside ``docs``), and ``docs``' block between ``BEGIN`` and ``END``: the index of the tables page and
    the shipped agents. The rest of ``docs``, the findings, is left as it is."""
    tables_page = tables_page or docs.with_name(TABLES_PAGE)
    text = docs.read_text()
    if BEGIN not in text or END not in text:
        raise SystemExit(f"{docs} has no {BEGIN} ... {END} block to fill")
    findings = Path(os.path.relpath(docs, tables_page.parent)).as_posix()
    images = docs.parent / "images"
    all_runs: dict[str, dict[str, dict[int, list[dict[str, float]]]]] = {}
    index: list[tuple[str, list[int]]] = []
    body: list[str] = []
    for env_id in BUDGETS:
        runs = {variant: complete_runs(out, env_id, variant) for variant in VARIANTS}
        if not any(runs.values()):
            index.append((env_id, []))
            body += [f"## {env_id}", "", f"No finished runs yet (budget {BUDGETS[env_id]:,} steps).", ""]
            continue
        all_runs[env_id] = runs
        seeds = sorted({s for v in runs.values() for s in v})
        index.append((env_id, seeds))
        image = images / f"results_{env_id}.png"
        figure(env_id, runs, image)
        hours = sum(rows[-1]["train_seconds"] for v in runs.values() for rows in v.values()) / 3600
        body += [
            f"## {env_id}",
            "",
            f"Budget {BUDGETS[env_id]:,} env steps; seeds {', '.join(map(str, seeds))}; "
            f"{hours:.2f} h of training in all (one CPU thread per run, mostly two runs at a time; "
            f"exceptions under [Machine and versions]({findings}#machine-and-versions)).",
            "",
            f"![{env_id} learning curves]({Path(os.path.relpath(image, tables_page.parent)).as_posix()})",
            "",
            *tables(env_id, runs),
            "",
            *(["The target, seed by seed:", "", *target_table(env_id, runs, out), ""] if env_id in TARGETS else []),
            "Per-update diagnostics (mean over each run's updates, then mean ± std over seeds):",
            "",
            *diagnostics_table(runs),
            "",
        ]
    aggregates = [("over the envs with 5 finished seeds of every variant", "Aggregate (rliable)")]
    scored_by_success = {env_id: runs for env_id, runs in all_runs.items() if env_id in TARGETS}
    body += ["## Aggregate (rliable)", "", *rliable_section(scored_by_success), ""]
    aggregates.append(("generalized sample reuse against plain TRPOPlus, TRPO and PPO", "Generalized sample reuse"))
    section = rliable_section(scored_by_success, variants=REUSE_VARIANTS, pairs=REUSE_PAIRS)
    body += ["## Generalized sample reuse", "", *section, ""]
    aggregates.append(("generalized sample reuse on every task, success or return", "Generalized sample reuse, every task"))
    body += ["## Generalized sample reuse, every task", "", *improvement_section(all_runs, REUSE_PAIRS), ""]
    for i, comparison in enumerate(BUDGET_COMPARISONS):  # study.yml's, across env ids or budgets
        heading = (
            f"{LABELS[comparison.variant]} on {comparison.env} against {LABELS[comparison.baseline]} on "
            f"{comparison.baseline_env}, to {_steps(comparison.budget)}"
        )
        aggregates.append((heading, heading))
        image = images / f"results_budget_comparison_{i}.png"
        body += [f"## {heading}", "", *budget_comparison_section(out, comparison, image, tables_page), ""]
    for env_id, runs in all_runs.items():  # the envs with 10 seeds of every study variant, on their own
        if min(len(runs.get(v, {})) for v in STUDY_VARIANTS) >= 10:
            pairs = [(comparison.variant, comparison.baseline) for comparison in COMPARISONS]  # study.yml's
            section = rliable_section({env_id: runs}, min_seeds=10, extra_pairs=pairs)
            aggregates.append((f"{env_id}, 10 seeds", f"{env_id}, 10 seeds"))
            body += [f"### {env_id}, 10 seeds", "", *section, ""]
    tables_page.write_text("\n".join([*tables_header(findings), *body]).rstrip("\n") + "\n")
    page = Path(os.path.relpath(tables_page, docs.parent)).as_posix()
    block = [*tables_index(index, aggregates, page), *agents_section(ROOT / "trained_agents" / "agents.json")]
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    docs.write_text(head + BEGIN + "\n" + "\n".join(block) + "\n" + END + tail)
    print(f"wrote {tables_page}, {images}/results_*.png and {docs}'s generated block")


RECIPE = "recipe"
"""An agents.json entry's ``variant`` for an agent trained by ``trpo-plus train`` with the zoo YAML's recipe (its
``command``: the command line that trained it, where it is not ``trpo-plus train --env <env> --seed <seed>``)."""


def agents_section(manifest_path: Path) -> list[str]:
    """Table of the shipped agents (tests/test_trained_agents.py checks each row against a fresh evaluation)."""
    if not manifest_path.exists():
        return []
    manifest = json.loads(manifest_path.read_text())
    more = f"success_rate_{REEVALUATION_EPISODES}"  # a re-evaluation on more episodes from the same seed, where run
    counts = f"{AGENT_EPISODES} and on {REEVALUATION_EPISODES}" if any(more in e for e in manifest.values()) else ""
    lines = [
        "## Trained agents",
        "",
        f"`trained_agents/trpo_plus/<env>_1/`: the best TRPOPlus run of each env (highest final evaluation success),"
        f" re-evaluated on {counts or AGENT_EPISODES} deterministic episodes of an env seeded once with {AGENT_SEED}"
        f" (not a seed the study's {EVAL_EPISODES}-episode evaluations use). `trpo-plus enjoy --env <env>` runs them"
        " (it falls back to `trained_agents/` when `logs/` has no run); `trpo-plus record-video --env <env>` films"
        " them. An agent trained on an env made with env kwargs keeps them in its `config.yml`, and both commands make"
        " the env with them, as rl-zoo3's enjoy does.",
        "",
        f"| env | env kwargs | variant | seed | steps | success rate ({AGENT_EPISODES} episodes) | mean return |"
        + (f" success rate ({REEVALUATION_EPISODES} episodes) |" if counts else "")
        + " video |",
        "|---" * (9 if counts else 8) + "|",
    ]
    for env_id, entry in sorted(manifest.items()):
        video = f"[mp4]({entry['video']})" if "video" in entry else "—"
        kwargs = ", ".join(f"`{key}={value!r}`" for key, value in entry.get("env_kwargs", {}).items()) or "—"
        again = (f" {entry[more]:.2f} |" if more in entry else " — |") if counts else ""
        if entry["variant"] == RECIPE:  # trained by `trpo-plus train` with the YAML's recipe, not a study variant
            label = f"the recipe of `zoo_hyperparams/trpo_plus.yml` (`trpo-plus train --env {env_id}`)"
        else:
            label = LABELS[entry["variant"]]
            if env_id == RECOMMENDED_GRASPER and not entry.get("env_kwargs"):
                label = f"the recipe of `zoo_hyperparams/trpo_plus.yml` ({label})"
        lines.append(
            f"| `{env_id}` | {kwargs} | {label} | {entry['seed']} | {entry['timesteps']:,} | "
            f"{entry['success_rate']:.2f} | {entry['mean_reward']:.2f} |{again} {video} |"
        )
    for env_id, entry in sorted(manifest.items()):
        if "held_out" in entry:  # episodes that played no part in picking the agent
            held_out = entry["held_out"]
            lifted = round(held_out["success_rate"] * held_out["episodes"])
            command = entry.get("command", f"trpo-plus train --env {env_id} --seed {entry['seed']}")
            origin = (
                f"`{env_id}`'s agent is the one run of `{command}`."
                if entry["variant"] == RECIPE
                else f"`{env_id}`'s agent is seed {entry['seed']} of its variant's runs, picked by the"
                f" {REEVALUATION_EPISODES}-episode evaluation above."
            )
            lines += [
                "",
                f"{origin} On {held_out['episodes']} further episodes that played no part in picking"
                f" it (reset seeds from {held_out['eval_seed']:,}) it succeeds {lifted} times"
                f" ({held_out['success_rate']:.3f}).",
            ]
    for env_id, entry in sorted(manifest.items()):
        if "video" in entry:
            kwargs = ", ".join(f"`{key}={value!r}`" for key, value in entry.get("env_kwargs", {}).items())
            title = f"{env_id} ({kwargs})" if kwargs else env_id  # the env the agent was trained and filmed on
            lines += ["", f"{title}:", "", f'<video src="{entry["video"]}" controls loop muted width="360"></video>']
    return [*lines, ""]


# ---------------------------------------------------------------------------------------------- agents
def evaluate_agent(folder: Path, env_id: str, episodes: int = AGENT_EPISODES, seed: int = AGENT_SEED) -> dict[str, float]:
    """Deterministic success rate and mean return of an exported agent over ``episodes`` episodes, the env seeded once
    with ``seed`` (as the study evaluates)."""
    from sb3_trpo_plus.application.evaluation import evaluate_agent as evaluate
    from sb3_trpo_plus.application.run_folders import load_trained

    model, env, _ = load_trained("trpo_plus", env_id, str(folder), 1, False, seed, False)
    result = evaluate(model, env, episodes, seed, seed_every_episode=False)
    env.close()
    return {"success_rate": result.success_rate, "mean_reward": result.mean_return}


def not_an_agent(variant: str) -> str | None:
    """Why ``variant``'s runs cannot be shipped as an agent (``config.yml`` holds plain values), or None. A variant's
    env_kwargs go into ``config.yml``, which ``trpo-plus enjoy`` and the agent test make the env with."""
    if callable(VARIANTS[variant].hyperparameters.get("target_kl")):
        return "a target_kl schedule, which config.yml cannot hold"
    return None


def export_agents(out: Path, envs: list[str], folder: Path) -> None:
    """Copy the best finished TRPOPlus run of each env into rl-zoo's layout under ``folder``; record its success."""
    manifest_path = folder / "agents.json"
    manifest: dict[str, Any] = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    for env_id in envs:
        candidates, without_checkpoint, not_agents = [], [], []
        for variant in (name for name, v in VARIANTS.items() if v.algo == "trpo_plus"):
            runs = complete_runs(out, env_id, variant)
            reason = not_an_agent(variant)
            if runs and reason:
                not_agents.append(f"{variant} ({reason})")
                continue
            for seed, rows in runs.items():
                if not (job_folder(out, env_id, variant, seed) / "model.zip").exists():  # checkpoints are not committed
                    without_checkpoint.append(f"{variant} seed {seed} ({rows[-1]['eval_success']:.2f})")
                    continue
                candidates.append((rows[-1]["eval_success"], rows[-1]["eval_return"], variant, seed))
        if without_checkpoint:
            print(f"{env_id}: finished runs without a local checkpoint, not exported: {', '.join(without_checkpoint)}")
        if not_agents:
            print(f"{env_id}: variants whose runs cannot be shipped: {', '.join(not_agents)}")
        if not candidates:
            print(f"{env_id}: no finished TRPOPlus run with a checkpoint")
            continue
        success, _, variant, seed = max(candidates)
        source = job_folder(out, env_id, variant, seed)
        run = folder / "trpo_plus" / f"{env_id}_1"
        (run / env_id).mkdir(parents=True, exist_ok=True)
        from sb3_trpo_plus import TRPOPlus

        model = TRPOPlus.load(source / "model.zip", device="cpu")
        model.__dict__.pop("train", None)  # a checkpoint may hold the runner's wrapper of train(): not the agent's
        model.save(run / f"{env_id}.zip", exclude=["train", "rollout_memory"])  # small: no replay memory
        params = hyperparameters(VARIANTS[variant], env_id)
        config = {key: value for key, value in params.items() if key not in {"callback", "monitor_kwargs", "policy_kwargs"}}
        if (source / "vecnormalize.pkl").exists():
            shutil.copyfile(source / "vecnormalize.pkl", run / env_id / "vecnormalize.pkl")
        (run / env_id / "config.yml").write_text(json.dumps(config, indent=1))  # JSON is YAML
        result = evaluate_agent(folder, env_id)
        exported = {
            "variant": variant,
            "seed": seed,
            "timesteps": BUDGETS[env_id],
            "study_eval_success": success,
            "success_rate": result["success_rate"],
            "mean_reward": round(result["mean_reward"], 3),
            "episodes": AGENT_EPISODES,
            "eval_seed": AGENT_SEED,
            "platform": platform.platform(),
        }
        if config.get("env_kwargs"):
            exported["env_kwargs"] = config["env_kwargs"]
        print(f"{env_id}: {variant} seed {seed}: success {result['success_rate']:.2f}, return {result['mean_reward']:.2f}")
        from sb3_trpo_plus.application.cli import record_video

        video = ROOT / "docs" / "videos" / f"{env_id}.mp4"
        record_video(["--env", env_id, "-f", str(folder), "--exp-id", "1", "--seed", str(AGENT_SEED), "-o", str(video)])
        exported["video"] = f"videos/{video.name}"
        manifest[env_id] = merged_entry(manifest.get(env_id, {}), exported)
        partial = manifest_path.with_suffix(".json.tmp")  # after every agent, atomically
        partial.write_text(json.dumps(manifest, indent=1) + "\n")
        partial.replace(manifest_path)


def merged_entry(entry: dict[str, Any], exported: dict[str, Any]) -> dict[str, Any]:
    """An agents.json entry updated with an export: the EXPORTED_KEYS of ``exported`` replace the entry's (its
    env_kwargs dropped where the export has none). Every other key of the entry (added by hand, e.g. ``held_out``) is
    kept in its place where the export is the entry's run (variant, seed, timesteps), and dropped, with a note, where it
    is another run: it describes the agent it replaces."""
    run = ("variant", "seed", "timesteps")
    merged = {key: value for key, value in entry.items() if key not in EXPORTED_KEYS or key in exported}
    added = [key for key in merged if key not in EXPORTED_KEYS]
    if added and any(entry.get(key) != exported[key] for key in run):
        print(f"another run than the one agents.json describes: dropped its {', '.join(added)}")
        merged = {key: value for key, value in merged.items() if key in EXPORTED_KEYS}
    merged.update(exported)
    return merged
