"""How long until a policy lifts 90 % of held-out cubes? Training wall-clock to the first evaluation at 0.90.

    python -m benchmarks.time_to_grasp --algo trpo_plus --seeds 0 1 2 3 4 --budget 300
    python -m benchmarks.time_to_grasp --algo ppo --seeds 0 1 2 3 4 --budget 300
    python -m benchmarks.time_to_grasp report            # table and plot of every folder under --out
    python -m benchmarks.time_to_grasp report --compare trpo_plus_reuse trpo_plus_fast   # P(X > Y) with its interval

Each (algorithm, seed) trains the recipe of ``--env`` (``make_model``: zoo_hyperparams/<algo>.yml on the batched
engine, ``--sim-threads`` physics threads; ``--set key=value`` overrides a recipe key, the value a YAML scalar)
from the start of ``learn``. Every ``--eval-every`` env steps it pauses the clock and evaluates the deterministic
policy on ``--eval-episodes`` held-out episodes of the env as registered (no training aids; env ``i`` reset with
seed ``1,000,000 + i``, the same episodes at every evaluation, the training ``VecNormalize`` statistics frozen),
then trains on until ``--budget`` seconds of training wall-clock have passed. The evaluation's own time is
recorded beside, never counted. With rollout workers (the recipe's ``rollout_workers``, or ``--workers BACKEND:N``
as ``make_model``'s) a segment the workers collect while the learner updates (``overlap_collection``) is waited for
on the training clock before each evaluation; ``--set rollout_workers=null overlap_collection=false`` trains the
recipe on the learner's own batched envs. One CSV per run: ``<out>/<name>/seed<k>.csv`` (``--name``: default the algorithm).

Each run's JSON keeps its env steps per training second and the medians of the per-iteration update time and
rollout-worker timings (``PHASES``). ``report`` prints, per name, the median env steps/s, the median (with its 95 %
bootstrap interval over seeds) and every seed's training seconds (and env steps) to the first evaluation at or
above 0.90, and whether it stays there to the end of the budget; the plot shows success against training
wall-clock, one line per seed (``<out>/time_to_grasp.png``); ``--compare X Y`` adds the probability that a run of
folder X learns faster than one of folder Y, by the area under its success curve over env steps and over training
seconds, with rliable's 95 % interval. Measure with nothing else running.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from benchmarks.machine import cpu_name

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "time_to_grasp"
EVAL_SEED = 1_000_000
TARGET = 0.90
FIELDS = ("timesteps", "train_seconds", "eval_seconds", "success", "mean_return")
PHASES = ("train/update_time", "workers/collect_steps_per_s", "workers/wait_ms")
"""Logged per iteration (TRPOPlus; rollout workers) and kept as medians in each run's JSON: where the time goes."""


def plain(value: Any) -> str:
    """A recipe's parsed value as JSON text: a class (an activation function, a wrapper) by its import path."""
    return f"{value.__module__}.{value.__qualname__}" if isinstance(value, type) else str(value)


def phase_recorder(phases: dict[str, list[float]]) -> Any:
    """A callback that appends, at the end of every rollout, the ``PHASES`` the logger holds then (the last update's
    time, the collection's worker timings) to ``phases``."""
    from stable_baselines3.common.callbacks import BaseCallback

    class PhaseRecorder(BaseCallback):
        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            for key in PHASES:
                value = self.logger.name_to_value.get(key)
                if value is not None:
                    phases.setdefault(key, []).append(float(value))

    return PhaseRecorder()


def evaluate_held_out(model: Any, env_id: str, episodes: int, statistics: Any) -> tuple[float, float]:
    """(success rate, mean return) of the deterministic policy on ``episodes`` held-out episodes: one batched
    simulation per episode, env ``i`` reset with seed ``EVAL_SEED + i``, each counted at its first episode's end."""
    from grasp_envs import make_batch_env
    from sb3_trpo_plus.application.evaluation import frozen_normalization

    env: Any = make_batch_env(env_id, episodes, seed=EVAL_SEED)
    if statistics is not None:  # the training statistics, frozen; rewards stay the env's
        env = frozen_normalization(env, statistics)
    observations = env.reset()
    done = np.zeros(episodes, dtype=bool)
    successes, returns = np.zeros(episodes), np.zeros(episodes)
    while not done.all():
        actions, _ = model.predict(observations, deterministic=True)
        observations, _, dones, infos = env.step(actions)
        for i in np.flatnonzero(dones & ~done):
            successes[i] = float(infos[i].get("is_success", False))
            returns[i] = float(infos[i]["episode"]["r"])
        done |= dones
    env.close()
    return float(successes.mean()), float(returns.mean())


def run(algo: str, seed: int, args: argparse.Namespace, overrides: dict[str, Any]) -> Path:
    import torch as th

    from sb3_trpo_plus import make_model, recipe
    from sb3_trpo_plus.rollouts import RolloutWorkers, rollout_workers

    th.set_num_threads(1)
    model = make_model(args.env, algo=algo, seed=seed, sim_threads=args.sim_threads, workers=args.workers, **overrides)
    if args.algo_class is not None:  # the same envs and recipe, trained by the subclass with its own arguments
        env = model.get_env()
        constructor = recipe(args.env, algo).replace(**overrides).constructor_arguments()
        model = algorithm_class(args.algo_class, algo)(model.policy_class, env, seed=seed, **constructor, **args.class_kwargs)
    pool = rollout_workers(model.get_env())  # type: ignore[arg-type]
    folder = args.out / (args.name or algo)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"seed{seed}.csv"
    statistics = model.get_vec_normalize_env()
    rows: list[dict[str, Any]] = []
    phases: dict[str, list[float]] = {}
    recorder = phase_recorder(phases)
    trained = 0.0
    while trained < args.budget:
        start = time.perf_counter()
        model.learn(args.eval_every, reset_num_timesteps=not rows, callback=recorder)
        if pool is not None and isinstance(pool[0], RolloutWorkers):  # a segment ordered during the last update is
            pool[0].wait_segments()  # collected on the training clock
        trained += time.perf_counter() - start
        start = time.perf_counter()
        success, mean_return = evaluate_held_out(model, args.env, args.eval_episodes, statistics)
        rows.append(
            {
                "timesteps": model.num_timesteps,
                "train_seconds": round(trained, 2),
                "eval_seconds": round(time.perf_counter() - start, 2),
                "success": success,
                "mean_return": round(mean_return, 3),
            }
        )
        print(f"{algo} seed {seed}: {model.num_timesteps:>8} steps, {trained:6.1f} s, success {success:.2f}", flush=True)
    with path.open("w", newline="") as file:
        writer = csv.DictWriter(file, FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    trained_recipe = {**recipe(args.env, algo), **overrides}
    settings = {
        "env": args.env,
        "algo": algo,
        "seed": seed,
        "budget": args.budget,
        "eval_every": args.eval_every,
        "eval_episodes": args.eval_episodes,
        "sim_threads": args.sim_threads,
        "workers": args.workers or trained_recipe.get("rollout_workers"),
        "overrides": overrides,
        "algo_class": args.algo_class,
        "class_kwargs": args.class_kwargs,
        "recipe": trained_recipe,
        "env_steps_per_s": round(model.num_timesteps / trained),
        "phase_medians": {key: round(float(np.median(values)), 4) for key, values in phases.items()},
        "machine": {"cpu": cpu_name(), "python": platform.python_version(), "torch": th.__version__},
    }
    (folder / f"seed{seed}.json").write_text(json.dumps(settings, indent=1, default=plain) + "\n")
    env = model.get_env()
    if env is not None:
        env.close()
    return path


def first_at_target(rows: Sequence[dict[str, float]]) -> tuple[float, int, bool] | None:
    """(training seconds, env steps) of the first evaluation at or above the target, and whether every later one
    stays there; None where none reaches it."""
    for index, row in enumerate(rows):
        if row["success"] >= TARGET:
            held = all(later["success"] >= TARGET for later in rows[index:])
            return row["train_seconds"], int(row["timesteps"]), held
    return None


def median_interval(values: Sequence[float], resamples: int = 20_000, seed: int = 0) -> tuple[float, float]:
    """95 % percentile-bootstrap interval of the median of ``values`` (one per seed): how far the seeds at hand let
    the median move. ``resamples`` draws of as many seeds with replacement, from a generator seeded with ``seed``."""
    if len(values) == 0:
        raise ValueError("median_interval needs at least one value")
    draws = np.random.default_rng(seed).choice(np.asarray(values, dtype=np.float64), size=(resamples, len(values)))
    low, high = np.percentile(np.median(draws, axis=1), [2.5, 97.5])
    return float(low), float(high)


def seed_number(path: Path) -> int:
    """The seed of a run's file ``seed<k>.csv``: runs are listed in seed order (seed2 before seed10)."""
    return int(path.stem.removeprefix("seed"))


def sample_area(rows: Sequence[dict[str, float]], max_steps: float) -> float:
    """Learning speed in samples: the mean success over the evaluations at or before ``max_steps`` env steps (every
    run of the benchmark evaluates at the same step counts, so runs compared up to one ``max_steps`` share them)."""
    return float(np.mean([row["success"] for row in rows if row["timesteps"] <= max_steps]))


def time_area(rows: Sequence[dict[str, float]], seconds: float) -> float:
    """Learning speed in wall-clock: the mean over ``[0, seconds)`` of the success of the latest evaluation so far
    (0 before the first), i.e. the area under the success-against-training-seconds step curve over ``seconds``."""
    times = np.array([0.0] + [row["train_seconds"] for row in rows if row["train_seconds"] < seconds] + [seconds])
    values = np.array([0.0] + [row["success"] for row in rows if row["train_seconds"] < seconds])
    return float(np.sum(np.diff(times) * values) / seconds)


def comparison_lines(runs: dict[str, dict[str, list[dict[str, float]]]], pairs: Sequence[tuple[str, str]]) -> list[str]:
    """P(X > Y) with rliable's 95 % stratified-bootstrap interval for each pair of result folders, scored by the area
    under success against env steps (over the steps every run of both reached) and against training seconds (over
    the seconds every run of both trained)."""
    from rliable import metrics

    from benchmarks.report import interval_estimates

    lines = [
        "| X > Y | seeds | P(X > Y), success area over env steps | P(X > Y), success area over training seconds |",
        "|---|---|---|---|",
    ]
    for a, b in pairs:
        for name in (a, b):
            if name not in runs or not runs[name]:
                raise ValueError(f"--compare {a} {b}: no runs of {name!r} (result folders: {sorted(runs)})")
        both = [*runs[a].values(), *runs[b].values()]
        max_steps = min(rows[-1]["timesteps"] for rows in both)
        seconds = min(rows[-1]["train_seconds"] for rows in both)
        cells = []
        for score, limit, unit in (
            (sample_area, max_steps, f"{max_steps / 1e6:.2f}M steps"),
            (time_area, seconds, f"{seconds:.0f} s"),
        ):
            x = np.array([[score(rows, limit)] for rows in runs[a].values()])
            y = np.array([[score(rows, limit)] for rows in runs[b].values()])
            point, interval = interval_estimates({"pair": (x, y)}, metrics.probability_of_improvement)
            low, high = float(np.squeeze(interval["pair"][0])), float(np.squeeze(interval["pair"][1]))
            cells.append(f"{float(np.squeeze(point['pair'])):.2f} [{low:.2f}, {high:.2f}] (to {unit})")
        lines.append(f"| {a} > {b} | {len(runs[a])} / {len(runs[b])} | {cells[0]} | {cells[1]} |")
    return lines


def read(path: Path) -> list[dict[str, float]]:
    with path.open() as file:
        return [{key: float(value) for key, value in row.items()} for row in csv.DictReader(file)]


def report(
    out: Path, pairs: Sequence[tuple[str, str]] = (), only: Sequence[str] = (), plot: str = "time_to_grasp.png"
) -> None:
    """Per result folder (``only`` these, where given) the median and every seed's time to the target, and the plot;
    for each of ``pairs`` the probability that a run of the first folder learns faster than one of the second
    (``comparison_lines``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = sorted(folder for folder in out.iterdir() if folder.is_dir() and (not only or folder.name in only))
    missing = sorted(set(only) - {folder.name for folder in names})
    if missing:
        raise ValueError(f"no result folder {', '.join(missing)} under {out}")
    fig, axes = plt.subplots(1, max(len(names), 1), figsize=(5 * max(len(names), 1), 3.6), squeeze=False)
    for ax, folder in zip(axes[0], names, strict=False):
        runs = {path.stem: read(path) for path in sorted(folder.glob("seed*.csv"), key=seed_number)}
        reached = {seed: first_at_target(rows) for seed, rows in runs.items()}
        times = [r[0] for r in reached.values() if r is not None]
        cells = [
            f"{seed}: {r[0]:.0f} s / {r[1]:,} steps{'' if r[2] else ' (not held)'}" if r else f"{seed}: not reached"
            for seed, r in reached.items()
        ]
        median = f"{np.median(times):.0f} s" if len(times) == len(runs) and times else "not every seed reached it"
        if len(times) == len(runs) and len(times) > 1:
            low, high = median_interval(times)
            median += f" (95 % bootstrap interval over seeds {low:.0f}-{high:.0f} s)"
        speeds = [rows[-1]["timesteps"] / rows[-1]["train_seconds"] for rows in runs.values() if rows]
        speed = f"{np.median(speeds) / 1e3:.1f}k" if speeds else "no"
        print(f"{folder.name} ({speed} env steps/s): median {median}; " + "; ".join(cells))
        for seed, rows in runs.items():
            ax.plot([r["train_seconds"] for r in rows], [r["success"] for r in rows], marker=".", label=seed)
        ax.axhline(TARGET, color="k", linestyle=":", linewidth=1)
        ax.set_xlabel("training wall-clock (s)")
        ax.set_ylabel("held-out success")
        ax.set_title(folder.name)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / plot, dpi=110)
    print(f"plot: {out / plot}")
    if pairs:
        folders = [folder for folder in out.iterdir() if folder.is_dir()]
        all_runs = {folder.name: {path.stem: read(path) for path in sorted(folder.glob("seed*.csv"))} for folder in folders}
        print("\n".join(comparison_lines(all_runs, pairs)))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", nargs="?", choices=("run", "report"), default="run")
    parser.add_argument("--env", default="Grasper3D-v7")
    parser.add_argument("--algo", default="trpo_plus", choices=("trpo_plus", "trpo", "ppo"))
    parser.add_argument("--name", default=None, help="the results folder (default: the algorithm)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--budget", type=float, default=300.0, help="training wall-clock seconds per run")
    parser.add_argument("--eval-every", type=int, default=50_000)
    parser.add_argument("--eval-episodes", type=int, default=50)
    parser.add_argument("--sim-threads", type=int, default=1)
    parser.add_argument("--workers", default=None, metavar="BACKEND:N", help="collect with N rollout workers (make_model)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="recipe overrides (YAML values)")
    parser.add_argument(
        "--algo-class", default=None, metavar="MODULE.CLASS", help="a subclass of --algo's class that trains instead"
    )
    parser.add_argument(
        "--class-set", nargs="*", default=[], metavar="KEY=VALUE", help="--algo-class's own arguments (YAML values)"
    )
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument(
        "--compare",
        nargs=2,
        action="append",
        default=[],
        metavar=("X", "Y"),
        help="report: P(X > Y) between two result folders (repeatable)",
    )
    parser.add_argument("--only", nargs="+", default=[], metavar="NAME", help="report: these result folders only")
    parser.add_argument("--plot", default="time_to_grasp.png", help="report: the plot's file name under --out")
    args = parser.parse_args(argv)
    if args.command == "report":
        report(args.out, [tuple(pair) for pair in args.compare], args.only, args.plot)
        return
    if args.compare or args.only or args.plot != "time_to_grasp.png":
        parser.error("--compare, --only and --plot are report options")
    overrides = recipe_overrides(parser, "--set", args.set)
    args.class_kwargs = recipe_overrides(parser, "--class-set", args.class_set)
    if args.class_kwargs and args.algo_class is None:
        parser.error("--class-set sets the arguments of --algo-class")
    for seed in args.seeds:
        print(f"wrote {run(args.algo, seed, args, overrides)}", flush=True)


def recipe_overrides(parser: argparse.ArgumentParser, option: str, pairs: Sequence[str]) -> dict[str, Any]:
    """``KEY=VALUE`` texts (``--set``) as a dict, each value read as YAML; a text without ``=`` is a usage error."""
    values: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep:
            parser.error(f"{option} takes KEY=VALUE, got {pair!r}")
        values[key] = yaml.safe_load(text)
    return values


def algorithm_class(path: str, algo: str) -> Any:
    """The class ``module.Class``, which must subclass ``algo``'s."""
    import importlib

    from sb3_trpo_plus.application.zoo import algorithms

    module, _, name = path.rpartition(".")
    if not module:
        raise ValueError(f"--algo-class takes MODULE.CLASS, got {path!r}")
    cls = getattr(importlib.import_module(module), name)
    base = algorithms()[algo]
    if not (isinstance(cls, type) and issubclass(cls, base)):
        raise ValueError(f"--algo-class {path} is not a subclass of {base.__name__} (--algo {algo})")
    return cls


if __name__ == "__main__":
    main()
