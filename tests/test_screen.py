"""benchmarks.screen: runs cut at the screen's budget, the table's figures and P(X > baseline) by hand."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture
def screen(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1]))  # benchmarks/ beside the package
    from benchmarks import screen

    return screen


def _write(out: Path, env: str, variant: str, seed: int, returns: list[float], every: int = 100) -> None:
    folder = out / env / variant / f"seed{seed}"
    folder.mkdir(parents=True)
    rows = [f"{every * (i + 1)},{value}" for i, value in enumerate(returns)]
    (folder / "progress.csv").write_text("timesteps,eval_return\n" + "\n".join(rows) + "\n")


def test_a_run_is_cut_at_its_last_evaluation_within_the_budget(screen) -> None:
    rows = [{"timesteps": float(t), "eval_return": 0.0} for t in (100, 200, 300, 400)]
    assert [row["timesteps"] for row in screen.cut(rows, 350)] == [100, 200, 300]
    assert screen.cut(rows[:2], 350) is None  # stopped short of the budget: not screened
    assert len(screen.cut(rows[:3], 310)) == 3  # within 5 % of the budget counts


def test_the_screen_tables_by_hand(screen, tmp_path: Path) -> None:
    for seed, (low, high) in enumerate([(1.0, 3.0), (2.0, 4.0), (3.0, 5.0)]):
        _write(tmp_path, "Hopper-v5", "plain", seed, [low, low, low, 99.0])  # the 4th evaluation is past the cut
        _write(tmp_path, "Hopper-v5", "ppo", seed, [high, high, high, -99.0])
    _write(tmp_path, "Hopper-v5", "trpo", 0, [5.0])  # not at the cut yet
    lines = screen.screen(["Hopper-v5"], ["ppo", "trpo"], "plain", 300, None, tmp_path)
    table = "\n".join(lines)
    assert "| Hopper-v5 | TRPOPlus plain | 0 1 2 | 2 (1-3) | 2 |" in table
    assert "| Hopper-v5 | SB3 PPO | 0 1 2 | 4 (3-5) | 4 |" in table
    assert "| Hopper-v5 | sb3-contrib TRPO | none yet | | |" in table
    # PPO's areas 3, 4, 5 against plain's 1, 2, 3: 8 of 9 pairs ahead, one tie (3 = 3) counts half
    ppo_row = next(line for line in lines if line.startswith("| SB3 PPO (3 seeds)"))
    assert ppo_row.split(" | ")[1].startswith(f"{(8 + 0.5) / 9:.2f} [")
    assert next(line for line in lines if line.startswith("| sb3-contrib TRPO")).count("fewer than 2 seeds") == 2


def test_several_baselines_are_peers_the_better_one_on_each_env(screen, tmp_path: Path) -> None:
    """ppo is the better peer on Hopper, trpo on HalfCheetah; the lever is compared with each env's better one."""
    for seed in range(3):
        _write(tmp_path, "Hopper-v5", "ppo", seed, [4.0 + seed] * 3)  # areas 4, 5, 6
        _write(tmp_path, "Hopper-v5", "trpo", seed, [1.0] * 3)
        _write(tmp_path, "HalfCheetah-v5", "ppo", seed, [1.0] * 3)
        _write(tmp_path, "HalfCheetah-v5", "trpo", seed, [10.0] * 3)
        _write(tmp_path, "Hopper-v5", "plain", seed, [5.0] * 3)  # level with ppo's middle seed
        _write(tmp_path, "HalfCheetah-v5", "plain", seed, [2.0] * 3)  # behind trpo, ahead of ppo
    lines = screen.screen(["Hopper-v5", "HalfCheetah-v5"], ["plain"], ["ppo", "trpo"], 300, None, tmp_path)
    assert "Baseline on each env (the larger mean area): Hopper-v5: SB3 PPO; HalfCheetah-v5: sb3-contrib TRPO." in lines
    header = next(line for line in lines if line.startswith("| P(X > "))
    assert header.startswith("| P(X > the better of SB3 PPO and sb3-contrib TRPO), area |")
    cells = next(line for line in lines if line.startswith("| TRPOPlus plain (3 seeds)")).split(" | ")[1:]
    # Hopper: 5 against 4, 5, 6: one ahead, one tie, one behind = 0.5; HalfCheetah: 2 against 10: 0; mean 0.25
    assert [cell.split(" [")[0] for cell in cells] == ["0.50", "0.00", "0.25"]
