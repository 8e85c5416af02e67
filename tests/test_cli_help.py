"""The ``trpo-plus`` command's help, and its errors: one line naming the input, exit status 2; arguments of TRPOPlus
that cannot work together are refused at construction, named as the caller wrote them."""

import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import pytest
import yaml
from stable_baselines3.common.env_util import make_vec_env

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.segment import SegmentDictRolloutBuffer, SegmentRolloutBuffer
from sb3_trpo_plus.application import cli, run_folders
from sb3_trpo_plus.application.enjoy import enjoy_parser
from sb3_trpo_plus.application.rl_zoo import config_module
from sb3_trpo_plus.application.zoo import HyperparameterError, load_hyperparameters
from sb3_trpo_plus.common.arguments import ArgumentError

VERBS = ("train", "enjoy", "record-video", "plot", "main")


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int | str | None, str, str]:
    """``trpo-plus ARGV`` in this process: its exit status, stdout and stderr."""
    with pytest.raises(SystemExit) as exit_:
        cli.main(argv)
    captured = capsys.readouterr()
    return exit_.value.code, captured.out, captured.err


@pytest.mark.parametrize("argv", [[], ["--help"], ["-h"]], ids=["bare", "--help", "-h"])
def test_top_level_help_lists_every_verb(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli(argv, capsys)
    assert code == 0 and out.count("usage:") == 1
    listed = {line.split()[0] for line in out.splitlines() if line.startswith("  ")}
    assert listed == set(VERBS)
    assert "trpo-plus COMMAND --help" in out


def test_an_unknown_verb_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_cli(["trian", "--env", "Reacher2D-v1"], capsys)
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and err.startswith("trpo-plus: error: unknown command 'trian'")


HELP_CASES = {
    "train": ["train", "--help"],
    "train-with-env": ["train", "--env", "Reacher2D-v1", "-n", "100", "--help"],
    "enjoy": ["enjoy", "--help"],
    "enjoy-trust-pickle": ["enjoy", "--trust-pickle", "--env", "Reacher2D-v1", "--help"],
    "record-video": ["record-video", "-h"],
    "plot": ["plot", "--help"],
    "main": ["main", "--help"],
}


@pytest.mark.parametrize("argv", HELP_CASES.values(), ids=HELP_CASES.keys())
def test_each_verbs_help_is_one_usage_block(
    argv: list[str], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import rl_zoo3.enjoy
    import rl_zoo3.train

    def not_run() -> None:
        raise AssertionError("rl-zoo3 ran")

    monkeypatch.setattr(rl_zoo3.train, "train", not_run)
    monkeypatch.setattr(rl_zoo3.enjoy, "enjoy", not_run)
    code, out, err = run_cli(argv, capsys)
    assert (code, err) == (0, "")
    assert out.count("usage:") == 1 and out.startswith(f"usage: trpo-plus {argv[0]} ")
    assert "{a2c," not in out  # rl-zoo3's own --algo choices
    if argv[0] == "train":
        assert "every other rl-zoo3 train flag passes through unchanged" in out
        for flag in ("-n N", "--seed", "-tb", "-f DIR", "--eval-freq", "-conf FILE", "--hyperparams", "-optimize"):
            assert flag in out, flag
        assert "python -m rl_zoo3.train --help" in out
    if argv[0] == "enjoy":
        assert "--trust-pickle" in out and "Hugging Face hub" in out


@pytest.mark.parametrize("parser", [cli._train_parser, enjoy_parser], ids=["train", "enjoy"])
def test_every_flag_has_a_help_text(parser) -> None:
    assert all(action.help for action in parser()._actions)


def test_the_commands_exit_status_for_help() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "sb3_trpo_plus", "train", "--help"], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.count("usage:") == 1 and "passes through unchanged" in result.stdout


def _yaml(path: Path, **entry: object) -> Path:
    path.write_text(yaml.safe_dump({"Reacher2D-v1": {"n_timesteps": 1000, "policy": "MlpPolicy", **entry}}))
    return path


ERROR_CASES = {
    "sim-threads": (["train", "--env", "Reacher2D-v1", "--sim-threads", "x"], "argument --sim-threads: invalid int"),
    "algo": (["train", "--env", "Reacher2D-v1", "--algo", "foo"], "argument --algo: invalid choice: 'foo'"),
    "workers": (["train", "--env", "Reacher2D-v1", "--workers", "bogus"], "argument --workers: expected 'BACKEND:N'"),
    "no-env": (["train"], "the following arguments are required: --env"),
    "unknown-env": (["train", "--env", "Reacher2D-v9"], "argument --env: no env 'Reacher2D-v9' is registered"),
    "rl-zoo3-flag": (["train", "--env", "Reacher2D-v1", "--evl-freq", "5"], "unrecognized arguments: --evl-freq"),
    "rl-zoo3-value": (["train", "--env", "Reacher2D-v1", "-n", "ten"], "argument -n/--n-timesteps: invalid int"),
    "hyperparams-python": (["train", "--env", "Reacher2D-v1", "-params", "sample_reuse:bogus"], "'bogus' is not defined"),
    "conf-missing": (["train", "--env", "Reacher2D-v1", "-conf", "{tmp}/none.yml"], "{tmp}/none.yml: cannot read"),
    "conf-value": (
        ["train", "--env", "Reacher2D-v1", "-conf", "{tmp}/bogus.yml"],
        "{tmp}/bogus.yml: Reacher2D-v1: sample_reuse: must be one of ('none', 'generalized'), got 'bogus'",
    ),
    "conf-combination": (
        ["train", "--env", "Reacher2D-v1", "--conf-file", "{tmp}/batches.yml"],
        "{tmp}/batches.yml: Reacher2D-v1: TRPOPlus: `reuse_batches` must be a finite number in [1, 1.5] for "
        "`reuse_max_batches`=2",
    ),
    "enjoy-no-run": (["enjoy", "--env", "Reacher2D-v1", "-f", "{tmp}/none"], "no run of Reacher2D-v1"),
    "enjoy-trust-pickle-no-run": (
        ["enjoy", "--trust-pickle", "--env", "Reacher2D-v1", "-f", "{tmp}/none", "--no-render"],
        "no run of Reacher2D-v1",
    ),
    "enjoy-exp-id": (
        ["enjoy", "--env", "Reacher2D-v1", "-f", str(run_folders.TRAINED_AGENTS), "--exp-id", "99"],
        "--exp-id 99: no run folder",
    ),
    "enjoy-no-model": (
        ["enjoy", "--env", "Reacher2D-v1", "-f", str(run_folders.TRAINED_AGENTS), "--load-best", "--no-render"],
        "No model found for trpo_plus on Reacher2D-v1",
    ),
    "enjoy-env-kwargs": (["enjoy", "--env", "Reacher2D-v1", "--env-kwargs", "nocolon"], "expected KEY:VALUE"),
    "record-video-no-run": (["record-video", "--env", "Reacher2D-v1", "-f", "{tmp}/none"], "no run of Reacher2D-v1"),
    "record-video-suffix": (["record-video", "--env", "Reacher2D-v1", "-o", "{tmp}/film.avi"], "writes an MP4"),
    "plot-no-runs": (["plot", "--env", "Reacher2D-v1", "-f", "{tmp}/none"], "no runs of Reacher2D-v1 found"),
    "plot-runs-folder": (["plot", "--env", "Reacher2D-v1", "--runs", "{tmp}/none"], "{tmp}/none is no folder"),
    "plot-format": (["plot", "--env", "Reacher2D-v1", "-o", "{tmp}/curve.xyz"], "argument -o/--output: a figure file"),
}


@pytest.mark.parametrize(("argv", "message"), ERROR_CASES.values(), ids=ERROR_CASES.keys())
def test_an_input_error_is_one_line_naming_it(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # where rl-zoo3 would write a run
    monkeypatch.setattr(sys, "argv", list(sys.argv))
    _yaml(tmp_path / "bogus.yml", sample_reuse="bogus")
    _yaml(tmp_path / "batches.yml", sample_reuse="generalized", reuse_batches=4, reuse_max_batches=2)
    code, _, err = run_cli([a.replace("{tmp}", str(tmp_path)) for a in argv], capsys)
    assert code == 2
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert err.startswith(f"trpo-plus {argv[0]}: error: ")
    assert message.replace("{tmp}", str(tmp_path)) in err


def test_a_hyperparameter_override_that_cannot_work_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Refused by the constructor inside rl-zoo3: the line names the recipe, the override and the argument."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", list(sys.argv))
    argv = ["train", "--env", "Pendulum-v1", "-f", str(tmp_path), "--eval-freq", "-1", "-params", "n_steps:0"]
    code, _, err = run_cli(argv, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("trpo-plus train: error: ") and "trpo_plus.yml: Pendulum-v1 with -params: " in err
    assert "`n_steps` must be an integer >= 1, got 0" in err


@pytest.mark.parametrize("output", ["{tmp}", "{tmp}/new/", "{tmp}/videos"], ids=["folder", "separator", "no-suffix"])
def test_record_video_writes_into_a_folder(output: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = [
        "--env",
        "Reacher2D-v1",
        "-f",
        str(run_folders.TRAINED_AGENTS),
        "-n",
        "3",
        "-o",
        output.replace("{tmp}", str(tmp_path)),
    ]
    (path,) = cli.record_video(argv)
    assert path == Path(output.replace("{tmp}", str(tmp_path))) / "Reacher2D-v1.mp4"
    assert path.stat().st_size > 0 and f"wrote {path}" in capsys.readouterr().out


# ------------------------------------------------------------------ TRPOPlus: combinations refused at construction
def test_a_number_given_as_a_str_is_refused_with_the_yaml_reason() -> None:
    """``--set projection_learning_rate=6e-4`` arrives as the str '6e-4' (YAML 1.1): the error says so."""
    with pytest.raises(ArgumentError) as error:
        TRPOPlus("MlpPolicy", "Pendulum-v1", target_kl="6e-4")
    assert str(error.value).endswith("got '6e-4' (a number as a str; YAML 1.1 reads 6e-4 as one: write !!float 6e-4 in YAML)")


def test_reuse_batches_out_of_reach_of_reuse_max_batches_is_refused_at_construction() -> None:
    with pytest.raises(ArgumentError) as error:
        TRPOPlus("MlpPolicy", "Pendulum-v1", sample_reuse="generalized", reuse_batches=4, reuse_max_batches=2)
    message = str(error.value)
    assert "`reuse_batches` must be a finite number in [1, 1.5] for `reuse_max_batches`=2" in message
    assert message.endswith("got 4")
    TRPOPlus("MlpPolicy", "Pendulum-v1", sample_reuse="generalized", reuse_batches=1.5, reuse_max_batches=2)


def test_overlap_collection_without_rollout_workers_is_refused_at_construction() -> None:
    env = make_vec_env("Pendulum-v1", n_envs=2)
    with pytest.raises(ArgumentError, match=r"overlap_collection=True .* the env is DummyVecEnv, not a pool"):
        TRPOPlus("MlpPolicy", env, sample_reuse="generalized", overlap_collection=True)


class _DictObservations(gym.ObservationWrapper):
    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = gym.spaces.Dict({"state": env.observation_space})

    def observation(self, observation: object) -> dict:
        return {"state": observation}


@pytest.mark.parametrize("dict_observations", [True, False], ids=["Dict", "Box"])
def test_a_rollout_buffer_class_for_other_observations_is_refused_at_construction(dict_observations: bool) -> None:
    wrapper = _DictObservations if dict_observations else None
    env = make_vec_env("Pendulum-v1", n_envs=1, wrapper_class=wrapper)
    policy = "MultiInputPolicy" if dict_observations else "MlpPolicy"
    buffer = SegmentRolloutBuffer if dict_observations else SegmentDictRolloutBuffer  # the other kind's
    space = "Dict" if dict_observations else "Box"
    with pytest.raises(ArgumentError, match=rf"`rollout_buffer_class` must be .* for the env's {space} observation space"):
        TRPOPlus(policy, env, n_steps=8, rollout_buffer_class=buffer)


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"sample_reuse": "generalized", "reuse_batches": 6}, "`reuse_batches` must be a finite number in [1, 5.5]"),
        ({"sample_reuse": "generalized", "replay_memory": 2}, "does not combine with ['replay_memory']"),
        ({"overlap_collection": True}, "overlap_collection=True learns from segments one update old"),
        ({"target_kl": -0.1}, "target_kl: must be a finite number > 0"),
        ({"learning_rate": "lin_-1e-3"}, "learning_rate: must be a finite number > 0"),
        ({"learning_rate": "lin_1.0.0"}, "learning_rate: expected a schedule 'lin_<number>'"),
    ],
)
def test_a_recipe_that_cannot_work_is_named_with_its_file_and_entry(tmp_path: Path, entry: dict, message: str) -> None:
    """``trpo-plus train`` checks the values of the recipes it hands rl-zoo3 before anything is built."""
    path = _yaml(tmp_path / "recipe.yml", **entry)
    load_hyperparameters(path, "trpo_plus")  # the types are right
    with pytest.raises(HyperparameterError) as error:
        config_module("trpo_plus", path)
    assert str(error.value).startswith(f"{path}: Reacher2D-v1: ") and message in str(error.value)


def test_every_shipped_recipe_passes_the_value_checks() -> None:
    config_module("trpo_plus")


@pytest.mark.parametrize(
    ("backend", "rest", "expected"),
    [
        ("process", [], 1),
        ("ray", [], 1),
        ("inprocess", [], 2),
        ("process", ["--num-threads", "2"], 2),
        ("process", ["--num-threads=2"], 2),
    ],
)
def test_worker_processes_leave_the_learner_one_torch_thread(backend: str, rest: list[str], expected: int) -> None:
    """Rollout worker processes share the cores with the learner: one PyTorch thread for it unless --num-threads says
    otherwise (benchmarks.torch_threads); an in-process layout keeps PyTorch's own."""
    import torch as th

    from sb3_trpo_plus.application.cli import _torch_threads_given, _workers_factory

    before = th.get_num_threads()
    th.set_num_threads(2)
    try:
        _workers_factory(backend, 1, 1, "--workers", _torch_threads_given(rest))
        assert th.get_num_threads() == expected
    finally:
        th.set_num_threads(before)
