"""The batched engine is the Gymnasium env, batched: the same transitions as SB3's DummyVecEnv over gymnasium.make."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

import grasp_envs
from grasp_envs import make_batch_env
from grasp_envs.base import SimArrays
from grasp_envs.control import point_jacobians
from grasp_envs.scripted import grasper3d_policy
from grasp_envs.wrappers import ScriptedStarts


def _dummy(env_id: str, n_envs: int, seed: int, scripted: dict[str, Any] | None = None) -> DummyVecEnv:
    def make() -> gym.Env[Any, Any]:
        env = gym.make(env_id)
        return ScriptedStarts(env, **scripted) if scripted else env

    dummy = DummyVecEnv([make] * n_envs)
    dummy.seed(seed)
    return dummy


def _record(env: VecEnv, steps: int, seed: int = 0) -> list[Any]:
    """``env``'s reset and ``steps`` steps with random actions (beyond the action bounds, so clipping is exercised)."""
    records: list[Any] = [(env.reset(), [dict(info) for info in env.reset_infos])]
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        actions = rng.uniform(-1.2, 1.2, size=(env.num_envs, *env.action_space.shape))
        records.append((actions, env.step(actions), [dict(info) for info in env.reset_infos]))
    return records


def _assert_replays(records: list[Any], batch: VecEnv) -> int:
    """``batch`` given the recorded actions: every observation, reward, done and info (terminal observations
    included) and every reset info equal to the record to 1e-9. Returns the number of episodes ended."""
    observation, reset_infos = records[0]
    np.testing.assert_allclose(batch.reset(), observation, rtol=0, atol=1e-9)
    assert batch.reset_infos == reset_infos
    ended = 0
    for t, (actions, (observation, reward, done, infos), reset_infos) in enumerate(records[1:]):
        batch_observation, batch_reward, batch_done, batch_infos = batch.step(actions)
        np.testing.assert_allclose(batch_observation, observation, rtol=0, atol=1e-9, err_msg=f"step {t}")
        np.testing.assert_allclose(batch_reward, reward, rtol=0, atol=1e-9, err_msg=f"step {t}")
        np.testing.assert_array_equal(batch_done, done, err_msg=f"step {t}")
        for info, batch_info in zip(infos, batch_infos, strict=True):
            assert set(batch_info) == set(info), f"step {t}"
            for key, value in info.items():
                np.testing.assert_allclose(batch_info[key], value, rtol=0, atol=1e-9, err_msg=f"step {t} {key}")
        assert batch.reset_infos == reset_infos, f"step {t}"
        ended += int(done.sum())
    return ended


def _assert_same_transitions(expected: VecEnv, batch: VecEnv, steps: int, seed: int = 0) -> int:
    """Step both with the same random actions; the batch's transitions equal ``expected``'s to 1e-9."""
    return _assert_replays(_record(expected, steps, seed), batch)


@pytest.mark.parametrize("env_id", grasp_envs.ENV_IDS)
def test_batch_equals_dummy_vec_env_for_every_id(env_id: str) -> None:
    """n = 1, 7 and 64 simulations on 1 and 2 threads, across resets and autoresets (each id's time limit is 50 or
    100 steps, so every env ends at least one episode)."""
    limit = gym.spec(env_id).max_episode_steps
    assert limit is not None
    for n_envs, steps in ((1, limit + 5), (7, limit + 5), (64, limit + 3)):
        records = _record(_dummy(env_id, n_envs, seed=11), steps)
        for n_threads in (1, 2):
            batch = make_batch_env(env_id, n_envs, seed=11, n_threads=n_threads, monitor=False)
            assert _assert_replays(records, batch) >= n_envs


def test_batch_scripted_starts_equal_the_wrapper() -> None:
    arguments = {"probability": 0.6, "steps": (20, 100), "hold_height": 0.07}
    dummy = _dummy("Grasper3D-v7", 6, seed=2, scripted=arguments)
    batch = make_batch_env("Grasper3D-v7", 6, seed=2, monitor=False, wrapper_class=ScriptedStarts, wrapper_kwargs=arguments)
    assert batch.env_is_wrapped(ScriptedStarts) == [True] * 6
    _assert_same_transitions(dummy, batch, 230)


@pytest.mark.parametrize("env_id", ["Reacher2D-v1", "WallReacher3D-v0", "Grasper3D-v0", "Grasper3D-v7"])
def test_unstable_simulation_ends_its_episode_alone(env_id: str) -> None:
    """A diverging simulation (MuJoCo resets it) ends its episode with info["unstable"] and a finite observation;
    the other simulations of the batch go on, as the DummyVecEnv's do."""
    dummy = _dummy(env_id, 3, seed=5)
    batch = make_batch_env(env_id, 3, seed=5, monitor=False)
    dummy.reset(), batch.reset()
    dummy.envs[1].unwrapped.data.qvel[:] = 1e12  # type: ignore[attr-defined]
    batch.unwrapped.batch.bind("qvel")[1] = 1e12  # type: ignore[attr-defined]
    actions = np.zeros((3, *batch.action_space.shape))
    observation, reward, done, infos = dummy.step(actions)
    batch_observation, batch_reward, batch_done, batch_infos = batch.step(actions)
    assert list(batch_done) == list(done) == [False, True, False]
    assert batch_infos[1]["unstable"] and infos[1]["unstable"] and batch_reward[1] == 0.0
    assert np.isfinite(batch_infos[1]["terminal_observation"]).all()
    np.testing.assert_allclose(batch_infos[1]["terminal_observation"], infos[1]["terminal_observation"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(batch_observation, observation, rtol=0, atol=1e-9)
    np.testing.assert_allclose(batch_reward, reward, rtol=0, atol=1e-9)


def test_jacobians_equal_mujocos_per_simulation() -> None:
    """The vectorised Jacobian over the bound cdof and subtree_com (a batch's, here a copy of one simulation's
    arrays: ``take``) is mj_jacSite / mj_jacBody, bit for bit."""
    env = gym.make("Grasper3D-v7").unwrapped
    env.reset(seed=0)
    model, data = env.model, env.data  # type: ignore[attr-defined]
    site, body = model.site("grip").id, model.body("forearm").id
    for _ in range(60):
        env.step(grasper3d_policy(env))  # type: ignore[arg-type]
        sim = SimArrays.of_data(model, data).take(np.array([0]))
        assert sim.data is None  # the batch's path, not MjData's
        jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacSite(model, data, jacp, None, site)
        np.testing.assert_array_equal(point_jacobians(sim, int(model.site_bodyid[site]), sim.site_xpos[:, site])[0][0], jacp)
        mujoco.mj_jacBody(model, data, jacp, jacr, body)
        batch_jacp, batch_jacr = point_jacobians(sim, body, sim.xpos[:, body])
        np.testing.assert_array_equal(batch_jacp[0], jacp)
        np.testing.assert_array_equal(batch_jacr[0], jacr)


def test_jacobian_columns_are_the_full_jacobians_columns_in_the_same_layout() -> None:
    """``point_jacobians(..., dofs)`` is the full Jacobian's ``[:, :, dofs]`` bit for bit and in the memory layout
    of that selection, on the batch's path and on one MjData's, so that the IK's products over it round the same on
    both (dofs inside and outside the body's chain, in any order)."""
    batch = make_batch_env("Grasper3D-v7", 5, seed=3)
    batch.reset()
    rng = np.random.default_rng(3)
    model = batch.model
    data = mujoco.MjData(model)
    for _ in range(20):
        batch.step(rng.uniform(-1, 1, size=(5, 4)))
    for body in (int(model.body("forearm").id), int(model.site_bodyid[model.site("grip").id])):
        for dofs in (np.arange(5), np.array([7, 0, 3]), np.arange(model.nv)):
            full = point_jacobians(batch.sim, body, batch.sim.xpos[:, body])
            columns = point_jacobians(batch.sim, body, batch.sim.xpos[:, body], dofs)
            batch.batch.get_data(2, data)
            one = point_jacobians(SimArrays.of_data(model, data), body, data.xpos[None, body], dofs)
            for whole, part, single in zip(full, columns, one, strict=True):
                np.testing.assert_array_equal(part, whole[:, :, dofs])
                assert part.strides == whole[:, :, dofs].strides
                np.testing.assert_array_equal(single[0], part[2])


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"n_envs": 0}, ValueError, "make_batch_env: `n_envs` must be an integer >= 1"),
        ({"n_envs": True}, ValueError, "make_batch_env: `n_envs` must be an integer >= 1"),
        ({"n_envs": 2, "n_threads": -1}, ValueError, "make_batch_env: `n_threads` must be an integer >= 0"),
        ({"n_envs": 2, "claw": "magnet"}, ValueError, "claw must be one of"),
        ({"n_envs": 2, "gripper": "x"}, TypeError, "has no option 'gripper'"),
        ({"n_envs": 2, "wrapper_class": gym.wrappers.ClipAction}, ValueError, "runs no per-env Gymnasium wrappers"),
        ({"n_envs": 2, "wrapper_class": ScriptedStarts, "wrapper_kwargs": {"probability": 2.0}}, ValueError, "probability"),
    ],
)
def test_bad_arguments_are_refused(kwargs: dict[str, Any], error: type[Exception], message: str) -> None:
    with pytest.raises(error, match=message):
        make_batch_env("Grasper3D-v7", **kwargs)


def test_other_ids_and_wrong_actions_are_refused() -> None:
    with pytest.raises(ValueError, match="runs the tasks of grasp_envs"):
        make_batch_env("Pendulum-v1", 2)
    with pytest.raises(TypeError, match="another task"):
        make_batch_env("Reacher2D-v1", 2, wrapper_class=ScriptedStarts)
    env = make_batch_env("Reacher2D-v1", 2, seed=0)
    env.reset()
    with pytest.raises(ValueError, match=r"actions of shape \(2, 2\)"):
        env.step(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="non-finite action for env 1"):
        env.step(np.array([[0.0, 0.0], [np.nan, 0.0]]))


def test_rgb_array_rendering_of_one_simulation_is_the_gymnasium_envs() -> None:
    batch = make_batch_env("Grasper3D-v7", 3, seed=4, monitor=False, render_mode="rgb_array", width=64, height=48)
    single = gym.make("Grasper3D-v7", render_mode="rgb_array", width=64, height=48)
    batch.reset()
    single.reset(seed=6)  # env 2 of the batch was seeded 4 + 2
    image = batch.unwrapped.render_env(2)  # type: ignore[attr-defined]
    assert image.shape == (48, 64, 3) and image.std() > 0
    np.testing.assert_array_equal(image, single.render())


def test_trpo_plus_trains_on_it_with_vec_normalize_eval_callback_and_save_load(tmp_path: Any) -> None:
    from stable_baselines3.common.callbacks import EvalCallback
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus import TRPOPlus

    env = VecNormalize(make_batch_env("Grasper3D-v7", 4, seed=0, n_threads=2))
    evaluation = VecNormalize(make_batch_env("Grasper3D-v7", 2, seed=100), training=False, norm_reward=False)
    callback = EvalCallback(evaluation, n_eval_episodes=2, eval_freq=64, log_path=str(tmp_path), verbose=0)
    model = TRPOPlus("MlpPolicy", env, n_steps=64, batch_size=256, replay_memory=2, cg_warm_start=True, seed=0)
    model.learn(512, callback=callback)
    assert callback.n_calls == 128 and len(callback.evaluations_results) == 2
    assert len(model.ep_info_buffer) > 0 and "is_success" in model.ep_info_buffer[0]  # VecMonitor's episode records
    model.save(tmp_path / "model.zip")
    env.save(str(tmp_path / "vecnormalize.pkl"))
    loaded = TRPOPlus.load(tmp_path / "model.zip", env=VecNormalize.load(str(tmp_path / "vecnormalize.pkl"), env.venv))
    observation = env.reset()
    expected = model.predict(observation, deterministic=True)[0]
    np.testing.assert_array_equal(loaded.predict(observation, deterministic=True)[0], expected)


def test_episode_records_are_monitors_and_normalization_syncs_with_a_dummy_vec_env(tmp_path: Any) -> None:
    """make_batch_env records episodes as Monitor inside make_vec_env's envs (same returns, lengths, is_success,
    the same CSV columns), with no VecEnvWrapper of its own: so VecNormalize statistics sync with a DummyVecEnv
    evaluation env (EvalCallback's sync_envs_normalization walks both wrapper stacks together)."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.monitor import Monitor, load_results
    from stable_baselines3.common.vec_env import VecNormalize, sync_envs_normalization

    batch = make_batch_env("Reacher2D-v1", 3, seed=7, monitor_file=str(tmp_path / "batch"))
    dummy = make_vec_env("Reacher2D-v1", 3, seed=7, monitor_kwargs={"info_keywords": ("is_success",)})
    assert batch.env_is_wrapped(Monitor) == dummy.env_is_wrapped(Monitor) == [True] * 3
    batch.reset(), dummy.reset()
    rng = np.random.default_rng(1)
    episodes = []
    for _ in range(120):
        actions = rng.uniform(-1, 1, (3, 2))
        infos, batch_infos = dummy.step(actions)[3], batch.step(actions)[3]
        for info, batch_info in zip(infos, batch_infos, strict=True):
            assert ("episode" in info) == ("episode" in batch_info)
            if "episode" in info:
                expected = {k: v for k, v in info["episode"].items() if k != "t"}
                assert {k: v for k, v in batch_info["episode"].items() if k != "t"} == expected
                episodes.append(expected)
    assert len(episodes) == 6
    batch.close()
    records = load_results(str(tmp_path))
    assert list(records["l"]) == [e["l"] for e in episodes] and "is_success" in records.columns
    training, evaluation = VecNormalize(batch), VecNormalize(dummy, training=False)
    training.obs_rms.mean[:] = 0.25
    sync_envs_normalization(training, evaluation)
    np.testing.assert_array_equal(evaluation.obs_rms.mean, training.obs_rms.mean)
