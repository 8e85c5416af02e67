"""Stable-Baselines3's VecEnv tests, adapted to the batched engine (``grasp_envs.make_batch_env``).

SB3 checks its VecEnvs in ``tests/test_vec_envs.py``, ``tests/test_vec_normalize.py``, ``tests/test_vec_monitor.py``
and ``tests/test_vec_check_nan.py`` on toy environments built from ``env_fns``. The batched VecEnv is built from a
registered id instead, so each check here runs on our tasks and, where the behaviour must match, against
``DummyVecEnv([lambda: gymnasium.make(env_id)] * n)`` seeded the same way. The SB3 test each one ports is named in the
comment above it.

Not ported, as they do not apply to a VecEnv made from an id with Box spaces: ``test_vecenv_func_checker`` (``env_fns``
returning one instance), ``test_subproc_start_method`` (worker processes), ``test_vecenv_dict_spaces``,
``test_vecenv_tuple_spaces`` and the Discrete/MultiDiscrete/MultiBinary cases of ``test_vecenv_single_space`` (Box only
here), ``test_framestack_vecenv`` (image observations), ``test_vecenv_wrapper_getattr`` (wrapper-to-wrapper attribute
look-up, independent of the wrapped VecEnv), ``test_render`` in ``"human"`` mode (needs a display), and from
``test_vec_normalize.py`` the RunningMeanStd, Dict/Discrete observation, HER and off-policy tests.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor, load_results
from stable_baselines3.common.vec_env import (
    DummyVecEnv,
    VecCheckNan,
    VecEnv,
    VecFrameStack,
    VecMonitor,
    VecNormalize,
    VecVideoRecorder,
)
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from grasp_envs import make_batch_env
from grasp_envs.batch import BatchVecEnv

N_ENVS = 3
ENV_IDS = ["Reacher2D-v1", "Grasper3D-v7"]
RESET_ATOL = 1e-9  # a reset only seeds and sets the state: the same numbers
STEP_TOL = {"rtol": 1e-6, "atol": 1e-7}  # after stepping: the same physics, room for a reordered sum
RENDER_SIZE = {"width": 48, "height": 48}  # small frames: rendering is the slow part
ENV_METHODS = {"Reacher2D-v1": "distance", "Grasper3D-v7": "cube_pos"}  # a public method of each task

Factory = Callable[..., tuple[VecEnv, DummyVecEnv]]


def make_reference(env_id: str, n_envs: int = N_ENVS, **options: Any) -> DummyVecEnv:
    """SB3's reference VecEnv: one ``gymnasium.make`` per env, stepped in sequence."""
    return DummyVecEnv([lambda: gymnasium.make(env_id, **options)] * n_envs)


@pytest.fixture
def make_pair() -> Iterator[Factory]:
    """``make_pair(env_id, seed=None, n_threads=1, **options)``: the batched VecEnv and DummyVecEnv, both seeded with
    ``VecEnv.seed(seed)`` (used at their next reset); both closed after the test.

    The batched VecEnv is ``make_batch_env``'s without its episode records (``monitor=False``): the reference's envs
    have no ``Monitor`` (``test_constructor_seed_matches_make_vec_env`` compares the records).
    """
    made: list[VecEnv] = []

    def factory(
        env_id: str, seed: int | None = None, n_envs: int = N_ENVS, n_threads: int = 1, **options: Any
    ) -> tuple[VecEnv, DummyVecEnv]:
        batch = make_batch_env(env_id, n_envs, n_threads=n_threads, monitor=False, **options)
        made.append(batch)
        reference = make_reference(env_id, n_envs, **options)
        made.append(reference)
        if seed is not None:
            batch.seed(seed)
            reference.seed(seed)
        return batch, reference

    yield factory
    for env in made:
        env.close()


def random_actions(space: gymnasium.spaces.Box, rng: np.random.Generator, n_envs: int = N_ENVS) -> np.ndarray:
    """Uniform actions within ``space``'s bounds, in its dtype."""
    return rng.uniform(space.low, space.high, (n_envs, *space.shape)).astype(space.dtype)


def max_episode_steps(env_id: str) -> int:
    spec = gymnasium.spec(env_id)
    assert spec.max_episode_steps is not None
    return spec.max_episode_steps


def assert_values_match(got: Any, expected: Any, where: str, **tol: float) -> None:
    """``got`` equals ``expected``: dicts key by key, numbers and arrays within ``tol`` (STEP_TOL if none)."""
    tol = tol or STEP_TOL
    if isinstance(expected, dict):
        assert isinstance(got, dict), f"{where}: {got!r} is not a dict"
        assert set(got) == set(expected), f"{where}: keys {sorted(got)} != {sorted(expected)}"
        for key, value in expected.items():
            assert_values_match(got[key], value, f"{where}[{key!r}]", **tol)
    elif isinstance(expected, list | tuple):
        assert isinstance(got, list | tuple) and len(got) == len(expected), f"{where}: {got!r} != {expected!r}"
        for i, (got_item, expected_item) in enumerate(zip(got, expected, strict=True)):
            assert_values_match(got_item, expected_item, f"{where}[{i}]", **tol)
    elif isinstance(expected, bool | np.bool_ | str) or expected is None:
        assert got == expected, f"{where}: {got!r} != {expected!r}"
    elif isinstance(expected, np.ndarray) or np.isscalar(expected):
        got_array, expected_array = np.asarray(got), np.asarray(expected)
        assert got_array.shape == expected_array.shape, f"{where}: shape {got_array.shape} != {expected_array.shape}"
        np.testing.assert_allclose(got_array, expected_array, err_msg=where, **tol)
    else:
        assert got == expected, f"{where}: {got!r} != {expected!r}"


def assert_steps_match(got: VecEnvStepReturn, expected: VecEnvStepReturn, where: str) -> None:
    """One ``step`` of the batched env gave DummyVecEnv's observations, rewards, dones and infos."""
    obs, rewards, dones, infos = got
    expected_obs, expected_rewards, expected_dones, expected_infos = expected
    assert isinstance(obs, np.ndarray) and obs.dtype == expected_obs.dtype, f"{where}: observation dtype"
    assert_values_match(obs, expected_obs, f"{where} observations")
    assert rewards.shape == expected_rewards.shape, f"{where}: reward shape {rewards.shape}"
    # DummyVecEnv keeps rewards in float32
    np.testing.assert_allclose(rewards, expected_rewards, rtol=1e-6, atol=1e-6, err_msg=f"{where} rewards")
    assert dones.dtype == np.bool_, f"{where}: dones dtype {dones.dtype}"
    np.testing.assert_array_equal(dones, expected_dones, err_msg=f"{where} dones")
    assert isinstance(infos, list | tuple) and len(infos) == len(expected_infos), f"{where}: infos {infos!r}"
    for i, (info, expected_info) in enumerate(zip(infos, expected_infos, strict=True)):
        assert_values_match(info, expected_info, f"{where} infos[{i}]")


# test_vec_envs.py: test_vecenv_single_space (check_vecenv_spaces, check_vecenv_obs), Box spaces
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_spaces_num_envs_and_observations(env_id: str, make_pair: Factory) -> None:
    made = make_batch_env(env_id, N_ENVS)
    made.close()
    assert isinstance(made, BatchVecEnv) and made.unwrapped is made
    batch, _ = make_pair(env_id, seed=0)
    single = gymnasium.make(env_id)
    assert isinstance(batch, BatchVecEnv)
    assert batch.num_envs == N_ENVS
    assert batch.observation_space == single.observation_space
    assert batch.observation_space.dtype == single.observation_space.dtype == np.float64
    assert batch.action_space == single.action_space
    assert batch.action_space.dtype == single.action_space.dtype
    obs = batch.reset()
    assert isinstance(obs, np.ndarray)
    assert obs.shape == (N_ENVS, *single.observation_space.shape)
    assert obs.dtype == single.observation_space.dtype
    assert all(batch.observation_space.contains(row) for row in obs)
    dones = np.zeros(N_ENVS, dtype=bool)
    steps = 0
    while not dones.any():
        actions = [batch.action_space.sample() for _ in range(N_ENVS)]  # SB3 steps with a list of actions
        obs, rewards, dones, infos = batch.step(actions)
        steps += 1
        assert obs.shape == (N_ENVS, *single.observation_space.shape) and obs.dtype == np.float64
        assert all(batch.observation_space.contains(row) for row in obs)
        assert rewards.shape == (N_ENVS,) and np.issubdtype(rewards.dtype, np.floating)
        assert dones.shape == (N_ENVS,) and dones.dtype == np.bool_
        assert len(infos) == N_ENVS and all(isinstance(info, dict) for info in infos)
    assert steps == max_episode_steps(env_id) and dones.all()  # no termination with random actions: truncation


# base_vec_env.VecEnv.seed (seeds seed + i, used at the next reset only) and reset_infos; test_vec_deterministic
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_seed_then_reset_matches_dummy(env_id: str, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id)
    assert list(batch.seed(11)) == list(reference.seed(11)) == [11, 12, 13]
    obs, expected = batch.reset(), reference.reset()
    assert obs.shape == expected.shape and obs.dtype == expected.dtype
    np.testing.assert_allclose(obs, expected, rtol=0, atol=RESET_ATOL)
    assert len(batch.reset_infos) == N_ENVS
    assert_values_match(batch.reset_infos, reference.reset_infos, "reset_infos", rtol=0, atol=RESET_ATOL)
    # the seeds were used once: the next reset draws on from each env's generator
    np.testing.assert_allclose(batch.reset(), reference.reset(), rtol=0, atol=RESET_ATOL)
    assert not np.allclose(batch.reset(), obs)
    reference.reset()
    # set_options: empty options change nothing (our tasks take none)
    batch.set_options({})
    reference.set_options(None)
    batch.seed(11)
    reference.seed(11)
    np.testing.assert_allclose(batch.reset(), expected, rtol=0, atol=RESET_ATOL)
    np.testing.assert_allclose(reference.reset(), expected, rtol=0, atol=RESET_ATOL)


# test_vec_envs.py: test_vec_deterministic (the make_vec_env part): make_batch_env(seed=s) makes make_vec_env's envs,
# with the episode statistics (return and length) that make_vec_env's Monitor records
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_constructor_seed_matches_make_vec_env(env_id: str) -> None:
    first = make_batch_env(env_id, N_ENVS, seed=0)
    second = make_batch_env(env_id, N_ENVS, seed=0)
    reference = make_vec_env(env_id, n_envs=N_ENVS, seed=0)
    try:
        obs = first.reset()
        np.testing.assert_allclose(second.reset(), obs, rtol=0, atol=RESET_ATOL)
        np.testing.assert_allclose(obs, reference.reset(), rtol=0, atol=RESET_ATOL)
        rng = np.random.default_rng(0)
        limit = max_episode_steps(env_id)
        for step in range(1, limit + 1):
            actions = random_actions(first.action_space, rng)
            got, expected = first.step(actions), reference.step(actions)
            np.testing.assert_array_equal(second.step(actions)[0], got[0])
            episodes = [info.pop("episode", None) for info in got[3]]
            expected_episodes = [info.pop("episode", None) for info in expected[3]]
            assert_steps_match(got, expected, f"{env_id} step {step}")
            if step < limit:
                assert episodes == expected_episodes == [None] * N_ENVS
                continue
            for i, (episode, expected_episode) in enumerate(zip(episodes, expected_episodes, strict=True)):
                assert episode is not None and expected_episode is not None, f"env {i}: no episode statistics"
                assert episode["l"] == expected_episode["l"] == limit
                assert episode["r"] == pytest.approx(expected_episode["r"], rel=1e-5, abs=1e-4)
    finally:
        for env in (first, second, reference):
            env.close()


# test_vec_envs.py: test_vec_deterministic (seed(3) twice, also through VecNormalize.seed)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_seeding_is_reproducible(env_id: str, make_pair: Factory) -> None:
    batch, _ = make_pair(env_id)
    batch.seed(3)
    obs = batch.reset()
    batch.seed(4)
    other = batch.reset()
    batch.seed(3)
    np.testing.assert_array_equal(batch.reset(), obs)
    assert not np.allclose(other, obs)
    normalized = VecNormalize(batch)  # VecEnvWrapper.seed seeds the wrapped VecEnv
    assert list(normalized.seed(3)) == [3, 4, 5]
    np.testing.assert_array_equal(normalized.venv.reset(), obs)
    normalized.seed(4)
    np.testing.assert_array_equal(normalized.venv.reset(), other)


# test_vec_envs.py: test_vec_seeding (seed() without an argument: different envs, different starts and rewards)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_unseeded_envs_differ(env_id: str, make_pair: Factory) -> None:
    batch, _ = make_pair(env_id)
    seeds = list(batch.seed())
    assert len(seeds) == N_ENVS and all(isinstance(s, int) for s in seeds)
    assert seeds == [seeds[0] + i for i in range(N_ENVS)]
    obs = batch.reset()
    _, rewards, _, _ = batch.step(np.stack([batch.action_space.sample() for _ in range(N_ENVS)]))
    for i in range(N_ENVS - 1):
        assert not np.allclose(obs[i], obs[i + 1])
        assert not np.allclose(rewards[i], rewards[i + 1])


# test_vec_envs.py: test_vecenv_terminal_obs (terminal_observation, auto-reset, TimeLimit.truncated), on our tasks and
# against DummyVecEnv step by step; n_threads must not change a number
@pytest.mark.parametrize("n_threads", [1, 2])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_episode_end_matches_dummy(env_id: str, n_threads: int, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=5, n_threads=n_threads)
    np.testing.assert_allclose(batch.reset(), reference.reset(), rtol=0, atol=RESET_ATOL)
    limit = max_episode_steps(env_id)
    rng = np.random.default_rng(1)
    prev_obs = None
    for step in range(1, limit + 4):
        actions = random_actions(batch.action_space, rng)
        got, expected = batch.step(actions), reference.step(actions)
        assert_steps_match(got, expected, f"{env_id} step {step}")
        obs, _, dones, infos = got
        for i, (done, info) in enumerate(zip(dones, infos, strict=True)):
            assert bool(done) == (step == limit), f"env {i} done at step {step}"
            assert info["TimeLimit.truncated"] == (step == limit)
            if not done:
                assert "terminal_observation" not in info
                continue
            terminal = info["terminal_observation"]
            assert isinstance(terminal, np.ndarray) and terminal.shape == obs[i].shape
            assert terminal.dtype == np.float64
            assert not np.allclose(terminal, obs[i])  # the auto-reset's observation is returned instead
            assert not np.allclose(terminal, prev_obs[i])
        if step == limit:  # the auto-resets' infos, as DummyVecEnv stores them
            assert_values_match(batch.reset_infos, reference.reset_infos, f"{env_id} reset_infos after auto-reset")
        prev_obs = obs


# test_vec_envs.py: check_vecenv_spaces (step_async/step_wait, list actions); ArmEnv clips out-of-range actions
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_step_async_wait_and_action_forms(env_id: str, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=2)
    batch.reset()
    reference.reset()
    rng = np.random.default_rng(2)
    space = batch.action_space
    for step in range(6):
        actions = random_actions(space, rng)
        if step == 0:
            batch.step_async(actions)
            got = batch.step_wait()
        elif step == 1:
            got = batch.step([row for row in actions])  # a list of per-env actions
        elif step == 2:
            actions = 2.0 * actions  # outside the bounds: clipped by every env
            got = batch.step(actions)
        elif step == 3:
            actions = actions.astype(np.float64)
            got = batch.step(actions)
        else:
            got = batch.step(actions)
        assert_steps_match(got, reference.step(actions), f"{env_id} step {step}")


# test_vec_check_nan.py: test_check_nan (VecCheckNan refuses NaN and inf actions; the envs themselves refuse them too)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_non_finite_actions(env_id: str, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=0)
    checked = VecCheckNan(batch, raise_exception=True)
    obs = checked.reset()
    assert np.isfinite(obs).all()
    zeros = np.zeros((N_ENVS, *batch.action_space.shape), dtype=np.float32)
    checked.step(zeros)
    for bad in (np.nan, np.inf):
        actions = zeros.copy()
        actions[1, 0] = bad
        with pytest.raises(ValueError):
            checked.step(actions)
    obs, rewards, _, _ = checked.step(zeros)
    assert np.isfinite(obs).all() and np.isfinite(rewards).all()
    assert np.isfinite(checked.reset()).all()
    # without the wrapper: DummyVecEnv's envs raise ValueError (ArmEnv._checked_action); so must the batched env
    reference.reset()
    actions = zeros.copy()
    actions[2, -1] = np.nan
    with pytest.raises(ValueError):
        reference.step(actions)
    with pytest.raises(ValueError):
        batch.step(actions)


# SB3 VecEnvs return copies (DummyVecEnv: deepcopy of its buffers): what was returned must not change on the next step,
# and writing into it must not change the envs
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_returned_arrays_are_copies(env_id: str, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=7)
    reset_obs = batch.reset()
    np.testing.assert_allclose(reset_obs, reference.reset(), rtol=0, atol=RESET_ATOL)
    kept_reset = reset_obs.copy()
    rng = np.random.default_rng(3)
    limit = max_episode_steps(env_id)
    returned: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    terminal: list[tuple[np.ndarray, np.ndarray]] = []
    for step in range(1, limit + 3):
        actions = random_actions(batch.action_space, rng)
        obs, rewards, dones, infos = batch.step(actions)
        expected = reference.step(actions)
        assert_steps_match((obs, rewards, dones, infos), expected, f"{env_id} step {step}")
        returned.append((obs, obs.copy(), rewards, rewards.copy(), dones, dones.copy()))
        if step == limit:
            terminal = [(info["terminal_observation"], info["terminal_observation"].copy()) for info in infos]
        if step == 2:
            obs[:] = 1e6  # the caller's array: the envs go on from their own state
            rewards[:] = 1e6
    np.testing.assert_array_equal(reset_obs, kept_reset, err_msg="the observations of reset changed")
    for step, (obs, obs_then, rewards, rewards_then, dones, dones_then) in enumerate(returned, start=1):
        if step == 2:
            continue
        np.testing.assert_array_equal(obs, obs_then, err_msg=f"observations of step {step} changed")
        np.testing.assert_array_equal(rewards, rewards_then, err_msg=f"rewards of step {step} changed")
        np.testing.assert_array_equal(dones, dones_then, err_msg=f"dones of step {step} changed")
    for i, (now, then) in enumerate(terminal):
        np.testing.assert_array_equal(now, then, err_msg=f"terminal_observation of env {i} changed")
    assert not np.shares_memory(returned[0][0], returned[1][0])


# test_vec_envs.py: test_vecenv_custom_calls (has_attr, set_attr/get_attr with indices, env_method), with the same
# VecEnv wrappers (None, VecNormalize, VecFrameStack); get_attr("spec") and get_attr("dt"), which trpo-plus' video reads
@pytest.mark.parametrize("wrapper", [None, VecNormalize, VecFrameStack])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_custom_calls(env_id: str, wrapper: type | None, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=0)
    vec_env: VecEnv = batch
    if wrapper is VecFrameStack:
        vec_env = VecFrameStack(batch, n_stack=2)
    elif wrapper is VecNormalize:
        vec_env = VecNormalize(batch)
    vec_env.reset()
    reference.reset()
    specs = vec_env.get_attr("spec")
    assert len(specs) == N_ENVS
    assert [spec.id for spec in specs] == [spec.id for spec in reference.get_attr("spec")] == [env_id] * N_ENVS
    assert [spec.max_episode_steps for spec in specs] == [max_episode_steps(env_id)] * N_ENVS
    assert vec_env.get_attr("dt") == reference.get_attr("dt")
    assert vec_env.get_attr("dt", indices=[2]) == reference.get_attr("dt", indices=[2])
    assert vec_env.get_attr("render_mode") == [None] * N_ENVS

    assert not vec_env.has_attr("dummy")
    with pytest.raises(AttributeError):
        vec_env.get_attr("dummy")
    assert vec_env.set_attr("dummy", 12) is None
    assert vec_env.has_attr("dummy")
    assert vec_env.get_attr("dummy") == [12] * N_ENVS
    assert vec_env.get_attr("dummy", indices=[0, 2]) == [12, 12]
    assert vec_env.get_attr("dummy", indices=[-1]) == [12]
    assert vec_env.get_attr("dummy", indices=1) == [12]
    vec_env.set_attr("dummy", 42, indices=None)
    assert vec_env.get_attr("dummy") == [42] * N_ENVS

    # env_method: a method of the task, each env's value (SB3's custom_method), with indices
    method = ENV_METHODS[env_id]
    values = vec_env.env_method(method, indices=[0, 2])
    assert len(values) == 2
    assert_values_match(values, reference.env_method(method, indices=[0, 2]), f"env_method({method!r})")
    assert_values_match(vec_env.env_method(method), reference.env_method(method), f"env_method({method!r})")
    with pytest.raises(AttributeError):
        vec_env.env_method("no_such_method")
    with pytest.raises(AttributeError):
        reference.env_method("no_such_method")


# test_vec_envs.py: test_vecenv_custom_calls (set_attr of one env's value, by index, and of a subset)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_set_attr_per_env(env_id: str, make_pair: Factory) -> None:
    batch, _ = make_pair(env_id, seed=0)
    batch.reset()
    set_results = [batch.set_attr("dummy1", env_idx, indices=env_idx) for env_idx in range(N_ENVS)]
    assert set_results == [None] * N_ENVS
    assert batch.has_attr("dummy1")
    assert batch.get_attr("dummy1") == list(range(N_ENVS))
    assert batch.get_attr("dummy1", indices=[0, 2]) == [0, 2]
    assert batch.get_attr("dummy1", indices=[-1]) == [N_ENVS - 1]
    batch.set_attr("dummy1", 42, indices=None)
    assert batch.get_attr("dummy1") == [42] * N_ENVS
    batch.set_attr("dummy1", 7, indices=[0, -1])
    assert batch.get_attr("dummy1") == [7, *[42] * (N_ENVS - 2), 7]


# test_vec_envs.py: test_vec_env_is_wrapped (no Monitor around gymnasium.make's envs, also seen through VecFrameStack)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_env_is_wrapped(env_id: str, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id)
    assert batch.env_is_wrapped(Monitor) == reference.env_is_wrapped(Monitor) == [False] * N_ENVS
    assert batch.env_is_wrapped(Monitor, indices=[0, 2]) == [False, False]
    assert VecFrameStack(batch, n_stack=2).env_is_wrapped(Monitor) == [False] * N_ENVS


# test_vec_envs.py: test_vecenv_custom_calls (render, explicit and implicit mode, warning for another mode) and
# test_render's rgb_array part (render modes kept by VecFrameStack and VecNormalize); images are DummyVecEnv's
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_render_rgb_array(env_id: str, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=4, render_mode="rgb_array", **RENDER_SIZE)
    assert batch.render_mode == "rgb_array"
    batch.reset()
    reference.reset()
    actions = random_actions(batch.action_space, np.random.default_rng(4))
    batch.step(actions)
    reference.step(actions)
    images = batch.get_images()
    expected_images = reference.get_images()
    assert len(images) == N_ENVS
    for i, (image, expected_image) in enumerate(zip(images, expected_images, strict=True)):
        assert isinstance(image, np.ndarray) and image.dtype == np.uint8
        assert image.shape == (RENDER_SIZE["height"], RENDER_SIZE["width"], 3)
        np.testing.assert_array_equal(image, expected_image, err_msg=f"image of env {i}")
    assert not np.array_equal(images[0], images[1])  # each env is drawn, not one env three times
    explicit = batch.render(mode="rgb_array")
    implicit = batch.render()
    np.testing.assert_array_equal(explicit, implicit)
    np.testing.assert_array_equal(explicit, reference.render(mode="rgb_array"))  # the envs' images, tiled
    with pytest.warns(UserWarning):
        batch.render(mode="something_else")
    stacked = VecFrameStack(batch, n_stack=2)
    assert stacked.render_mode == "rgb_array"
    normalized = VecNormalize(stacked)
    assert normalized.render_mode == "rgb_array"
    np.testing.assert_array_equal(normalized.render(), explicit)


# test_vec_envs.py: test_video_recorder (VecVideoRecorder writes the first steps' video)
def test_video_recorder(tmp_path: Path, make_pair: Factory) -> None:
    batch, _ = make_pair("Reacher2D-v1", seed=0, render_mode="rgb_array", **RENDER_SIZE)
    recorder = VecVideoRecorder(
        batch, str(tmp_path), record_video_trigger=lambda step: step == 0, video_length=6, name_prefix="batch"
    )
    recorder.reset()
    rng = np.random.default_rng(0)
    for _ in range(8):
        recorder.step(random_actions(batch.action_space, rng))
    recorder.close()
    videos = sorted(path.name for path in tmp_path.glob("*.mp4"))
    assert videos == ["batch-step-0-to-step-6.mp4"]
    assert (tmp_path / videos[0]).stat().st_size > 0


# test_vec_normalize.py: test_vec_env (clipping, save/load), test_obs_rms_vec_normalize and test_get_original: the
# statistics and normalized values are DummyVecEnv's, terminal observations included; test_vecenv_terminal_obs with
# VecNormalize
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_vec_normalize_matches_dummy(env_id: str, tmp_path: Path, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=9)
    kwargs = {"norm_obs": True, "norm_reward": True, "clip_obs": 5.0, "clip_reward": 5.0}
    normalized, expected_env = VecNormalize(batch, **kwargs), VecNormalize(reference, **kwargs)
    np.testing.assert_allclose(normalized.reset(), expected_env.reset(), **STEP_TOL)
    rng = np.random.default_rng(9)
    limit = max_episode_steps(env_id)
    for step in range(1, limit + 3):
        actions = random_actions(batch.action_space, rng)
        got, expected = normalized.step(actions), expected_env.step(actions)
        assert_steps_match(got, expected, f"{env_id} normalized step {step}")
        obs, rewards, _, _ = got
        assert np.max(np.abs(obs)) <= kwargs["clip_obs"] and np.max(np.abs(rewards)) <= kwargs["clip_reward"]
        np.testing.assert_allclose(normalized.get_original_obs(), expected_env.get_original_obs(), **STEP_TOL)
        np.testing.assert_allclose(normalized.normalize_obs(normalized.get_original_obs()), obs, **STEP_TOL)
        original_rewards = normalized.get_original_reward()
        np.testing.assert_allclose(original_rewards, expected_env.get_original_reward(), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(normalized.obs_rms.mean, expected_env.obs_rms.mean, **STEP_TOL)
    np.testing.assert_allclose(normalized.obs_rms.var, expected_env.obs_rms.var, **STEP_TOL)
    assert normalized.obs_rms.count == expected_env.obs_rms.count
    np.testing.assert_allclose(normalized.ret_rms.mean, expected_env.ret_rms.mean, rtol=1e-5)
    np.testing.assert_allclose(normalized.ret_rms.var, expected_env.ret_rms.var, rtol=1e-5)

    path = tmp_path / "vec_normalize.pkl"
    normalized.save(path)
    fresh = make_batch_env(env_id, N_ENVS)
    try:
        loaded = VecNormalize.load(path, venv=fresh)
        assert loaded.num_envs == N_ENVS and loaded.observation_space == normalized.observation_space
        np.testing.assert_array_equal(loaded.obs_rms.mean, normalized.obs_rms.mean)
        np.testing.assert_array_equal(loaded.obs_rms.var, normalized.obs_rms.var)
        np.testing.assert_array_equal(loaded.ret_rms.var, normalized.ret_rms.var)
        assert loaded.clip_obs == normalized.clip_obs and loaded.norm_reward == normalized.norm_reward
        assert loaded.reset().shape == (N_ENVS, *batch.observation_space.shape)
    finally:
        fresh.close()


# test_vec_envs.py: test_vecenv_terminal_obs with VecFrameStack (stacked terminal observations, stacks cleared on reset)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_vec_frame_stack_matches_dummy(env_id: str, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=6)
    stacked, expected_env = VecFrameStack(batch, n_stack=2), VecFrameStack(reference, n_stack=2)
    dim = batch.observation_space.shape[0]
    assert stacked.observation_space.shape == (2 * dim,)
    obs = stacked.reset()
    np.testing.assert_allclose(obs, expected_env.reset(), rtol=0, atol=RESET_ATOL)
    np.testing.assert_array_equal(obs[:, :dim], 0.0)  # the stack starts empty
    rng = np.random.default_rng(6)
    limit = max_episode_steps(env_id)
    for step in range(1, limit + 3):
        actions = random_actions(batch.action_space, rng)
        got, expected = stacked.step(actions), expected_env.step(actions)
        assert_steps_match(got, expected, f"{env_id} stacked step {step}")
        obs, _, dones, infos = got
        if step == limit:
            assert dones.all()
            np.testing.assert_array_equal(obs[:, :dim], 0.0)
            for info in infos:
                assert info["terminal_observation"].shape == (2 * dim,)


# test_vec_monitor.py: test_vec_monitor (episode r and l, the file's header and columns),
# test_vec_monitor_info_keywords, test_vec_monitor_load_results, and test_vec_monitor_warn (no warning: the batched
# envs have no Monitor)
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_vec_monitor(env_id: str, tmp_path: Path, make_pair: Factory) -> None:
    batch, reference = make_pair(env_id, seed=8)
    filename = str(tmp_path / "batch")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        monitored = VecMonitor(batch, filename, info_keywords=("is_success",))
    expected_env = VecMonitor(reference, info_keywords=("is_success",))
    monitored.reset()
    expected_env.reset()
    rng = np.random.default_rng(8)
    limit = max_episode_steps(env_id)
    returns = np.zeros(N_ENVS)
    for step in range(1, limit + 1):
        actions = random_actions(batch.action_space, rng)
        _, rewards, dones, infos = monitored.step(actions)
        _, _, _, expected_infos = expected_env.step(actions)
        returns += rewards
        if step < limit:
            assert not any("episode" in info for info in infos)
            continue
        assert dones.all()
        for i, (info, expected_info) in enumerate(zip(infos, expected_infos, strict=True)):
            episode = info["episode"]
            assert episode["l"] == limit
            assert episode["r"] == pytest.approx(returns[i], rel=1e-5, abs=1e-4)
            assert episode["r"] == pytest.approx(expected_info["episode"]["r"], rel=1e-5, abs=1e-5)
            assert episode["is_success"] == expected_info["episode"]["is_success"]
    monitored.close()
    with open(filename + ".monitor.csv") as handle:
        first_line = handle.readline()
    assert first_line.startswith("#")
    assert set(json.loads(first_line[1:])) == {"t_start", "env_id"}
    results = load_results(str(tmp_path))
    assert len(results.index) == N_ENVS
    assert {"r", "l", "t", "is_success"} <= set(results.columns)
    assert list(results["l"]) == [limit] * N_ENVS


# test_vec_monitor.py: test_vec_monitor_ppo (PPO learns on the VecMonitor; evaluate_policy gives no warning)
def test_ppo_and_evaluate_policy(make_pair: Factory) -> None:
    batch, _ = make_pair("Reacher2D-v1", seed=0)
    monitored = VecMonitor(batch)
    model = PPO("MlpPolicy", monitored, n_steps=16, batch_size=48, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=96)
    assert model.num_timesteps == 96
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        rewards, lengths = evaluate_policy(model, monitored, n_eval_episodes=N_ENVS, return_episode_rewards=True)
    assert [str(w.message) for w in record] == []
    assert lengths == [max_episode_steps("Reacher2D-v1")] * N_ENVS
    assert all(np.isfinite(rewards))


# DummyVecEnv and SubprocVecEnv can be closed twice
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_close(env_id: str) -> None:
    batch = make_batch_env(env_id, N_ENVS, seed=0)
    batch.reset()
    batch.step(np.zeros((N_ENVS, *batch.action_space.shape), dtype=np.float32))
    assert batch.close() is None
    batch.close()
