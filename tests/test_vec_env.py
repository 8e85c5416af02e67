"""ShardedSubprocVecEnv behaves exactly like DummyVecEnv, several envs per worker process."""

import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.monitor import Monitor

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.vec_env import ShardedSubprocVecEnv


@pytest.mark.parametrize("in_process", [False, True], ids=["processes", "in-process"])
@pytest.mark.parametrize("n_workers", [1, 2, 3])
def test_same_transitions_as_dummy_vec_env(n_workers: int, in_process: bool) -> None:
    dummy = make_vec_env("Reacher2D-v0", n_envs=5, seed=3)
    kwargs = dict(n_workers=n_workers, in_process=in_process)
    sharded = make_vec_env("Reacher2D-v0", n_envs=5, seed=3, vec_env_cls=ShardedSubprocVecEnv, vec_env_kwargs=kwargs)
    try:
        assert sharded.n_workers == n_workers and sharded.in_process == in_process
        assert len(sharded.processes) == n_workers - in_process
        np.testing.assert_array_equal(dummy.reset(), sharded.reset())
        rng = np.random.default_rng(0)
        for _ in range(120):  # more than two 50-step episodes: auto-resets and terminal observations
            actions = rng.uniform(-1, 1, (5, 2)).astype(np.float32)
            expected, got = dummy.step(actions), sharded.step(actions)
            for a, b in zip(expected[:3], got[:3], strict=True):
                np.testing.assert_array_equal(a, b)
            for info_a, info_b in zip(expected[3], got[3], strict=True):
                assert info_a.keys() == info_b.keys()
                if "terminal_observation" in info_a:
                    np.testing.assert_array_equal(info_a["terminal_observation"], info_b["terminal_observation"])
        assert sharded.get_attr("frame_skip", [1, 4]) == [2, 2]
        assert sharded.env_method("distance", indices=[0, 3]) == dummy.env_method("distance", indices=[0, 3])
        assert all(sharded.env_is_wrapped(Monitor))
        sharded.set_attr("noted_goal", 0.5)
        sharded.set_attr("noted_goal", 0.02, indices=[0, 1, 3, 4])
        assert sharded.get_attr("noted_goal") == [0.02, 0.02, 0.5, 0.02, 0.02]
    finally:
        sharded.close()


def test_trains_trpo_plus() -> None:
    env = make_vec_env("Pendulum-v1", n_envs=4, vec_env_cls=ShardedSubprocVecEnv, vec_env_kwargs=dict(n_workers=2))
    try:
        model = TRPOPlus("MlpPolicy", env, n_steps=32, batch_size=64, policy_kwargs=dict(net_arch=[16]), replay_memory=1)
        model.learn(256)
        assert model.num_timesteps == 256
    finally:
        env.close()


def test_rejects_no_envs() -> None:
    with pytest.raises(ValueError, match="at least one"):
        ShardedSubprocVecEnv([])


def test_workers_ignore_sigint_and_a_dead_one_is_named() -> None:
    import os
    import signal

    from sb3_trpo_plus.vec_env import RolloutWorkerError

    env = make_vec_env("Reacher2D-v0", n_envs=4, vec_env_cls=ShardedSubprocVecEnv, vec_env_kwargs=dict(n_workers=2))
    try:
        env.reset()
        os.kill(env.processes[0].pid, signal.SIGINT)  # a terminal's Ctrl-C reaches the workers too
        env.step(np.zeros((4, 2), dtype=np.float32))
        os.kill(env.processes[1].pid, signal.SIGKILL)
        with pytest.raises(RolloutWorkerError, match=r"worker 1 \(pid \d+\) stepping envs 2 \(Reacher2D-v0\), 3 "):
            env.step(np.zeros((4, 2), dtype=np.float32))
    finally:
        env.close()  # skips the dead worker
    assert env.closed and not any(p.is_alive() for p in env.processes)
