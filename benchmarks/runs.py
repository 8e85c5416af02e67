"""The convergence study's results folder: one folder per run, <out>/<env>/<variant>/seed<k>/, holding

- ``progress.csv``: a row per chunk (COLUMNS), written by the runner;
- ``reevaluation.csv``: evaluations of its checkpoints on more episodes (REEVALUATION_COLUMNS), by the protocol;
- ``model.zip`` and ``vecnormalize.pkl``: the last checkpoint (git-ignored).

Reading and writing those files, atomically; nothing here trains or evaluates.
"""

from __future__ import annotations

import csv
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

OUT = Path(__file__).resolve().parent / "results" / "convergence"
# Per-update diagnostics read from the logger after each policy update (mean over the chunk's updates).
DIAGNOSTICS = {
    "kl": "train/kl_divergence_loss",
    "line_search_success": "train/is_line_search_success",
    "line_search_steps": "train/line_search_steps",
    "cg_residual": "train/cg_residual",
    "cg_relative_residual": "train/cg_relative_residual",
    "step_gradient_cosine": "train/step_gradient_cosine",
    "warm_start_cosine": "train/cg_warm_start_cosine",
    "replay_ess": "train/replay_ess",
    "std": "train/std",
}
COLUMNS = [
    "timesteps",
    "train_seconds",
    "eval_success",
    "eval_return",
    "train_success",
    "train_return",
    "train_episodes",
    *DIAGNOSTICS,
    "kl_overshoot",
    "resumed",
]
REEVALUATION_COLUMNS = ["timesteps", "episodes", "reset_seed", "eval_success", "eval_return"]
CHECKPOINT_FILES = ("model.zip", "vecnormalize.pkl")


def job_folder(out: Path, env_id: str, variant: str, seed: int) -> Path:
    return out / env_id / variant / f"seed{seed}"


def read_progress(folder: Path, name: str = "progress.csv") -> list[dict[str, float]]:
    """The rows of a run's CSV (``progress.csv``, or ``reevaluation.csv``) as floats; a blank cell is NaN."""
    path = folder / name
    if not path.exists():
        return []
    with path.open() as file:
        return [
            {key: float(value) if value != "" else float("nan") for key, value in row.items()} for row in csv.DictReader(file)
        ]


def read_reevaluation(out: Path, env_id: str, variant: str, seed: int) -> list[dict[str, float]]:
    return read_progress(job_folder(out, env_id, variant, seed), "reevaluation.csv")


def atomic_replace(write: Callable[[Path], Any], path: Path) -> None:
    """``write`` a temporary file beside ``path``, then move it onto ``path``: a reader sees the old file or the new."""
    temporary = path.with_name(f"{path.stem}.tmp{path.suffix}")  # SB3 keeps a name that ends in .zip
    write(temporary)
    os.replace(temporary, path)


def append_row(path: Path, row: dict[str, Any]) -> None:
    """Append a row to a progress.csv; a CSV whose header is not COLUMNS (one without some of them) is first rewritten
    with COLUMNS, the missing cells blank."""
    cell = {key: ("" if isinstance(v, float) and not np.isfinite(v) else v) for key, v in row.items()}
    if path.exists():
        with path.open() as file:
            header = next(csv.reader(file), [])
        if header != COLUMNS:
            with path.open() as file:
                old = list(csv.DictReader(file))

            def rewrite(temporary: Path) -> None:
                with temporary.open("w", newline="") as file:
                    writer = csv.DictWriter(file, fieldnames=COLUMNS, restval="", extrasaction="ignore")
                    writer.writeheader()
                    writer.writerows(old)

            atomic_replace(rewrite, path)
    new = not path.exists()
    with path.open("a", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=COLUMNS)
        if new:
            writer.writeheader()
        writer.writerow(cell)


def write_reevaluation(out: Path, env_id: str, variant: str, seed: int, row: dict[str, Any]) -> None:
    """Add ``row`` to the run's reevaluation.csv (sorted by timesteps, episodes, seed), replacing the file atomically."""
    rows = [*read_reevaluation(out, env_id, variant, seed), row]
    rows.sort(key=lambda r: (r["timesteps"], r["episodes"], r["reset_seed"]))
    integers = ("timesteps", "episodes", "reset_seed")

    def write(temporary: Path) -> None:
        with temporary.open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=REEVALUATION_COLUMNS)
            writer.writeheader()
            for r in rows:
                writer.writerow({key: int(r[key]) if key in integers else r[key] for key in REEVALUATION_COLUMNS})

    atomic_replace(write, job_folder(out, env_id, variant, seed) / "reevaluation.csv")


def keep_checkpoint(folder: Path, destination: Path) -> None:
    """Copy a job folder's checkpoint files and CSV to ``destination``, which appears whole or not at all.

    A copy already there (a run started again from zero, into the same folder) is replaced, as SB3's
    CheckpointCallback overwrites its files.
    """
    temporary = destination.with_name(destination.name + ".tmp")
    shutil.rmtree(temporary, ignore_errors=True)  # a copy cut short by a stop
    temporary.mkdir(parents=True)
    for name in (*CHECKPOINT_FILES, "progress.csv"):
        if (folder / name).exists():
            shutil.copy2(folder / name, temporary / name)
    shutil.rmtree(destination, ignore_errors=True)
    os.replace(temporary, destination)
