"""The convergence study's job runner: one (env, variant, seed) trained in chunks, and the scheduler of many.

A job trains in chunks of budget / CHUNKS steps; after each it evaluates the policy (benchmarks/protocol.py), saves
the model and the VecNormalize statistics atomically and appends a row to its progress.csv (benchmarks/runs.py). A
job run again continues from its last row.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.builders import (
    algorithm_class,
    evaluation_env,
    model_settings,
    training_envs,
    use_zero_start_in_sb3_contrib_trpo,
)
from benchmarks.protocol import EVAL_EPISODES, EVAL_SEED, evaluate
from benchmarks.runs import DIAGNOSTICS, append_row, atomic_replace, job_folder, keep_checkpoint, read_progress
from benchmarks.study import BUDGETS, TARGETS, VARIANTS

CHUNKS = 25
# the settings a variant may change on a checkpoint it resumes (branches from): the trust region, the batch, the memory
BRANCH_SETTINGS = ("target_kl", "n_steps", "replay_memory")


def run_job(
    env_id: str, variant: str, seed: int, steps: int, out: Path, keep: Path | None = None, vec_env: str = "dummy"
) -> None:
    """Train one (env, variant, seed) to ``steps`` in chunks, resuming from the last saved chunk.

    With ``keep``, every chunk's checkpoint and CSV are also copied to ``keep/<timesteps>/<env>/<variant>/seed<k>``.
    """
    import torch as th
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus.application.callbacks import EpisodeStats

    th.set_num_threads(1)
    if VARIANTS[variant].zero_cg_start:
        use_zero_start_in_sb3_contrib_trpo()
    folder = job_folder(out, env_id, variant, seed)
    folder.mkdir(parents=True, exist_ok=True)
    rows = read_progress(folder)
    done = int(rows[-1]["timesteps"]) if rows else 0
    if done >= steps:
        return
    if rows and not (folder / "model.zip").exists():  # a committed CSV of an unfinished run, without its checkpoint
        print(f"{folder}: no checkpoint to resume from, starting again", flush=True)
        (folder / "progress.csv").unlink()
        rows, done = [], 0
    config = model_settings(env_id, variant)
    algo_class = algorithm_class(variant)
    # Monitor records the success flag of the tasks that have one (Gymnasium's locomotion tasks have none)
    monitor = {"info_keywords": ("is_success",)} if env_id in TARGETS else None
    venv = training_envs(env_id, variant, seed + 100_000 * len(rows), monitor_kwargs=monitor, vec_env=vec_env)
    model_path, stats_path = folder / "model.zip", folder / "vecnormalize.pkl"
    if rows:
        env = VecNormalize.load(str(stats_path), venv) if config.normalize else venv
        # a variant's own BRANCH_SETTINGS (a target_kl schedule, say) apply to a checkpoint it resumes, so that a run
        # can branch from another variant's checkpoint; every other setting is the checkpoint's
        # (resolved on this env: a value written {times_zoo: ...} in study.yml is the zoo's value times its factor)
        overrides = VARIANTS[variant].hyperparameters
        branch = {key: config.kwargs[key] for key in BRANCH_SETTINGS if key in overrides} or None
        model = algo_class.load(model_path, env=env, device="cpu", custom_objects=branch)
        model.__dict__.pop("train", None)  # a checkpoint that holds a wrapper of train() (as below) resumes unwrapped
    else:
        env = VecNormalize(venv, **config.normalize_kwargs) if config.normalize_kwargs is not None else venv
        model = algo_class(config.policy, env, seed=seed, device="cpu", verbose=0, **config.kwargs)
    # the training VecNormalize: the evaluation env takes its settings and shares its observation statistics
    eval_env = evaluation_env(env_id, variant, EVAL_SEED, env if config.normalize else None)
    diagnostics: dict[str, list[float]] = {name: [] for name in DIAGNOSTICS}
    overshoots: list[float] = []  # each TRPO update's KL over its trust region's radius
    original_train = model.train

    def train_and_record() -> None:  # the update's logged values, read before SB3 dumps the logger
        original_train()
        values = model.logger.name_to_value
        for name, key in DIAGNOSTICS.items():
            if key in values:
                diagnostics[name].append(float(values[key]))
        # TRPOPlus logs each update's radius (target_kl may be a schedule); sb3-contrib's TRPO has a constant one
        radius = float(values.get("train/target_kl", getattr(model, "target_kl", None) or 0.0))
        if radius > 0 and "train/kl_divergence_loss" in values:
            overshoots.append(float(values["train/kl_divergence_loss"]) / radius)

    model.train = train_and_record
    # the CSV is the study's log; SB3's default logger (verbose 0, no TensorBoard) would make an empty folder
    # <tempdir>/SB3-<date> at every chunk's learn(): 25-40 per run
    model.set_logger(Logger(folder=None, output_formats=[]))
    progress_over_budget(model, max(BUDGETS.get(env_id, steps), steps))

    chunk = max(steps // CHUNKS, 1)
    seconds = rows[-1]["train_seconds"] if rows else 0.0
    resumed = 1.0 if rows else 0.0
    while done < steps:
        recorder = EpisodeStats()
        start = time.perf_counter()
        model.learn(min(chunk, steps - done), callback=recorder, reset_num_timesteps=False)
        seconds += time.perf_counter() - start
        done = int(model.num_timesteps)
        eval_return, eval_success = evaluate(model, eval_env, EVAL_EPISODES)
        returns = [r for r, _, _ in recorder.episodes]
        successes = [float(s) for _, s, _ in recorder.episodes]
        means = {name: float(np.mean(v)) if v else float("nan") for name, v in diagnostics.items()}
        overshoot = max(overshoots) if overshoots else float("nan")
        overshoots.clear()
        for values in diagnostics.values():
            values.clear()
        row = {
            "timesteps": done,
            "train_seconds": round(seconds, 2),
            "eval_success": eval_success,
            "eval_return": round(eval_return, 4),
            "train_success": float(np.mean(successes)) if successes else float("nan"),
            "train_return": round(float(np.mean(returns)), 4) if returns else float("nan"),
            "train_episodes": len(returns),
            **{k: round(v, 5) for k, v in means.items()},
            "kl_overshoot": round(overshoot, 4),
            "resumed": resumed,
        }
        resumed = 0.0
        # not the wrappers of train() and of the progress
        atomic_replace(lambda p: model.save(p, exclude=["train", "_update_current_progress_remaining"]), model_path)
        if config.normalize:
            atomic_replace(lambda p: env.save(str(p)), stats_path)
        append_row(folder / "progress.csv", row)
        if keep is not None:
            keep_checkpoint(folder, job_folder(keep / str(done), env_id, variant, seed))
    env.close()
    eval_env.close()


def progress_over_budget(model: Any, budget: int) -> None:
    """Make ``model``'s remaining progress (what SB3's schedules read) ``1 - timesteps / budget``.

    SB3 measures it against the ``total_timesteps`` of the running ``learn`` call; a job learns in chunks, and
    may stop at ``--steps`` and later resume to the budget, so a schedule would restart with every chunk. Against
    the env's study budget, it runs once over the whole run, however the run is cut.
    """

    def update(num_timesteps: int, total_timesteps: int) -> None:
        model._current_progress_remaining = 1.0 - float(num_timesteps) / float(budget)

    model._update_current_progress_remaining = update


def run_study(
    envs: Sequence[str],
    variants: Sequence[str],
    seeds: Sequence[int],
    jobs: int,
    out: Path,
    steps: int | None,
    keep: Path | None = None,
    vec_env: str = "dummy",
) -> None:
    """Run every unfinished job, ``jobs`` at a time, each in its own process (``python -m benchmarks.convergence job``)."""
    todo = []
    for env_id in envs:
        budget = steps or BUDGETS[env_id]
        for seed in seeds:
            for variant in variants:
                rows = read_progress(job_folder(out, env_id, variant, seed))
                if not rows or rows[-1]["timesteps"] < budget:
                    todo.append((env_id, variant, seed, budget))
    print(f"{len(todo)} unfinished jobs", flush=True)
    root = Path(__file__).resolve().parents[1]

    def launch(job: tuple[str, str, int, int]) -> None:
        env_id, variant, seed, budget = job
        command = [
            sys.executable,
            "-m",
            "benchmarks.convergence",
            "job",
            "--env",
            env_id,
            "--variant",
            variant,
            "--seed",
            str(seed),
            "--steps",
            str(budget),
            "--out",
            str(out),
        ]
        if keep is not None:
            command += ["--keep-checkpoints", str(keep)]
        command += ["--vec-env", vec_env]
        start = time.time()
        result = subprocess.run(command, capture_output=True, text=True, cwd=root)
        status = "ok" if result.returncode == 0 else f"FAILED ({result.returncode}):\n{result.stderr[-2000:]}"
        print(f"{env_id} {variant} seed{seed}: {time.time() - start:.0f} s {status}", flush=True)

    with ThreadPoolExecutor(jobs) as pool:
        list(pool.map(launch, todo))
