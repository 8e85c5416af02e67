"""Learning curves from monitor CSVs: mean ± std over runs, several algorithms in one figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from stable_baselines3.common.monitor import load_results


def run_curve(folder: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Timesteps at each episode end, episode returns and success flags (None if not logged) of one run."""
    frame = load_results(str(folder))  # all *.monitor.csv of the run, sorted by wall time
    timesteps = np.cumsum(frame["l"].to_numpy())
    success = frame["is_success"].to_numpy(dtype=float) if "is_success" in frame else None
    return timesteps, frame["r"].to_numpy(), success


def _on_grid(timesteps: np.ndarray, values: np.ndarray, grid: np.ndarray, window: int) -> np.ndarray:
    smoothed = np.convolve(values, np.ones(window) / window, mode="valid") if len(values) >= window else values
    return np.interp(grid, timesteps[len(timesteps) - len(smoothed) :], smoothed)


def learning_curve_figure(groups: dict[str, list[Path]], title: str, output: Path, points: int = 100) -> None:
    """Plot reward (and success rate when logged) vs timesteps; mean ± std over the runs of each group."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = {label: [run_curve(run) for run in runs] for label, runs in groups.items()}
    has_success = any(c[2] is not None for runs in curves.values() for c in runs)
    fig, axes = plt.subplots(1, 2 if has_success else 1, figsize=(11 if has_success else 6, 4), squeeze=False)
    for label, runs in curves.items():
        runs = [run for run in runs if len(run[0]) > 0]
        if not runs:
            continue
        end = min(run[0][-1] for run in runs)
        grid = np.linspace(min(run[0][0] for run in runs), end, points)
        window = max(1, min(len(run[0]) for run in runs) // 20)
        panels = [(0, 1)] + ([(1, 2)] if has_success else [])
        for axis_index, column in panels:
            columns = [(run[0], run[column]) for run in runs]
            series = [_on_grid(t, values, grid, window) for t, values in columns if values is not None]
            if not series:
                continue
            mean, std = np.mean(series, axis=0), np.std(series, axis=0)
            ax = axes[0, axis_index]
            ax.plot(grid, mean, label=f"{label} ({len(series)} run{'s' if len(series) > 1 else ''})")
            ax.fill_between(grid, mean - std, mean + std, alpha=0.25)
    axes[0, 0].set_ylabel("episode reward")
    if has_success:
        axes[0, 1].set_ylabel("success rate")
        axes[0, 1].set_ylim(-0.05, 1.05)
    for ax in axes[0]:
        ax.set_xlabel("timesteps")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=100)
    plt.close(fig)
