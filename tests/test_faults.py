"""Faults survived, nothing lost: Ctrl-C, a dead rollout worker, a full disk, damaged files, an older model."""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import sigint
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.worker_failures import RolloutWorkerError
from sb3_trpo_plus.application.agents import (
    RunFileError,
    load_agent,
    load_eval_agent,
    load_normalization,
    load_policy,
    read_run_config,
)
from sb3_trpo_plus.application.callbacks import SaveOnInterrupt, save_vec_normalize
from sb3_trpo_plus.common import persistence

ROOT = Path(__file__).resolve().parents[1]
COMPAT = ROOT / "tests" / "data" / "compat"
TINY = dict(n_steps=64, batch_size=64, policy_kwargs=dict(net_arch=[16]), device="cpu")


def tiny_model(env: Any, **kwargs: Any) -> TRPOPlus:
    return TRPOPlus("MlpPolicy", env, **{**TINY, "replay_memory": 2, "cg_warm_start": True, "seed": 0, **kwargs})


def parameters(model: TRPOPlus) -> dict[str, np.ndarray]:
    return {name: p.detach().cpu().numpy().copy() for name, p in model.policy.state_dict().items()}


def wait_for(condition: Any, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.2)


# ---------------------------------------------------------------------------------------------- Ctrl-C
CHILD = textwrap.dedent(
    """
    import sys
    from pathlib import Path

    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus import TRPOPlus
    from sb3_trpo_plus.application.callbacks import SaveOnInterrupt

    out = Path(sys.argv[1])

    class Ready(BaseCallback):
        def _on_step(self):
            return True

        def _on_rollout_end(self):
            if self.model._n_updates >= 2:
                (out / "ready").touch()

    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    model = TRPOPlus("MlpPolicy", env, n_steps=64, batch_size=64, replay_memory=2, cg_warm_start=True,
                     policy_kwargs=dict(net_arch=[16]), seed=0, device="cpu")
    model.learn(10_000_000, callback=[SaveOnInterrupt(out), Ready()])
    """
)


def test_sigint_during_learn_saves_a_checkpoint_that_resumes(tmp_path: Path) -> None:
    script = tmp_path / "child.py"
    script.write_text(CHILD)
    child = subprocess.Popen(
        [sys.executable, str(script), str(tmp_path)], stderr=subprocess.PIPE, text=True, preexec_fn=sigint.handled_in_child
    )
    try:
        wait_for(lambda: (tmp_path / "ready").exists() or child.poll() is not None, 120, "three updates")
        assert child.poll() is None, child.stderr.read() if child.stderr else ""
        child.send_signal(signal.SIGINT)
        _, stderr = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode != 0 and "KeyboardInterrupt" in stderr  # Ctrl-C still ends the program
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []  # no temporary files left
    venv = DummyVecEnv([lambda: Monitor(gym.make("Pendulum-v1"))])
    env = VecNormalize.load(str(tmp_path / "interrupted_vecnormalize.pkl"), venv)
    assert env.obs_rms.count > 128
    model = TRPOPlus.load(tmp_path / "interrupted.zip", env=env, device="cpu")
    assert len(model.rollout_memory) == 2 and model.previous_step is not None
    steps, updates = model.num_timesteps, model._n_updates
    model.learn(128, reset_num_timesteps=False)
    assert model.num_timesteps >= steps + 128 and model._n_updates == updates + 2
    env.close()


def test_sigint_during_an_update_lets_it_finish(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    model = tiny_model(env)
    train = TRPOPlus.train

    def train_interrupted_at_second_update(self: TRPOPlus) -> None:
        if self._n_updates == 1:
            os.kill(os.getpid(), signal.SIGINT)  # arrives in the middle of the update
        train(self)

    monkeypatch.setattr(TRPOPlus, "train", train_interrupted_at_second_update)
    with sigint.handled_here() as handler:
        with pytest.raises(KeyboardInterrupt):
            model.learn(10_000, callback=SaveOnInterrupt(tmp_path))
        assert signal.getsignal(signal.SIGINT) is handler  # the handler in place before learn is back
    assert model._n_updates == 2  # the interrupted update completed; no third one started
    saved = TRPOPlus.load(tmp_path / "interrupted.zip", device="cpu")
    for name, value in parameters(model).items():
        np.testing.assert_array_equal(saved.policy.state_dict()[name].numpy(), value, err_msg=name)
    assert len(saved.rollout_memory) == 2
    assert load_normalization(tmp_path / "interrupted_vecnormalize.pkl").obs_mean.shape == (3,)  # type: ignore[union-attr]
    env.close()


def test_an_ignored_sigint_stays_ignored(tmp_path: Path) -> None:
    """A process started with nohup or as a background job ignores SIGINT: training goes on to its end."""
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    model = tiny_model(env)

    class SigintAtSecondRollout(BaseCallback):
        def _on_rollout_start(self) -> None:
            if self.model._n_updates == 1:
                os.kill(os.getpid(), signal.SIGINT)

        def _on_step(self) -> bool:
            return True

    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        callback = SaveOnInterrupt(tmp_path)
        model.learn(3 * 64, callback=[callback, SigintAtSecondRollout()])
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)
    assert model._n_updates == 3 and not callback.interrupted
    assert not (tmp_path / "interrupted.zip").exists()
    env.close()


SIGNAL_TESTS = [
    "tests/test_faults.py::test_sigint_during_learn_saves_a_checkpoint_that_resumes",
    "tests/test_faults.py::test_sigint_during_an_update_lets_it_finish",
    "tests/test_faults.py::test_an_ignored_sigint_stays_ignored",
    "tests/test_faults.py::test_train_command_saves_on_sigint_and_resumes",
    "tests/test_rollouts.py::test_ctrl_c_while_workers_collect_lets_the_segment_finish_and_saves_a_checkpoint",
    "tests/test_rollouts.py::test_process_workers_ignore_sigint",
]


@pytest.mark.slow
def test_the_signal_tests_pass_in_a_background_job() -> None:
    """``make test &`` starts the suite with SIGINT ignored; every test that sends SIGINT passes there too."""
    root = Path(__file__).resolve().parents[1]
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "0", *SIGNAL_TESTS]
    result = subprocess.run(command, cwd=root, capture_output=True, text=True, timeout=900, preexec_fn=sigint.ignored_in_child)
    assert result.returncode == 0, result.stdout[-4000:]
    assert f"{len(SIGNAL_TESTS)} passed" in result.stdout


@pytest.mark.slow
def test_train_command_saves_on_sigint_and_resumes(tmp_path: Path) -> None:
    conf = tmp_path / "conf.yml"
    conf.write_text(
        "Reacher2D-v0:\n  n_envs: 1\n  n_timesteps: 10000000\n  policy: MlpPolicy\n  normalize: true\n"
        "  n_steps: 64\n  batch_size: 64\n  replay_memory: 2\n  policy_kwargs: {net_arch: [16]}\n"
    )
    logs = tmp_path / "logs"
    command = [sys.executable, "-m", "sb3_trpo_plus", "train", "--env", "Reacher2D-v0", "-conf", str(conf)]
    command += ["-f", str(logs), "--seed", "0", "--eval-freq", "-1", "--num-threads", "1", "--device", "cpu"]
    run = logs / "trpo_plus" / "Reacher2D-v0_1"
    child = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        cwd=tmp_path,
        preexec_fn=sigint.handled_in_child,
    )
    try:

        def episodes() -> int:  # the batched engine's monitor file (the default VecEnv of grasp_envs' ids)
            monitor = run / "batch.monitor.csv"
            return len(monitor.read_text().splitlines()) - 2 if monitor.exists() else 0

        wait_for(lambda: episodes() >= 5 or child.poll() is not None, 180, "five episodes")  # > 3 rollouts of 64
        assert child.poll() is None, child.stdout.read() if child.stdout else ""
        child.send_signal(signal.SIGINT)
        output, _ = child.communicate(timeout=120)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 0, output
    assert "interrupted" in output
    model = TRPOPlus.load(run / "Reacher2D-v0.zip", device="cpu")
    assert len(model.rollout_memory) == 2
    assert load_normalization(run / "Reacher2D-v0" / "vecnormalize.pkl").obs_count > 200  # type: ignore[operator]
    policy, statistics, _ = load_agent(run)  # rl-zoo3's OrderedDict YAML, read safely
    assert statistics is not None and policy is not None
    updates = model._n_updates
    resume = [*command, "-i", str(run / "Reacher2D-v0.zip"), "-n", "128"]
    subprocess.run(resume, check=True, capture_output=True, cwd=tmp_path, timeout=300)
    resumed = TRPOPlus.load(logs / "trpo_plus" / "Reacher2D-v0_2" / "Reacher2D-v0.zip", device="cpu")
    assert resumed._n_updates == updates + 2 and len(resumed.rollout_memory) == 2


# ---------------------------------------------------------------------------------------------- a worker dies
class DieAtStep(gym.Wrapper):
    """Kills its own process (SIGKILL, as the out-of-memory killer would) at its ``step``-th step."""

    def __init__(self, env: gym.Env, step: int):
        super().__init__(env)
        self.remaining = step

    def step(self, action: Any) -> Any:
        self.remaining -= 1
        if self.remaining == 0:
            os.kill(os.getpid(), signal.SIGKILL)
        return self.env.step(action)


def dying_env_fns() -> list[Any]:
    return [lambda: Monitor(gym.make("Pendulum-v1")), lambda: DieAtStep(Monitor(gym.make("Pendulum-v1")), 150)]


class ParametersAtRolloutStart(BaseCallback):
    def _on_training_start(self) -> None:
        self.before: dict[str, np.ndarray] = {}

    def _on_rollout_start(self) -> None:
        self.before = parameters(self.model)  # type: ignore[arg-type]

    def _on_step(self) -> bool:
        return True


def test_dead_subproc_vec_env_worker_is_named_and_weights_are_untouched() -> None:
    """SB3's ``SubprocVecEnv`` (one env per process): a worker's death is named as the pools name theirs
    (tests/test_rollouts.py)."""
    # forkserver (the default), not fork: forked SubprocVecEnv workers inherit each other's pipe ends, so a dead
    # worker's pipe would never report end-of-file
    env = SubprocVecEnv(dying_env_fns())
    model = tiny_model(env)
    record = ParametersAtRolloutStart()
    try:
        with pytest.raises(
            RolloutWorkerError, match=r"worker 1 \(pid \d+\) stepping env 1 \(Pendulum-v1\) died: killed by SIGKILL"
        ) as caught:
            model.learn(10_000, callback=record)
    finally:
        with contextlib.suppress(ConnectionError, EOFError):  # SB3's SubprocVecEnv.close trips on the dead worker
            env.close()
        for process in env.processes:
            if process.is_alive():
                process.terminate()
    assert isinstance(caught.value.__cause__, (EOFError, ConnectionError))
    assert model._n_updates == 2  # steps 129-150 of each env were the third rollout: it never reached its update
    for name, value in parameters(model).items():
        np.testing.assert_array_equal(value, record.before[name], err_msg=name)


# ---------------------------------------------------------------------------------------------- full disk
class DiskFullWriter(io.BufferedWriter):
    """A file on a disk that fills up after ``capacity`` bytes."""

    def __init__(self, raw: io.FileIO, capacity: int):
        super().__init__(raw)
        self.capacity = capacity

    def write(self, data: Any) -> int:
        self.capacity -= len(data)
        if self.capacity < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(data)


def test_full_disk_keeps_the_previous_model_and_raises(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    model = tiny_model("Pendulum-v1")
    path = tmp_path / "model.zip"
    model.save(path)
    before = path.read_bytes()
    model.learn(128)
    monkeypatch.setattr(persistence, "open", lambda name, mode: DiskFullWriter(io.FileIO(name, mode), 4096), raising=False)
    with pytest.raises(OSError, match=r"model\.zip") as caught:
        model.save(path)
    assert caught.value.errno == errno.ENOSPC
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["model.zip"]  # the temporary file is gone
    monkeypatch.undo()
    assert TRPOPlus.load(path, device="cpu").num_timesteps == 0


def test_full_disk_keeps_the_previous_statistics(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    path = tmp_path / "vecnormalize.pkl"
    save_vec_normalize(env, path)
    before = path.read_bytes()
    env.reset()
    env.step(np.zeros((1, 1), dtype=np.float32))
    monkeypatch.setattr(persistence, "open", lambda name, mode: DiskFullWriter(io.FileIO(name, mode), 100), raising=False)
    with pytest.raises(OSError, match=r"vecnormalize\.pkl") as caught:
        save_vec_normalize(env, path)
    monkeypatch.undo()
    assert caught.value.errno == errno.ENOSPC
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["vecnormalize.pkl"]


# ---------------------------------------------------------------------------------------------- damaged files
@pytest.fixture(scope="module")
def run_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small rl-zoo3 run folder: model zip, config.yml, vecnormalize.pkl."""
    run = tmp_path_factory.mktemp("logs") / "trpo_plus" / "Pendulum-v1_1"
    (run / "Pendulum-v1").mkdir(parents=True)
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    model = tiny_model(env)
    model.learn(64)
    model.save(run / "Pendulum-v1.zip")
    save_vec_normalize(env, run / "Pendulum-v1" / "vecnormalize.pkl")
    (run / "Pendulum-v1" / "config.yml").write_text(json.dumps({"policy": "MlpPolicy", "normalize": True}))
    return run


def damaged_copy(source: Path, target: Path, how: str) -> Path:
    data = bytearray(source.read_bytes())
    if how == "truncated":
        data = data[: len(data) // 2]
    else:  # corrupted: bytes flipped in the middle
        middle = len(data) // 2
        data[middle : middle + 64] = bytes(255 - b for b in data[middle : middle + 64])
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(bytes(data))
    return target


@pytest.mark.parametrize("how", ["truncated", "corrupted"])
def test_damaged_model_zip_is_named(run_folder: Path, tmp_path: Path, how: str) -> None:
    damaged = damaged_copy(run_folder / "Pendulum-v1.zip", tmp_path / "model.zip", how)
    with pytest.raises(ValueError, match=rf"{re.escape(str(damaged))}.*(truncated|corrupted)"):
        TRPOPlus.load(damaged, device="cpu")
    env = gym.make("Pendulum-v1")
    with pytest.raises(RunFileError, match=rf"{re.escape(str(damaged))}: "):
        load_policy(damaged, env.observation_space, env.action_space)


@pytest.mark.parametrize("how", ["truncated", "corrupted"])
def test_damaged_statistics_are_named(run_folder: Path, tmp_path: Path, how: str) -> None:
    damaged = damaged_copy(run_folder / "Pendulum-v1" / "vecnormalize.pkl", tmp_path / "vecnormalize.pkl", how)
    with pytest.raises(RunFileError, match=rf"{re.escape(str(damaged))}: "):
        load_normalization(damaged)


def test_damaged_config_is_named(run_folder: Path, tmp_path: Path) -> None:
    config = tmp_path / "trpo_plus" / "Pendulum-v1_1" / "Pendulum-v1" / "config.yml"
    config.parent.mkdir(parents=True)
    config.write_text('{"policy": "MlpPolicy", "normalize": [tru')
    with pytest.raises(RunFileError, match=rf"{re.escape(str(config))}: malformed YAML"):
        read_run_config(config.parents[1])


def test_damaged_files_in_a_run_are_named_by_load_agent(run_folder: Path, tmp_path: Path) -> None:
    run = tmp_path / "trpo_plus" / "Pendulum-v1_1"
    (run / "Pendulum-v1").mkdir(parents=True)
    (run / "Pendulum-v1" / "config.yml").write_bytes((run_folder / "Pendulum-v1" / "config.yml").read_bytes())
    (run / "Pendulum-v1.zip").write_bytes((run_folder / "Pendulum-v1.zip").read_bytes())
    pkl = damaged_copy(run_folder / "Pendulum-v1" / "vecnormalize.pkl", run / "Pendulum-v1" / "vecnormalize.pkl", "truncated")
    for trust_pickle in (False, True):
        with pytest.raises(RunFileError, match=re.escape(str(pkl))):
            load_agent(run, trust_pickle=trust_pickle)


@pytest.mark.parametrize("file", ["Pendulum-v1/vecnormalize.pkl", "Pendulum-v1.zip"])
def test_randomly_flipped_bytes_are_named_on_both_loading_paths(run_folder: Path, tmp_path: Path, file: str) -> None:
    """A few bytes of a real file set at random, 150 times (seeded): the weights-only and the trusted loader either
    load the run or raise RunFileError naming the file, whatever the unpickled bytes make Python raise."""
    run = tmp_path / "trpo_plus" / "Pendulum-v1_1"
    shutil.copytree(run_folder, run)
    target = run / file
    original = target.read_bytes()
    rng = np.random.default_rng(0)
    refused = 0
    for _ in range(150):
        damaged = bytearray(original)
        for position in rng.integers(len(original), size=rng.integers(1, 5)):
            damaged[position] = rng.integers(256)
        target.write_bytes(bytes(damaged))
        for trust_pickle in (False, True):
            try:
                _, env = load_eval_agent(run, trust_pickle=trust_pickle)
            except RunFileError as error:
                assert str(error).startswith(f"{target}: "), error
                refused += 1
            else:
                env.close()
    assert refused > 150  # most damaged files are refused (a flipped byte can also fall where nothing reads it)


def resume_command(logs: Path, model: Path) -> list[str]:
    """``trpo-plus train -i model``: continue a run (rl-zoo3 unpickles the model and the statistics beside it)."""
    flags = ["-f", str(logs), "-i", str(model), "-n", "64", "--eval-freq", "-1", "--num-threads", "1", "--device", "cpu"]
    return ["train", "--env", "Pendulum-v1", *flags, "-params", "n_envs:1", "n_steps:64", "batch_size:64"]


@pytest.mark.parametrize("how", ["truncated", "corrupted"])
@pytest.mark.parametrize("file", ["Pendulum-v1/vecnormalize.pkl", "Pendulum-v1.zip"])
def test_damaged_files_of_a_resumed_run_are_named(
    run_folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, file: str, how: str
) -> None:
    from sb3_trpo_plus.application import cli

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", list(sys.argv))  # rl-zoo3's train reads its flags from sys.argv
    run = tmp_path / "logs" / "trpo_plus" / "Pendulum-v1_1"
    shutil.copytree(run_folder, run)
    damaged = damaged_copy(run_folder / file, run / file, how)
    with pytest.raises(RunFileError, match=rf"{re.escape(str(damaged))}: .*(truncated|corrupted)"):
        cli.main(resume_command(tmp_path / "logs", run / "Pendulum-v1.zip"))


# ---------------------------------------------------------------------------------------------- older models
COMPAT_FOLDERS = sorted(p for p in COMPAT.iterdir() if p.is_dir() and (p / "manifest.json").exists())


@pytest.mark.parametrize("folder", COMPAT_FOLDERS, ids=[p.name for p in COMPAT_FOLDERS])
def test_model_of_a_released_version_loads_and_trains(folder: Path) -> None:
    manifest = json.loads((folder / "manifest.json").read_text())
    env = VecNormalize.load(str(folder / "vecnormalize.pkl"), make_vec_env(manifest["env_id"], n_envs=1, seed=1))
    model = TRPOPlus.load(folder / "model.zip", env=env, device="cpu")
    shapes = {name: list(value.shape) for name, value in model.policy.state_dict().items()}
    assert shapes == manifest["parameters"]  # parameter names are part of the format
    assert model.num_timesteps == manifest["num_timesteps"] and model._n_updates == manifest["n_updates"]
    assert len(model.rollout_memory) == manifest["replay_rollouts"]
    model.learn(128, reset_num_timesteps=False)
    assert model._n_updates == manifest["n_updates"] + 2
    assert all(th.isfinite(p).all() for p in model.policy.parameters())
    policy = load_policy(folder / "model.zip", env.observation_space, env.action_space)  # the weights-only reader too
    assert sorted(policy.state_dict()) == sorted(manifest["parameters"])
    env.close()


def test_compat_fixture_is_small() -> None:
    assert COMPAT_FOLDERS, "no compatibility fixture in tests/data/compat"
    for folder in COMPAT_FOLDERS:
        assert sum(p.stat().st_size for p in folder.iterdir()) < 200_000
        with zipfile.ZipFile(folder / "model.zip") as archive:
            assert {"data", "policy.pth", "policy.optimizer.pth", "pytorch_variables.pth"} <= set(archive.namelist())


@pytest.mark.parametrize("how", ["truncated", "corrupted"])
def test_damaged_statistics_of_a_trusted_enjoy_are_named(
    run_folder: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, how: str
) -> None:
    """``trpo-plus enjoy --trust-pickle`` unpickles ``vecnormalize.pkl`` with SB3; a damaged one is named."""
    from sb3_trpo_plus.application import cli

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "argv", list(sys.argv))
    run = tmp_path / "logs" / "trpo_plus" / "Pendulum-v1_1"
    shutil.copytree(run_folder, run)
    file = "Pendulum-v1/vecnormalize.pkl"
    damaged = damaged_copy(run_folder / file, run / file, how)
    command = ["enjoy", "--env", "Pendulum-v1", "-f", str(tmp_path / "logs"), "--exp-id", "1", "--no-render", "-n", "5"]
    with pytest.raises(RunFileError, match=rf"{re.escape(str(damaged))}: "):
        cli.main([*command, "--trust-pickle"])
