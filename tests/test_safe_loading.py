"""No code runs from a run's files: YAML, the model zip and the VecNormalize statistics are read as data."""

from __future__ import annotations

import base64
import io
import json
import os
import pickle
import re
import shutil
import zipfile
from collections import OrderedDict
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
import yaml
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.application import cli, run_folders
from sb3_trpo_plus.application.agents import (
    RunFileError,
    load_agent,
    load_eval_agent,
    load_normalization,
    load_policy,
    load_run_yaml,
    read_run_config,
)
from sb3_trpo_plus.application.callbacks import save_vec_normalize

TRAINED = run_folders.TRAINED_AGENTS / "trpo_plus"


class RunsCommand:
    """Unpickling this runs ``os.system(command)``: the attack a pickle can carry."""

    def __init__(self, command: str):
        self.command = command

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        return os.system, (self.command,)


@pytest.fixture
def marker(tmp_path: Path) -> Path:
    """A file that exists only if injected code ran."""
    return tmp_path / "pwned"


@pytest.fixture
def run(tmp_path: Path) -> Path:
    """A small rl-zoo3 run folder: model zip, config.yml and args.yml as rl-zoo3 writes them, vecnormalize.pkl."""
    folder = tmp_path / "logs" / "trpo_plus" / "Pendulum-v1_1"
    (folder / "Pendulum-v1").mkdir(parents=True)
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    model = TRPOPlus("MlpPolicy", env, n_steps=64, batch_size=64, policy_kwargs=dict(net_arch=[16]), device="cpu")
    model.learn(64)
    model.save(folder / "Pendulum-v1.zip")
    save_vec_normalize(env, folder / "Pendulum-v1" / "vecnormalize.pkl")
    config = OrderedDict([("normalize", True), ("policy", "MlpPolicy"), ("policy_kwargs", "dict(net_arch=[16])")])
    config["monitor_kwargs"] = {"info_keywords": ("is_success",)}  # a tuple: !!python/tuple
    config["eval_policy_kwargs"] = {"activation_fn": th.nn.Tanh}  # a class: !!python/name
    (folder / "Pendulum-v1" / "config.yml").write_text(yaml.dump(config))
    args = OrderedDict([("algo", "trpo_plus"), ("env", "Pendulum-v1"), ("env_kwargs", {"g": 9.81})])
    (folder / "Pendulum-v1" / "args.yml").write_text(yaml.dump(args))
    return folder


# ---------------------------------------------------------------------------------------------- YAML
def test_reads_rl_zoo_ordered_dicts(run: Path) -> None:
    assert yaml.dump(OrderedDict(a=1)).startswith("!!python/object/apply:collections.OrderedDict")
    config = read_run_config(run)
    assert config.env_id == "Pendulum-v1" and config.algo == "trpo_plus"
    assert config.env_kwargs == {"g": 9.81}  # args.yml's, as rl-zoo3's enjoy
    assert config.normalize_kwargs == {"norm_obs": True, "norm_reward": False}
    assert config.hyperparams["policy_kwargs"] == {"net_arch": [16]}
    assert config.hyperparams["monitor_kwargs"] == {"info_keywords": ("is_success",)}
    assert config.hyperparams["eval_policy_kwargs"] == {"activation_fn": th.nn.Tanh}


TAGS = [
    '!!python/object/apply:os.system ["touch {marker}"]',
    '!!python/object/new:os.system ["touch {marker}"]',
    "!!python/name:os.system",
    '!!python/object/apply:collections.OrderedDict [[["a", !!python/object/apply:os.system ["touch {marker}"]]]]',
]


@pytest.mark.parametrize("tag", TAGS, ids=["apply", "new", "name", "nested-in-ordered-dict"])
@pytest.mark.parametrize("file", ["config.yml", "args.yml"])
def test_python_tags_are_refused(run: Path, marker: Path, tag: str, file: str) -> None:
    path = run / "Pendulum-v1" / file
    path.write_text(f"env_kwargs: {tag.format(marker=marker)}\nnormalize: true\n")
    with pytest.raises(RunFileError, match=rf"{re.escape(str(path))}: refused: .*python/"):
        load_agent(run)
    with pytest.raises(RunFileError, match=re.escape(str(path))):
        load_agent(run, trust_pickle=True)  # the YAML is read safely on the trusted path too
    assert not marker.exists()


CODE_STRINGS = {
    "normalize": "__import__('os').system('touch {marker}')",
    "policy_kwargs": "dict(net_arch=__import__('os').system('touch {marker}'))",
    "monitor_kwargs": "dict(info_keywords=__import__('os').system('touch {marker}'))",
}


@pytest.mark.parametrize("key", sorted(CODE_STRINGS))
def test_code_strings_are_refused(run: Path, marker: Path, key: str) -> None:
    path = run / "Pendulum-v1" / "config.yml"
    path.write_text(yaml.safe_dump({"policy": "MlpPolicy", "normalize": True, key: CODE_STRINGS[key].format(marker=marker)}))
    with pytest.raises(RunFileError, match=re.escape(str(path))):
        load_agent(run)
    assert not marker.exists()


def test_enjoy_and_record_video_refuse_code_in_yaml(run: Path, marker: Path) -> None:
    folder = str(run.parents[1])
    (run / "Pendulum-v1" / "args.yml").write_text(f'env_kwargs: !!python/object/apply:os.system ["touch {marker}"]\n')
    base = ["--env", "Pendulum-v1", "-f", folder, "--exp-id", "1", "-n", "5", "--no-render"]
    for command in (cli.enjoy, cli.record_video):
        argv = [a for a in base if a != "--no-render"] if command is cli.record_video else base
        with pytest.raises(RunFileError, match=r"args\.yml: refused"):
            command(argv)
    with pytest.raises(RunFileError, match=r"args\.yml: refused"):
        cli.enjoy([*base, "--trust-pickle"])  # read as data on the trusted path too
    assert not marker.exists()


CODE_STRINGS_IN_RUN = [
    ("config.yml", "normalize"),
    ("config.yml", "policy_kwargs"),
    ("config.yml", "monitor_kwargs"),
    ("args.yml", "env_kwargs"),  # rl-zoo3 passes it to the env constructor as it is
]


@pytest.mark.parametrize("trust_pickle", [False, True], ids=["weights-only", "trust-pickle"])
@pytest.mark.parametrize(("file", "key"), CODE_STRINGS_IN_RUN, ids=[f"{f}-{k}" for f, k in CODE_STRINGS_IN_RUN])
def test_enjoy_and_record_video_refuse_code_strings(
    run: Path, marker: Path, monkeypatch: pytest.MonkeyPatch, file: str, key: str, trust_pickle: bool
) -> None:
    path = run / "Pendulum-v1" / file
    code = CODE_STRINGS.get(key, "__import__('os').system('touch {marker}')").format(marker=marker)
    if file == "config.yml":
        path.write_text(yaml.safe_dump({"policy": "MlpPolicy", "normalize": True, key: code}))
    else:
        path.write_text(yaml.safe_dump({"algo": "trpo_plus", "env": "Pendulum-v1", key: code}))
    trust = ["--trust-pickle"] if trust_pickle else []
    base = ["--env", "Pendulum-v1", "-f", str(run.parents[1]), "--exp-id", "1", "-n", "5", *trust]
    for argv in ([*base, "--no-render"], base):
        command = cli.enjoy if "--no-render" in argv else cli.record_video
        with pytest.raises(RunFileError, match=rf"{re.escape(str(path))}: .*{key}"):
            command(argv)
    assert not marker.exists()


DOWNLOADED_CODE = {
    "config-tag": ("config.yml", 'normalize: !!python/object/apply:os.system ["touch {marker}"]\n'),
    "config-normalize-string": ("config.yml", "normalize: \"__import__('os').system('touch {marker}')\"\n"),
    "args-tag": ("args.yml", 'env_kwargs: !!python/object/apply:os.system ["touch {marker}"]\n'),
}


@pytest.mark.parametrize("case", sorted(DOWNLOADED_CODE))
def test_enjoy_reads_a_run_downloaded_from_the_hub_as_data(
    run: Path, marker: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """As rl-zoo3's enjoy, a run not found under an ``rl-trained-agents`` folder is downloaded from the hub; its YAML
    is then read as data, even with ``--trust-pickle`` (rl-zoo3 would read it with ``yaml.UnsafeLoader`` and evaluate
    ``normalize``)."""
    import rl_zoo3.load_from_hub

    file, text = DOWNLOADED_CODE[case]
    folder = tmp_path / "rl-trained-agents"
    downloaded: list[Path] = []

    def download_from_hub(algo: str, env_name: Any, exp_id: int, folder: str, **_: Any) -> None:
        target = Path(folder, algo, f"{env_name}_1")  # the hub's copy of the run, code in its YAML
        shutil.copytree(run, target)
        (target / "Pendulum-v1" / file).write_text(text.format(marker=marker))
        downloaded.append(target)

    monkeypatch.setattr(rl_zoo3.load_from_hub, "download_from_hub", download_from_hub)
    path = folder / "trpo_plus" / "Pendulum-v1_1" / "Pendulum-v1" / file
    with pytest.raises(RunFileError, match=rf"{re.escape(str(path))}: .*refused"):
        cli.enjoy(["--env", "Pendulum-v1", "-f", str(folder), "--trust-pickle", "-n", "5", "--no-render"])
    assert downloaded and not marker.exists()


def test_malformed_ordered_dict_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "config.yml"
    path.write_text("!!python/object/apply:collections.OrderedDict [1, 2]\n")
    with pytest.raises(RunFileError, match="OrderedDict"):
        load_run_yaml(path)


def test_wrappers_only_from_known_packages(run: Path, marker: Path) -> None:
    path = run / "Pendulum-v1" / "config.yml"
    for wrapper in ("os.system", "subprocess.Popen", "gymnasium.make"):
        path.write_text(yaml.safe_dump({"policy": "MlpPolicy", "normalize": True, "env_wrapper": wrapper}))
        with pytest.raises(RunFileError, match="env_wrapper"):
            load_agent(run)
    path.write_text(yaml.safe_dump({"policy": "MlpPolicy", "normalize": True, "env_wrapper": "gymnasium.wrappers.ClipAction"}))
    policy, _, _ = load_agent(run)
    assert policy is not None and not marker.exists()


# ---------------------------------------------------------------------------------------------- model zip
def rewrite_zip(path: Path, entry: str, content: bytes) -> None:
    with zipfile.ZipFile(path) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    entries[entry] = content
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in entries.items():
            archive.writestr(name, data)


def test_pickled_fields_of_the_zip_are_never_decoded(run: Path, marker: Path) -> None:
    model_path = run / "Pendulum-v1.zip"
    with zipfile.ZipFile(model_path) as archive:
        data = json.loads(archive.read("data"))
    payload = base64.b64encode(pickle.dumps(RunsCommand(f"touch {marker}"))).decode()
    for key in ("lr_schedule", "observation_space", "rollout_memory", "policy_class"):
        data[key] = {**(data[key] if isinstance(data.get(key), dict) else {}), ":serialized:": payload}
    rewrite_zip(model_path, "data", json.dumps(data).encode())
    policy, _, _ = load_agent(run)
    assert policy is not None and not marker.exists()


def test_pickle_in_policy_weights_is_refused(run: Path, marker: Path) -> None:
    model_path = run / "Pendulum-v1.zip"
    rewrite_zip(model_path, "policy.pth", pickle.dumps(RunsCommand(f"touch {marker}")))
    with pytest.raises(RunFileError, match=rf"{re.escape(str(model_path))}: policy.pth cannot be read as plain weights"):
        load_agent(run)
    assert not marker.exists()


def test_weights_that_do_not_fit_are_named(run: Path) -> None:
    env = gym.make("Pendulum-v1")
    with pytest.raises(RunFileError, match=r"does not fit|cannot rebuild"):
        load_policy(run / "Pendulum-v1.zip", env.observation_space, gym.spaces.Box(-1, 1, (4,)))


# ---------------------------------------------------------------------------------------------- VecNormalize pickle
def test_code_in_statistics_is_refused(run: Path, marker: Path) -> None:
    path = run / "Pendulum-v1" / "vecnormalize.pkl"
    path.write_bytes(pickle.dumps({"obs_rms": RunsCommand(f"touch {marker}")}))
    with pytest.raises(RunFileError, match=rf"{re.escape(str(path))}: refused the global (posix|os|nt)\.system"):
        load_normalization(path)
    assert not marker.exists()


def test_statistics_equal_vec_normalize_load(run: Path) -> None:
    path = run / "Pendulum-v1" / "vecnormalize.pkl"
    trusted = VecNormalize.load(str(path), make_vec_env("Pendulum-v1", n_envs=1))
    stats = load_normalization(path)
    np.testing.assert_array_equal(stats.obs_mean, trusted.obs_rms.mean)  # type: ignore[arg-type]
    np.testing.assert_array_equal(stats.obs_var, trusted.obs_rms.var)  # type: ignore[arg-type]
    assert stats.obs_count == trusted.obs_rms.count and stats.clip_obs == trusted.clip_obs
    assert (stats.norm_obs, stats.norm_reward, stats.gamma) == (trusted.norm_obs, trusted.norm_reward, trusted.gamma)


@pytest.mark.parametrize("norm_reward", [True, False])
def test_statistics_normalise_as_vec_normalize(tmp_path: Path, norm_reward: bool) -> None:
    """The loaded statistics' normalize/unnormalize of observations and rewards equal the unpickled VecNormalize's."""
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=0), norm_reward=norm_reward, clip_obs=1.5)
    env.reset()
    for _ in range(50):
        env.step(np.random.default_rng(0).uniform(-2, 2, (2, 1)).astype(np.float32))
    env.save(str(tmp_path / "vecnormalize.pkl"))
    trusted = VecNormalize.load(str(tmp_path / "vecnormalize.pkl"), make_vec_env("Pendulum-v1", n_envs=1))
    stats = load_normalization(tmp_path / "vecnormalize.pkl")
    rng = np.random.default_rng(1)
    for obs in (rng.normal(0, 3, 3), rng.normal(0, 3, (5, 3))):  # one observation of gym.make, and a batch
        normalized = stats.normalize_obs(obs)
        np.testing.assert_array_equal(normalized, trusted.normalize_obs(obs))
        assert normalized.dtype == np.float32 and np.abs(normalized).max() <= 1.5  # type: ignore[union-attr]
        np.testing.assert_array_equal(stats.unnormalize_obs(obs), trusted.unnormalize_obs(obs))
    rewards = rng.normal(0, 5, 4)
    np.testing.assert_array_equal(stats.normalize_reward(rewards), trusted.normalize_reward(rewards))
    np.testing.assert_array_equal(stats.unnormalize_reward(rewards), trusted.unnormalize_reward(rewards))
    with pytest.raises(ValueError, match=r"shape \(4,\) does not end in the statistics' \(3,\)"):
        stats.normalize_obs(np.zeros(4))
    env.close()


def test_a_loaded_agent_acts_on_a_plain_gymnasium_env() -> None:
    """No VecEnv: the statistics normalise gym.make's observation, as the run's test VecEnv does."""
    run = TRAINED / "Reacher2D-v1_1"
    policy, statistics, _ = load_agent(run)
    _, vec_env = load_eval_agent(run, seed=3)
    assert statistics is not None
    env = gym.make("Reacher2D-v1")
    obs, _ = env.reset(seed=3)
    np.testing.assert_allclose(statistics.normalize_obs(obs), vec_env.reset()[0], rtol=0, atol=0)
    action, _ = policy.predict(statistics.normalize_obs(obs), deterministic=True)
    assert env.action_space.contains(action)
    env.close()
    vec_env.close()


# ---------------------------------------------------------------------------------------------- same agent either way
@pytest.mark.parametrize("env_id", ["Reacher2D-v1", "Grasper3D-v6"])
def test_weights_only_agent_acts_as_the_full_load(env_id: str) -> None:
    run = TRAINED / f"{env_id}_1"
    policy, safe_env = load_eval_agent(run, seed=3)
    model, trusted_env = load_eval_agent(run, trust_pickle=True, seed=3)
    assert isinstance(model, TRPOPlus) and not isinstance(policy, TRPOPlus)
    obs_safe, obs_trusted = safe_env.reset(), trusted_env.reset()
    for _ in range(60):
        np.testing.assert_array_equal(obs_safe, obs_trusted)
        action_safe, _ = policy.predict(obs_safe, deterministic=True)
        action_trusted, _ = model.predict(obs_trusted, deterministic=True)
        np.testing.assert_array_equal(action_safe, action_trusted)
        obs_safe, *_ = safe_env.step(action_safe)
        obs_trusted, *_ = trusted_env.step(action_trusted)
    safe_env.close()
    trusted_env.close()


def test_enjoy_runs_a_shipped_agent_through_the_safe_path(capsys: pytest.CaptureFixture[str]) -> None:
    summary = cli.enjoy(["--env", "Reacher2D-v1", "--no-render", "-n", "200"])
    assert summary["episodes"] == 4 and summary["success_rate"] >= 0.5
    assert "Success rate" in capsys.readouterr().out


def test_load_agent_returns_env_kwargs_and_statistics() -> None:
    policy, statistics, env_kwargs = load_agent(TRAINED / "Grasper3D-v6_1")
    assert env_kwargs == {"start_pose": "ready"}
    assert statistics is not None and statistics.obs_mean.shape == policy.observation_space.shape  # type: ignore[union-attr]
    buffer = io.BytesIO()
    pickle.dump(statistics, buffer)  # plain data: picklable, shareable
