"""sb3_trpo_plus.application.evaluation: seeded episodes, fixed VecNormalize statistics, the env's own returns and
successes."""

import os
import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.vec_env import VecNormalize

import grasp_envs  # noqa: F401  (registers the envs)
from sb3_trpo_plus.application.agents import RunFileError, load_normalization
from sb3_trpo_plus.application.evaluation import evaluate_agent, evaluation_env

ENV_ID = "Reacher2D-v1"


class Recorder:
    """A policy that pushes with a constant action and keeps every observation it is shown."""

    def __init__(self, action: float = 0.5) -> None:
        self.action = action
        self.observations: list[np.ndarray] = []

    def predict(self, observation: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        self.observations.append(np.array(observation[0]))
        return np.full((1, 2), self.action, dtype=np.float32), None


def _episode(seed: int | None, env: gym.Env | None = None, action: float = 0.5) -> tuple[list[np.ndarray], float, bool]:
    """One episode of the constant action on a plain env reset with ``seed``: observations, return, final success."""
    env = env or gym.make(ENV_ID)
    observation, _ = env.reset(seed=seed)
    observations, total, done, info = [observation], 0.0, False, {}
    while not done:
        observation, reward, terminated, truncated, info = env.step(np.full(2, action, dtype=np.float32))
        total += float(reward)
        done = terminated or truncated
        observations.append(observation)
    return observations[:-1], total, bool(info.get("is_success", False))


def test_episode_k_is_reset_with_seed_plus_k_and_gives_the_envs_return_and_success() -> None:
    policy = Recorder()
    result = evaluate_agent(policy, evaluation_env(ENV_ID), n_episodes=3, seed=40)
    expected = [_episode(40 + k) for k in range(3)]
    length = len(expected[0][0])
    assert len(policy.observations) == 3 * length
    for k, (observations, total, success) in enumerate(expected):
        np.testing.assert_allclose(policy.observations[k * length : (k + 1) * length], observations, rtol=1e-6)
        assert result.returns[k] == pytest.approx(total, abs=1e-5)
        assert result.successes[k] == success
    assert result.episodes == 3
    assert result.mean_return == pytest.approx(np.mean([total for _, total, _ in expected]), abs=1e-5)
    assert result.success_rate == np.mean([success for _, _, success in expected])
    # the same episodes whatever ran before: episodes 1 and 2 are those of a run from seed 41
    again = evaluate_agent(Recorder(), evaluation_env(ENV_ID), n_episodes=2, seed=41)
    assert again.returns == result.returns[1:]


def test_seeded_once_the_later_episodes_continue_the_envs_generator() -> None:
    policy = Recorder()
    result = evaluate_agent(policy, evaluation_env(ENV_ID), n_episodes=2, seed=40, seed_every_episode=False)
    env = gym.make(ENV_ID)
    first, second = _episode(40, env), _episode(None, env)  # the second reset draws from the first's generator
    assert result.returns == pytest.approx((first[1], second[1]), abs=1e-5)
    np.testing.assert_allclose(policy.observations[len(first[0])], second[0][0], rtol=1e-6)


@pytest.mark.parametrize("saved", [False, True])
def test_vecnormalize_statistics_normalize_the_observations_and_stay_fixed(tmp_path: Path, saved: bool) -> None:
    statistics = RunningMeanStd(shape=gym.make(ENV_ID).observation_space.shape)
    statistics.mean, statistics.var = np.full_like(statistics.mean, 0.1), np.full_like(statistics.var, 4.0)
    statistics.count = 7.0
    if saved:  # a run's vecnormalize.pkl
        training = VecNormalize(make_vec_env(ENV_ID, n_envs=1))
        training.obs_rms = statistics
        training.save(str(tmp_path / "vecnormalize.pkl"))
    env = evaluation_env(ENV_ID, normalization=tmp_path / "vecnormalize.pkl" if saved else statistics)
    assert isinstance(env, VecNormalize) and not env.training and not env.norm_reward
    policy = Recorder()
    result = evaluate_agent(policy, env, n_episodes=1, seed=3)
    observations, total, _ = _episode(3)
    expected = np.clip((np.array(observations) - 0.1) / np.sqrt(4.0 + 1e-8), -10.0, 10.0)
    np.testing.assert_allclose(policy.observations, expected, rtol=1e-5, atol=1e-6)
    assert result.returns[0] == pytest.approx(total, abs=1e-5)  # the env's rewards, not normalized
    np.testing.assert_array_equal(env.obs_rms.mean, np.full_like(statistics.mean, 0.1))
    assert env.obs_rms.count == 7.0


def _saved_run(path: Path, **normalize_kwargs: float | bool) -> RunningMeanStd:
    """A run's vecnormalize.pkl with ``normalize_kwargs`` and observation statistics mean 0.1, var 4; returns them."""
    training = VecNormalize(make_vec_env(ENV_ID, n_envs=1), **normalize_kwargs)  # type: ignore[arg-type]
    statistics = RunningMeanStd(shape=training.observation_space.shape)
    statistics.mean, statistics.var = np.full_like(statistics.mean, 0.1), np.full_like(statistics.var, 4.0)
    if training.norm_obs:
        training.obs_rms = statistics
    training.save(str(path))
    return statistics


@pytest.mark.parametrize("source", ["path", "statistics", "training VecNormalize"])
def test_the_runs_clip_obs_and_epsilon_apply(tmp_path: Path, source: str) -> None:
    path = tmp_path / "vecnormalize.pkl"
    _saved_run(path, clip_obs=0.5, epsilon=0.25)
    normalization = {"path": path, "statistics": load_normalization(path), "training VecNormalize": None}[source]
    if normalization is None:
        normalization = VecNormalize.load(str(path), make_vec_env(ENV_ID, n_envs=1))
    env = evaluation_env(ENV_ID, normalization=normalization)
    assert isinstance(env, VecNormalize) and (env.clip_obs, env.epsilon, env.training, env.norm_reward) == (
        0.5,
        0.25,
        False,
        False,
    )
    policy = Recorder()
    evaluate_agent(policy, env, n_episodes=1, seed=3)
    observations, _, _ = _episode(3)
    expected = np.clip((np.array(observations) - 0.1) / np.sqrt(4.0 + 0.25), -0.5, 0.5)
    np.testing.assert_allclose(policy.observations, expected, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("saved", [False, True])
def test_a_run_that_did_not_normalize_observations_gets_the_envs_own(tmp_path: Path, saved: bool) -> None:
    """VecNormalize(norm_obs=False) (rl-zoo3's ``normalize: "dict(norm_obs=False, norm_reward=True)"``)."""
    path = tmp_path / "vecnormalize.pkl"
    _saved_run(path, norm_obs=False, norm_reward=True)
    normalization = path if saved else VecNormalize.load(str(path), make_vec_env(ENV_ID, n_envs=1))
    env = evaluation_env(ENV_ID, normalization=normalization)
    assert isinstance(env, VecNormalize) and not env.norm_obs and not env.norm_reward
    policy = Recorder()
    result = evaluate_agent(policy, env, n_episodes=1, seed=3)
    observations, total, _ = _episode(3)
    np.testing.assert_allclose(policy.observations, observations, rtol=1e-6)
    assert result.returns[0] == pytest.approx(total, abs=1e-5)


class RunsACommand:
    """Unpickled, it would run ``touch <mark>``: what a downloaded vecnormalize.pkl can carry."""

    def __init__(self, mark: Path) -> None:
        self.mark = mark

    def __reduce__(self) -> tuple:
        return os.system, (f"touch {self.mark}",)


@pytest.mark.parametrize("where", ["the whole file", "inside a VecNormalize"])
def test_a_vecnormalize_pickle_that_runs_code_is_refused_and_runs_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    monkeypatch.chdir(tmp_path)
    mark, path = tmp_path / "MARK", tmp_path / "vecnormalize.pkl"
    if where == "the whole file":
        path.write_bytes(pickle.dumps(RunsACommand(mark)))
    else:
        training = VecNormalize(make_vec_env(ENV_ID, n_envs=1))
        training.payload = RunsACommand(mark)  # type: ignore[attr-defined]
        training.save(str(path))
    with pytest.raises(RunFileError, match=r"refused the global (posix|os|nt)\.system"):
        evaluation_env(ENV_ID, normalization=path)
    assert not mark.exists()  # pickle.load would have made it


def test_one_env_and_at_least_one_episode() -> None:
    with pytest.raises(ValueError, match="one env"):
        evaluate_agent(Recorder(), make_vec_env(ENV_ID, n_envs=2), n_episodes=1, seed=0)
    with pytest.raises(ValueError, match="at least 1"):
        evaluate_agent(Recorder(), evaluation_env(ENV_ID), n_episodes=0, seed=0)


@pytest.mark.parametrize("source", ["path", "training VecNormalize", "observation statistics"])
def test_statistics_of_another_observation_shape_are_refused(tmp_path: Path, source: str) -> None:
    """Statistics saved for Reacher2D-v1 do not fit Reacher3D-v1's observations: refused when the env is built,
    naming both shapes, whichever form they come in."""
    from sb3_trpo_plus.algorithm.normalization import StatisticsMismatchError

    path = tmp_path / "vecnormalize.pkl"
    statistics = _saved_run(path)
    normalization = {"path": path, "observation statistics": statistics, "training VecNormalize": None}[source]
    if normalization is None:
        normalization = VecNormalize.load(str(path), make_vec_env(ENV_ID, n_envs=1))
    with pytest.raises(StatisticsMismatchError, match=r"statistics of shape \(\d+,\) do not fit the env's \(\d+,\)"):
        evaluation_env("Reacher3D-v1", normalization=normalization)


def test_norm_reward_frame_stack_and_several_envs(tmp_path: Path) -> None:
    """What ``trpo-plus enjoy --norm-reward --n-envs 2`` and a run's ``frame_stack`` build: rewards scaled by the
    statistics' return scale, frames stacked over the normalized observations, env ``i`` seeded ``seed + i``."""
    from stable_baselines3.common.vec_env import VecFrameStack

    path = tmp_path / "vecnormalize.pkl"
    training = VecNormalize(make_vec_env(ENV_ID, n_envs=1))
    training.ret_rms.var = np.array(9.0)
    training.save(str(path))
    env = evaluation_env(ENV_ID, normalization=path, seed=5, n_envs=2, frame_stack=3, norm_reward=True)
    assert isinstance(env, VecFrameStack) and env.num_envs == 2
    observations = env.reset()
    single = gym.make(ENV_ID).observation_space.shape[0]
    assert observations.shape == (2, 3 * single)
    for i in range(2):
        first, _ = gym.make(ENV_ID).reset(seed=5 + i)
        np.testing.assert_allclose(observations[i, -single:], np.clip(first / np.sqrt(1 + 1e-8), -10, 10), rtol=1e-5)
    _, rewards, _, _ = env.step(np.zeros((2, 2), dtype=np.float32))
    plain = gym.make(ENV_ID)
    plain.reset(seed=5)
    _, reward, _, _, _ = plain.step(np.zeros(2, dtype=np.float32))
    assert rewards[0] == pytest.approx(reward / np.sqrt(9.0 + 1e-8), rel=1e-5)
