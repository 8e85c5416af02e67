"""The time-to-grasp benchmark's bookkeeping (benchmarks/time_to_grasp.py): when a run reached the target, whether it
held it, and the report over runs."""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # benchmarks/ is a package beside the installed ones
from benchmarks import time_to_grasp  # noqa: E402


def _rows(successes: list[float]) -> list[dict[str, float]]:
    return [{"timesteps": 50_000 * (i + 1), "train_seconds": 10.0 * (i + 1), "success": s} for i, s in enumerate(successes)]


def test_first_evaluation_at_the_target_and_whether_it_held() -> None:
    assert time_to_grasp.first_at_target(_rows([0.1, 0.5, 0.9, 0.96])) == (30.0, 150_000, True)
    assert time_to_grasp.first_at_target(_rows([0.92, 0.88, 0.95])) == (10.0, 50_000, False)
    assert time_to_grasp.first_at_target(_rows([0.1, 0.89])) is None


def test_report_reads_every_run(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "trpo_plus"
    folder.mkdir()
    for seed, successes in ((0, [0.2, 0.9, 0.94]), (1, [0.1, 0.5, 0.91])):
        with (folder / f"seed{seed}.csv").open("w") as file:
            file.write("timesteps,train_seconds,eval_seconds,success,mean_return\n")
            for row in _rows(successes):
                file.write(f"{row['timesteps']},{row['train_seconds']},1.0,{row['success']},0\n")
    time_to_grasp.report(tmp_path)
    out = capsys.readouterr().out
    # env steps/s: the median over runs of steps / training seconds at the last evaluation (150,000 / 30 s)
    assert (
        "trpo_plus (5.0k env steps/s): median 25 s (95 % bootstrap interval over seeds 20-30 s); "
        "seed0: 20 s / 100,000 steps; seed1: 30 s / 150,000 steps"
    ) in out
    assert (tmp_path / "time_to_grasp.png").is_file()


def test_the_median_interval_of_two_seeds_by_hand() -> None:
    """Two seeds: a resample's median is the first value (probability 1/4), their mean (1/2) or the second (1/4), so
    the 2.5 % and 97.5 % percentiles are the two values."""
    assert time_to_grasp.median_interval([40.0, 80.0]) == (40.0, 80.0)
    assert time_to_grasp.median_interval([55.0, 55.0, 55.0]) == (55.0, 55.0)
    low, high = time_to_grasp.median_interval([float(v) for v in range(1, 21)])
    assert 5 < low < 10.5 < high < 16  # around the median 10.5, well inside the range 1-20
    with pytest.raises(ValueError, match="at least one value"):
        time_to_grasp.median_interval([])


def test_runs_are_listed_in_seed_order(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "runs"
    folder.mkdir()
    for seed in (10, 2):
        with (folder / f"seed{seed}.csv").open("w") as file:
            file.write(f"timesteps,train_seconds,eval_seconds,success,mean_return\n50000,{seed}.0,1.0,0.95,0\n")
    time_to_grasp.report(tmp_path)
    out = capsys.readouterr().out
    assert out.index("seed2: 2 s") < out.index("seed10: 10 s")


def test_the_phase_recorder_keeps_what_the_logger_holds_at_each_rollout_end() -> None:
    """Per rollout, the last update's time and the workers' timings as logged; keys not logged are left out."""
    from stable_baselines3.common.logger import Logger

    phases: dict[str, list[float]] = {}
    recorder = time_to_grasp.phase_recorder(phases)
    logger = Logger(folder=None, output_formats=[])
    recorder.model = type("Model", (), {"logger": logger})()  # what init_callback gives the callback to read
    logger.record("train/update_time", 0.5)
    logger.record("workers/wait_ms", 80.0)
    logger.record("train/value_loss", 3.0)
    recorder.on_rollout_end()
    logger.record("train/update_time", 0.25)
    recorder.on_rollout_end()
    assert phases == {"train/update_time": [0.5, 0.25], "workers/wait_ms": [80.0, 80.0]}


def test_the_machine_record_names_the_processor_model(tmp_path: Path) -> None:
    """The CPU beside a measurement is the processor's model name where Linux gives it, the architecture otherwise."""
    import platform

    from benchmarks.machine import cpu_name

    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 9B14\nflags\t\t: fpu\n")
    assert cpu_name(cpuinfo) == "AMD EPYC 9B14"
    cpuinfo.write_text("processor\t: 0\n")
    assert cpu_name(cpuinfo) == (platform.processor() or platform.machine())
    assert cpu_name(tmp_path / "missing") == (platform.processor() or platform.machine())


def test_success_areas_over_steps_and_over_seconds_by_hand() -> None:
    rows = _rows([0.1, 0.5, 0.9, 0.96])  # evaluations at 50k ... 200k steps, 10 ... 40 s
    assert time_to_grasp.sample_area(rows, 150_000) == 0.5  # (0.1 + 0.5 + 0.9) / 3
    assert time_to_grasp.sample_area(rows, 200_000) == (0.1 + 0.5 + 0.9 + 0.96) / 4
    # 0 until the first evaluation, then each evaluation's success until the next: (0 + 1 + 5 + 9) / 40
    assert abs(time_to_grasp.time_area(rows, 40.0) - 0.375) < 1e-12
    assert abs(time_to_grasp.time_area(rows, 35.0) - (1 + 5 + 4.5) / 35) < 1e-12  # the last step cut at 35 s


def test_comparison_scores_both_folders_up_to_what_all_their_runs_reached(tmp_path: Path) -> None:
    """Every run of X ahead of every run of Y: P = 1 with no resample reversing it; the areas run to the shortest run
    of either folder (150k steps, 30 s here); a folder without runs is named."""
    fast = {f"seed{k}": _rows([0.5, 0.9, 0.95, 0.97]) for k in range(3)}
    slow = {f"seed{k}": _rows([0.0, 0.1, 0.3]) for k in range(3)}
    lines = time_to_grasp.comparison_lines({"fast": fast, "slow": slow}, [("fast", "slow")])
    assert lines[2] == ("| fast > slow | 3 / 3 | 1.00 [1.00, 1.00] (to 0.15M steps) | 1.00 [1.00, 1.00] (to 30 s) |")
    reversed_lines = time_to_grasp.comparison_lines({"fast": fast, "slow": slow}, [("slow", "fast")])
    assert "| slow > fast | 3 / 3 | 0.00 [0.00, 0.00]" in reversed_lines[2]
    with pytest.raises(ValueError, match="no runs of 'missing'"):
        time_to_grasp.comparison_lines({"fast": fast}, [("fast", "missing")])


def test_report_of_named_folders_only(tmp_path: Path, capsys) -> None:
    for name in ("shown", "hidden"):
        (tmp_path / name).mkdir()
        with (tmp_path / name / "seed0.csv").open("w") as file:
            file.write("timesteps,train_seconds,eval_seconds,success,mean_return\n50000,10.0,1.0,0.95,0\n")
    time_to_grasp.report(tmp_path, only=["shown"])
    out = capsys.readouterr().out
    assert "shown (5.0k env steps/s): median 10 s" in out and "hidden" not in out
    with pytest.raises(ValueError, match="no result folder absent"):
        time_to_grasp.report(tmp_path, only=["shown", "absent"])


def test_algo_class_must_subclass_the_algorithm() -> None:
    from benchmarks.multistep import MultiStepTRPOPlus

    assert time_to_grasp.algorithm_class("benchmarks.multistep.MultiStepTRPOPlus", "trpo_plus") is MultiStepTRPOPlus
    with pytest.raises(ValueError, match="not a subclass of PPO"):
        time_to_grasp.algorithm_class("benchmarks.multistep.MultiStepTRPOPlus", "ppo")
    with pytest.raises(ValueError, match=r"MODULE\.CLASS"):
        time_to_grasp.algorithm_class("MultiStepTRPOPlus", "trpo_plus")


def test_class_arguments_need_a_class() -> None:
    with pytest.raises(SystemExit):
        time_to_grasp.main(["--class-set", "n_policy_steps=2"])
