"""The convergence study's tables agree with each other and with the envs (benchmarks/convergence.py)."""

import sys
from pathlib import Path

import gymnasium as gym
import pytest

import grasp_envs  # noqa: F401  (registers the envs)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import convergence  # benchmarks/convergence.py
import convergence_report


def test_every_variant_has_a_label_and_every_env_a_target() -> None:
    assert set(convergence_report.LABELS) == set(convergence.VARIANTS)
    assert set(convergence.TARGETS) == set(convergence.BUDGETS)
    assert set(convergence.STUDY_VARIANTS) <= set(convergence.VARIANTS)


@pytest.mark.parametrize("variant", sorted(convergence.TRAIN_ENV_KWARGS))
def test_training_env_kwargs_are_accepted_by_the_env(variant: str) -> None:
    assert variant in convergence.VARIANTS
    env = gym.make("Grasper3D-v4", **convergence.TRAIN_ENV_KWARGS[variant])
    env.reset(seed=0)
    env.close()


def test_export_skips_a_finished_run_without_its_checkpoint(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    env_id = "Reacher2D-v1"
    folder = convergence.job_folder(tmp_path / "out", env_id, "warm", 3)
    folder.mkdir(parents=True)
    budget = convergence.BUDGETS[env_id]
    (folder / "progress.csv").write_text(f"timesteps,eval_success,eval_return\n{budget},0.9,10.0\n")
    agents = tmp_path / "agents"
    convergence_report.export_agents(tmp_path / "out", [env_id], agents)
    printed = capsys.readouterr().out
    assert "warm seed 3 (0.90)" in printed
    assert "no finished TRPOPlus run with a checkpoint" in printed
    assert not agents.exists()


def test_zero_start_solver_starts_at_zero_and_draws_nothing() -> None:
    import torch as th
    from trpo_divergence import zero_start_solver

    matrix = th.tensor([[4.0, 1.0], [1.0, 3.0]])
    b = th.tensor([1.0, 2.0])
    th.manual_seed(0)
    solution = zero_start_solver(lambda v: matrix @ v, b, max_iter=1)
    # one CG iteration from 0 is the steepest-descent step (b·b / b·Ab) b, hand-computed: 5 / 20 * b
    th.testing.assert_close(solution, th.tensor([0.25, 0.5]))
    th.manual_seed(0)
    expected = th.randn(1)
    th.manual_seed(0)
    zero_start_solver(lambda v: matrix @ v, b, max_iter=2)
    assert th.equal(th.randn(1), expected), "the solver must not draw from torch's global generator"


def test_zero_cg_start_variants_are_sb3_contrib_trpo() -> None:
    assert convergence.ZERO_CG_START and all(convergence.VARIANTS[v][0] == "trpo" for v in convergence.ZERO_CG_START)


def test_complete_runs_are_in_the_order_of_the_seeds(tmp_path: Path) -> None:
    # the 10-seed tables take the first seeds of each variant: seed10 must not come before seed2
    budget = convergence.BUDGETS["Reacher2D-v1"]
    for seed in (10, 2, 1):
        folder = convergence.job_folder(tmp_path, "Reacher2D-v1", "plain", seed)
        folder.mkdir(parents=True)
        (folder / "progress.csv").write_text(f"timesteps,eval_success\n{budget},0.5\n")
    (convergence.job_folder(tmp_path, "Reacher2D-v1", "plain", 3)).mkdir()  # unfinished: no CSV
    assert list(convergence_report.complete_runs(tmp_path, "Reacher2D-v1", "plain")) == [1, 2, 10]
