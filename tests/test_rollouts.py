"""Rollout workers (sb3_trpo_plus.rollouts) in the learner's process and in local processes."""

from __future__ import annotations

import os
import signal
import threading

import numpy as np
import pytest
import sigint
import torch as th
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback, EvalCallback
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from grasp_envs import make_batch_env
from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.rollouts import InProcessRollouts, ProcessRollouts, RolloutWorkerError

SMALL = {"n_steps": 32, "policy_kwargs": {"net_arch": [16, 16]}, "n_critic_updates": 2, "cg_max_steps": 5}


def parameters(model: TRPOPlus) -> th.Tensor:
    return th.nn.utils.parameters_to_vector(model.policy.parameters()).detach().clone()


def train(pool, iterations: int = 2, **kwargs) -> tuple[TRPOPlus, VecNormalize]:
    env = VecNormalize(pool)
    model = TRPOPlus("MlpPolicy", env, seed=0, **{**SMALL, **kwargs})
    model.learn(iterations * SMALL["n_steps"] * pool.num_envs)
    return model, env


def test_local_processes_collect_what_the_in_process_workers_collect() -> None:
    """Same seeds and partition: the same rollouts, VecNormalize statistics and trained weights, replay memory on."""
    results = []
    for pool_class in (InProcessRollouts, ProcessRollouts):
        pool = pool_class("Reacher2D-v1", num_workers=2, envs_per_worker=3, seed=7)
        try:
            model, env = train(pool, replay_memory=2)
            buffer = model.rollout_buffer
            results.append(
                (
                    parameters(model),
                    env.obs_rms.mean.copy(),
                    env.ret_rms.var,
                    buffer.observations.copy(),
                    buffer.rewards.copy(),
                    buffer.advantages.copy(),
                    [r.rewards.copy() for r in model.rollout_memory],
                )
            )
        finally:
            pool.close()
    (a, b) = results
    assert th.equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    assert a[2] == b[2]
    for x, y in zip(a[3:6], b[3:6], strict=True):
        np.testing.assert_array_equal(x, y)
    for x, y in zip(a[6], b[6], strict=True):
        np.testing.assert_array_equal(x, y)


def test_workers_envs_are_the_batched_engines_envs_with_make_vec_envs_seeds() -> None:
    """Stepped one step at a time, 2 workers x 3 envs give the transitions of one 6-env batch (env i: seed + i)."""
    pool = InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=3, seed=11)
    batch = make_batch_env("Reacher2D-v1", n_envs=6, seed=11)
    rng = np.random.default_rng(0)
    try:
        np.testing.assert_array_equal(pool.reset(), batch.reset())
        for _ in range(120):  # past the 50-step time limit: autoresets and terminal observations
            actions = rng.uniform(-1, 1, size=(6, *pool.action_space.shape)).astype(np.float32)
            obs_a, rew_a, done_a, infos_a = pool.step(actions)
            obs_b, rew_b, done_b, infos_b = batch.step(actions)
            np.testing.assert_array_equal(obs_a, obs_b)
            np.testing.assert_array_equal(rew_a, rew_b)
            np.testing.assert_array_equal(done_a, done_b)
            for info_a, info_b in zip(infos_a, infos_b, strict=True):
                assert info_a.keys() == info_b.keys()
                if "terminal_observation" in info_a:
                    np.testing.assert_array_equal(info_a["terminal_observation"], info_b["terminal_observation"])
                    assert info_a["episode"]["r"] == info_b["episode"]["r"]
    finally:
        pool.close()
        batch.close()


def test_a_pool_answers_the_vec_env_queries_of_the_right_envs() -> None:
    pool = InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=0)
    try:
        assert pool.num_envs == 4 and len(pool.workers) == 2
        pool.reset()
        pool.set_attr("custom_flag", 5, indices=[1, 2])
        assert pool.get_attr("custom_flag", indices=[1, 2]) == [5, 5]
        assert len(pool.get_attr("dt")) == 4
        assert pool.env_is_wrapped(VecNormalize, indices=[3]) == [False]
        assert len(pool.env_method("distance")) == 4
        pool.seed(3)
        first = pool.reset()
        pool.seed(3)
        np.testing.assert_array_equal(pool.reset(), first)
    finally:
        pool.close()


class _Counting(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.steps = 0
        self.rollouts = 0
        self.keys: set[str] = set()
        self.logged: dict[str, float] = {}

    def _on_step(self) -> bool:
        self.steps += 1
        self.keys |= set(self.locals)
        return True

    def _on_rollout_end(self) -> None:
        self.rollouts += 1
        self.logged = dict(self.logger.name_to_value)


def test_callbacks_fire_once_per_step_of_the_segments(tmp_path) -> None:
    pool = InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=1)
    eval_env = VecNormalize(DummyVecEnv([lambda: __import__("gymnasium").make("Reacher2D-v1")]), training=False)
    counting = _Counting()
    callbacks = CallbackList(
        [
            counting,
            EvalCallback(eval_env, eval_freq=SMALL["n_steps"], n_eval_episodes=2, log_path=str(tmp_path), verbose=0),
            CheckpointCallback(save_freq=SMALL["n_steps"], save_path=str(tmp_path), save_vecnormalize=True),
        ]
    )
    try:
        env = VecNormalize(pool)
        model = TRPOPlus("MlpPolicy", env, seed=0, **SMALL)
        model.learn(2 * SMALL["n_steps"] * pool.num_envs, callback=callbacks)
        assert counting.steps == 2 * SMALL["n_steps"] and counting.rollouts == 2
        assert {"new_obs", "rewards", "dones", "infos", "actions"} <= counting.keys
        assert (tmp_path / "evaluations.npz").exists()
        assert sorted(p.name for p in tmp_path.glob("rl_model_*_steps.zip"))
        np.testing.assert_array_equal(eval_env.obs_rms.mean, env.obs_rms.mean)  # EvalCallback synced the statistics
        assert {"workers/broadcast_ms", "workers/transfer_ms", "workers/worker_1_steps_per_s"} <= counting.logged.keys()
        assert len(model.ep_info_buffer) > 0  # the 50-step episodes ended inside the segments
    finally:
        pool.close()


def test_a_saved_model_resumes_on_a_new_pool(tmp_path) -> None:
    pool = InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=2)
    model, env = train(pool, iterations=1, replay_memory=2)
    model.save(tmp_path / "model.zip")
    env.save(str(tmp_path / "vecnormalize.pkl"))
    pool.close()
    again = InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=3)
    try:
        loaded = TRPOPlus.load(tmp_path / "model.zip", env=VecNormalize.load(str(tmp_path / "vecnormalize.pkl"), again))
        assert len(loaded.rollout_memory) == 1
        before = parameters(loaded)
        loaded.learn(SMALL["n_steps"] * again.num_envs, reset_num_timesteps=False)
        assert loaded.num_timesteps == 2 * SMALL["n_steps"] * again.num_envs
        assert not th.equal(before, parameters(loaded)) and len(loaded.rollout_memory) == 2
    finally:
        again.close()


def test_episodes_are_written_to_the_monitor_file(tmp_path) -> None:
    pool = InProcessRollouts("Reacher2D-v1", num_workers=1, envs_per_worker=2, seed=0, monitor_file=str(tmp_path / "run"))
    try:
        train(pool, iterations=2)
    finally:
        pool.close()
    rows = (tmp_path / "run.monitor.csv").read_text().splitlines()
    assert rows[1] == "r,l,t,is_success" and len(rows) - 2 == 2 * 2 * SMALL["n_steps"] // 50


def _kill_worker_soon(pool, worker: int, delay: float) -> threading.Timer:
    pid = pool.workers[worker]["pid"]
    timer = threading.Timer(delay, os.kill, args=(pid, signal.SIGKILL))
    timer.start()
    return timer


CRASH = "crashing_env:CrashOnce-v0"  # tests/crashing_env.py: its process exits at `at_step`, once per marker file


def check_restart_after_a_crash(pool_class, tmp_path) -> None:
    """One of two workers exits mid-segment: it is replaced, its segment collected again, training completes."""
    pool = pool_class(
        CRASH,
        num_workers=2,
        envs_per_worker=2,
        seed=0,
        max_restarts=1,
        env_kwargs={"marker": str(tmp_path / "crashed"), "at_step": 20},
    )
    try:
        pids = [worker["pid"] for worker in pool.workers]
        model = TRPOPlus("MlpPolicy", VecNormalize(pool), seed=0, **SMALL)
        model.learn(2 * SMALL["n_steps"] * pool.num_envs)
        assert sum(pool.restarts) == 1 and (tmp_path / "crashed").exists()
        restarted = pool.restarts.index(1)
        assert pool.workers[restarted]["pid"] != pids[restarted]
        assert model.num_timesteps == 2 * SMALL["n_steps"] * pool.num_envs
    finally:
        pool.close()


def check_restart_after_a_kill(pool, delay: float) -> None:
    """SIGKILL to a 1-worker pool's process during a long segment: the worker is replaced and training completes."""
    try:
        old_pid = pool.workers[0]["pid"]
        # segments long enough that the kill lands inside training on an idle machine too (2,000 steps per env)
        model = TRPOPlus("MlpPolicy", pool, seed=0, **{**SMALL, "n_steps": 2000})
        timer = _kill_worker_soon(pool, 0, delay)
        model.learn(2 * 2000 * pool.num_envs)
        timer.join()
        assert pool.restarts == [1] and pool.workers[0]["pid"] != old_pid
    finally:
        pool.close()


def test_a_process_worker_that_dies_mid_segment_is_restarted_and_its_segment_collected_again(tmp_path) -> None:
    check_restart_after_a_crash(ProcessRollouts, tmp_path)


def check_crash_beyond_restarts(pool_class, tmp_path, cause: str) -> None:
    """One of two workers exits mid-segment with no restart left: the error names that worker, its envs and how it
    ended, and the weights are those before the segment (the first: no update ran)."""
    pool = pool_class(
        CRASH,
        num_workers=2,
        envs_per_worker=2,
        seed=0,
        max_restarts=0,
        env_kwargs={"marker": str(tmp_path / "crashed"), "at_step": 20},
    )
    try:
        model = TRPOPlus("MlpPolicy", pool, seed=0, **SMALL)
        before = parameters(model)
        worker = r"(worker 0 \(pid \d+ on .*\) stepping envs 0-1|worker 1 \(pid \d+ on .*\) stepping envs 2-3)"
        message = (
            rf"{pool_class.__name__} {worker} \(crashing_env:CrashOnce-v0\) died: {cause} "
            r"\(restarted 0 times of max_restarts=0\)"
        )
        with pytest.raises(RolloutWorkerError, match=message):
            model.learn(2 * SMALL["n_steps"] * pool.num_envs)
        assert (tmp_path / "crashed").exists() and model._n_updates == 0
        assert th.equal(before, parameters(model))
    finally:
        pool.close()


class KillDuringFirstSegment(BaseCallback):
    """SIGKILLs a pool's worker ``delay`` seconds into the first segment; keeps the weights each rollout started with."""

    def __init__(self, pool, worker: int, delay: float):
        super().__init__()
        self.pool, self.worker, self.delay = pool, worker, delay
        self.timer: threading.Timer | None = None
        self.before: th.Tensor | None = None

    def _on_rollout_start(self) -> None:
        self.before = parameters(self.model)
        if self.timer is None:
            self.timer = _kill_worker_soon(self.pool, self.worker, self.delay)

    def _on_step(self) -> bool:
        return True


def check_kill_beyond_restarts(pool, cause: str) -> None:
    """SIGKILL to worker 1 of a pool on a grasp_envs id (the batched engine inside each worker) in the middle of the
    first segment, no restart left: the error names the worker and its envs, and no update ran."""
    try:
        model = TRPOPlus("MlpPolicy", pool, seed=0, **{**SMALL, "n_steps": 400, "batch_size": 400})  # segments of ~1 s
        before = parameters(model)
        killer = KillDuringFirstSegment(pool, worker=1, delay=0.3)
        message = (
            rf"{type(pool).__name__} worker 1 \(pid {pool.workers[1]['pid']} on .*\) stepping envs 2-3 \(Grasper3D-v7\) "
            rf"died: {cause} \(restarted 0 times of max_restarts=0\)"
        )
        with pytest.raises(RolloutWorkerError, match=message):
            model.learn(2 * 400 * pool.num_envs, callback=killer)
        assert killer.timer is not None
        killer.timer.join()
        assert model._n_updates == 0
        assert th.equal(before, killer.before) and th.equal(before, parameters(model))
    finally:
        pool.close()


def test_a_dead_worker_beyond_its_restarts_names_itself_and_leaves_the_weights(tmp_path) -> None:
    check_crash_beyond_restarts(ProcessRollouts, tmp_path, "exit code 3")


def test_a_killed_batched_engine_worker_beyond_its_restarts_names_itself_and_leaves_the_weights() -> None:
    check_kill_beyond_restarts(
        ProcessRollouts("Grasper3D-v7", num_workers=2, envs_per_worker=2, seed=0, max_restarts=0), "killed by SIGKILL"
    )


def test_process_workers_ignore_sigint() -> None:
    """A terminal's Ctrl-C reaches the workers too: they ignore it (the learner handles it, then stops and closes
    them), so the pool steps on with the same workers."""
    pool = ProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=0)
    try:
        pool.reset()
        pids = [worker["pid"] for worker in pool.workers]
        for pid in pids:
            os.kill(pid, signal.SIGINT)
        for _ in range(3):
            pool.step(np.zeros((pool.num_envs, *pool.action_space.shape), dtype=np.float32))
        assert [worker["pid"] for worker in pool.workers] == pids and pool.restarts == [0, 0]
    finally:
        pool.close()


def test_a_worker_killed_by_a_signal_is_restarted() -> None:
    check_restart_after_a_kill(ProcessRollouts("Grasper3D-v7", num_workers=1, envs_per_worker=2, seed=0, max_restarts=2), 0.5)


@pytest.mark.parametrize("env_id", ["Reacher2D-v1", "CartPole-v1"])
def test_one_worker_collects_what_sb3s_collection_loop_collects(env_id: str) -> None:
    """One worker, no VecNormalize, the learner's generator seeded as the worker's: the rollout buffer and the replay
    record equal those of SB3's ``collect_rollouts`` over the same envs (the batched engine for a grasp_envs id,
    ``make_vec_env``'s DummyVecEnv otherwise; CartPole: discrete actions), time-limit bootstraps included."""
    from stable_baselines3.common.env_util import make_vec_env

    n_envs, n_steps = 3, 60  # Reacher2D-v1's episodes end by time limit at step 50
    pool = InProcessRollouts(env_id, num_workers=1, envs_per_worker=n_envs, seed=11)
    reference = make_batch_env(env_id, n_envs, seed=11) if env_id == "Reacher2D-v1" else make_vec_env(env_id, n_envs, seed=11)
    collected = []
    try:
        for env in (reference, pool):
            th.manual_seed(0)
            model = TRPOPlus("MlpPolicy", env, n_steps=n_steps, replay_memory=1, policy_kwargs={"net_arch": [16]})
            _, callback = model._setup_learn(n_steps * n_envs)
            th.manual_seed(pool._torch_seed(0))
            assert model.collect_rollouts(model.env, callback, model.rollout_buffer, n_steps)
            collected.append((model.rollout_buffer, model.rollout_buffer.segment))
    finally:
        pool.close()
        reference.close()
    (buffer_a, record_a), (buffer_b, record_b) = collected
    for name in ("observations", "actions", "rewards", "episode_starts", "values", "log_probs", "advantages", "returns"):
        np.testing.assert_array_equal(getattr(buffer_a, name), getattr(buffer_b, name), err_msg=name)
    for name in (
        "observations",
        "raw_observations",
        "last_observation",
        "actions",
        "rewards",
        "buffer_rewards",
        "raw_rewards",
        "episode_starts",
        "dones",
        "episode_timesteps",
        "values",
        "log_probs",
        "last_values",
        "truncated_steps",
        "terminal_timesteps",
    ):
        np.testing.assert_array_equal(getattr(record_a, name), getattr(record_b, name), err_msg=name)
    assert [[env for env, _ in step] for step in record_a.ended] == [[env for env, _ in step] for step in record_b.ended]
    if env_id == "Reacher2D-v1":
        assert len(record_a.truncated_steps) == n_envs
        np.testing.assert_array_equal(record_a.terminal_observations, record_b.terminal_observations)


def test_an_error_inside_a_worker_surfaces_with_its_traceback() -> None:
    with pytest.raises(RolloutWorkerError, match=r"(?s)ProcessRollouts worker 0 .*Traceback.*no_such_option"):
        ProcessRollouts("Grasper3D-v7", num_workers=1, envs_per_worker=1, env_kwargs={"no_such_option": 1})


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"num_workers": 0}, "`num_workers` must be an integer >= 1, got 0"),
        ({"envs_per_worker": True}, "`envs_per_worker` must be an integer >= 1, got True"),
        ({"seed": "1"}, "`seed` must be None or an integer >= 0, got '1'"),
        ({"max_restarts": 1.5}, "`max_restarts` must be an integer >= 0, got 1.5"),
        ({"sim_threads": -1}, "`sim_threads` must be an integer >= 0, got -1"),
    ],
)
def test_bad_pool_arguments_are_named(kwargs, message) -> None:
    arguments = {"num_workers": 1, "envs_per_worker": 1, **kwargs}
    with pytest.raises(ValueError, match=f"InProcessRollouts: {message}".replace("(", r"\(").replace(")", r"\)")):
        InProcessRollouts("Reacher2D-v1", **arguments)


def test_an_unknown_env_id_fails_before_any_worker_starts() -> None:
    with pytest.raises(Exception, match="NoSuchEnv"):
        ProcessRollouts("NoSuchEnv-v0", num_workers=2, envs_per_worker=1)


def test_gsde_is_refused_on_workers() -> None:
    pool = InProcessRollouts("Reacher2D-v1", num_workers=1, envs_per_worker=2, seed=0)
    try:
        model = TRPOPlus("MlpPolicy", pool, seed=0, use_sde=True, **SMALL)
        with pytest.raises(ValueError, match="gSDE"):
            model.learn(SMALL["n_steps"] * 2)
    finally:
        pool.close()


def test_workers_under_other_wrappers_are_stepped_one_step_at_a_time_with_a_warning() -> None:
    from stable_baselines3.common.vec_env import VecMonitor

    pool = InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=1, seed=0)
    try:
        model = TRPOPlus("MlpPolicy", VecMonitor(pool), seed=0, **SMALL)
        with pytest.warns(UserWarning, match="wrapped by VecMonitor: TRPOPlus steps them one step at a time"):
            model.learn(SMALL["n_steps"] * 2)
        assert model.num_timesteps == SMALL["n_steps"] * 2
    finally:
        pool.close()


def test_dict_observations_are_refused_when_the_pool_starts() -> None:
    import gymnasium as gym
    from gymnasium import spaces

    class DictObservations(gym.Env):
        observation_space = spaces.Dict({"x": spaces.Box(-1, 1, (2,))})
        action_space = spaces.Box(-1, 1, (1,))

    gym.register("DictObservationsForWorkers-v0", entry_point=DictObservations)
    message = "InProcessRollouts: rollout workers collect array observations; DictObservationsForWorkers-v0 observes Dict"
    with pytest.raises(ValueError, match=message):
        InProcessRollouts("DictObservationsForWorkers-v0", num_workers=1, envs_per_worker=1)


def test_ctrl_c_while_workers_collect_lets_the_segment_finish_and_saves_a_checkpoint(tmp_path) -> None:
    """SIGINT reaches the learner while it waits for the segments; the process workers ignore it. The segment
    completes, ``learn`` stops before the update, ``SaveOnInterrupt`` saves, and the same pool resumes the run."""
    from sb3_trpo_plus.application.callbacks import SaveOnInterrupt

    pool = ProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=0)
    try:
        env = VecNormalize(pool)
        model = TRPOPlus("MlpPolicy", env, seed=0, replay_memory=2, **SMALL)
        collect = pool.collect_segments

        def interrupted(*args, **kwargs):
            if model._n_updates == 1:
                os.kill(os.getpid(), signal.SIGINT)  # handled while the learner waits for the workers
            return collect(*args, **kwargs)

        pool.collect_segments = interrupted  # type: ignore[method-assign]
        with sigint.handled_here(), pytest.raises(KeyboardInterrupt):
            model.learn(10_000, callback=SaveOnInterrupt(tmp_path))
        assert model._n_updates == 1 and all(worker["pid"] for worker in pool.workers)
        pool.collect_segments = collect  # type: ignore[method-assign]
        resumed = TRPOPlus.load(
            tmp_path / "interrupted.zip", env=VecNormalize.load(str(tmp_path / "interrupted_vecnormalize.pkl"), pool)
        )
        assert len(resumed.rollout_memory) == 1
        resumed.learn(SMALL["n_steps"] * pool.num_envs, reset_num_timesteps=False)
        assert resumed._n_updates == 2 and pool.restarts == [0, 0]
    finally:
        pool.close()
