"""benchmarks.update_cost: the timing wrapper, one measurement and the table, by hand."""

from __future__ import annotations

import pytest

from benchmarks import update_cost
from benchmarks.study import LABELS


def test_timed_records_each_call_and_passes_results_and_errors_through() -> None:
    seconds: list[float] = []
    double = update_cost.timed(lambda x: 2 * x, seconds)
    assert double(3) == 6 and len(seconds) == 1 and seconds[0] >= 0

    def fail() -> None:
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError, match="boom"):
        update_cost.timed(fail, seconds)()
    assert len(seconds) == 2  # a failing call is timed too


def test_measure_times_every_update_and_collection_of_a_variant() -> None:
    result = update_cost.measure("Reacher2D-v0", "plain", 2048)  # 8 envs x 256 steps: one update
    assert result["samples"] == 2048 and result["updates"] == 1
    assert result["update_per_10k"] > 0 and result["collect_per_10k"] > 0


def test_summary_gives_medians_over_repeats_and_the_median_ratio_to_the_first_variant() -> None:
    repeats = [
        {
            "plain": {"updates": 4, "update_per_10k": 1.0, "collect_per_10k": 3.0},
            "ppo": {"updates": 8, "update_per_10k": 3.0, "collect_per_10k": 5.0},
        },
        {
            "plain": {"updates": 4, "update_per_10k": 2.0, "collect_per_10k": 4.0},
            "ppo": {"updates": 8, "update_per_10k": 2.0, "collect_per_10k": 6.0},
        },
        {
            "plain": {"updates": 4, "update_per_10k": 4.0, "collect_per_10k": 9.0},
            "ppo": {"updates": 8, "update_per_10k": 10.0, "collect_per_10k": 7.0},
        },
    ]
    lines = update_cost.summary("Reacher2D-v0", ["plain", "ppo"], repeats)
    assert lines[0] == "Reacher2D-v0, 3 repeats, medians:"
    assert lines[4] == f"| {LABELS['plain']} | 4 | 2.00 | 4.00 | 1.00 |"
    # ratios per repeat 3.0, 1.0, 2.5: median 2.5 (not the ratio of the medians, 3.0 / 2.0)
    assert lines[5] == f"| {LABELS['ppo']} | 8 | 3.00 | 6.00 | 2.50 |"


def test_main_prints_the_table_and_writes_every_repeat_with_the_machine(tmp_path, capsys) -> None:
    import json

    out = tmp_path / "cost.json"
    update_cost.main(["--env", "Reacher2D-v0", "--variants", "plain", "--steps", "2048", "--repeats", "1", "--out", str(out)])
    assert f"| {LABELS['plain']} | 1 |" in capsys.readouterr().out
    record = json.loads(out.read_text())
    assert record["env"] == "Reacher2D-v0" and record["steps"] == 2048 and len(record["repeats"]) == 1
    assert set(record["machine"]) == {"cpu", "python", "torch"}
    with pytest.raises(SystemExit):
        update_cost.main(["--variants", "plain", "--repeats", "0"])
