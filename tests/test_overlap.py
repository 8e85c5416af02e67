"""TRPOPlus(overlap_collection=True): rollout workers collect the next segment while the learner updates."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sb3_trpo_plus import TRPOPlus, make_model
from sb3_trpo_plus.algorithm.generalized import ReuseSettings, generalized_batch
from sb3_trpo_plus.algorithm.segment import Segment
from sb3_trpo_plus.rollouts import InProcessRollouts, ProcessRollouts

TINY = dict(n_steps=32, batch_size=64, n_critic_updates=2, cg_max_steps=5, policy_kwargs={"net_arch": [16]}, device="cpu")


def _segment_arrays(segment: Segment) -> dict[str, np.ndarray]:
    names = ("raw_observations", "observations", "actions", "log_probs", "values", "raw_rewards", "dones")
    return {name: np.asarray(getattr(segment, name)) for name in names}


def test_ordered_then_gathered_segments_are_the_collected_ones() -> None:
    """submit_segments + gather_segments on local processes = collect_segments in the learner's process."""
    policy = TRPOPlus("MlpPolicy", "Reacher2D-v1", seed=0, **TINY).policy
    results = []
    for pool_class, ordered in ((InProcessRollouts, False), (ProcessRollouts, True)):
        pool = pool_class("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=3)
        try:
            pool.reset()
            if ordered:
                pool.submit_segments(policy, 16, 0.99, None)
                assert pool.collecting
                pool.wait_segments()
                assert pool.collecting  # arrived, kept for gather_segments
                segments = pool.gather_segments()
                assert not pool.collecting
            else:
                segments = pool.collect_segments(policy, 16, 0.99, None)
            results.append([_segment_arrays(segment) for segment in segments])
        finally:
            pool.close()
    for a, b in zip(*results, strict=True):
        for name in a:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_any_other_use_of_the_pool_drops_the_ordered_segments() -> None:
    pool = ProcessRollouts("Reacher2D-v1", num_workers=1, envs_per_worker=2, seed=0)
    policy = TRPOPlus("MlpPolicy", "Reacher2D-v1", seed=0, **TINY).policy
    try:
        pool.reset()
        pool.submit_segments(policy, 8, 0.99, None)
        with pytest.raises(RuntimeError, match="the segments ordered before were not gathered"):
            pool.submit_segments(policy, 8, 0.99, None)
        assert len(pool.get_attr("spec")) == 2  # answered once the ordered segment arrived and was dropped
        assert not pool.collecting
        with pytest.raises(RuntimeError, match="no segments were ordered"):
            pool.gather_segments()
        pool.submit_segments(policy, 8, 0.99, None)
        assert pool.reset().shape == (2, *pool.observation_space.shape)
        assert not pool.collecting
    finally:
        pool.close()


class _Behaviour(BaseCallback):
    """At each rollout's end (after the next segment was ordered, before the update): the weights and the segment."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[dict[str, th.Tensor], Segment]] = []

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        weights = {name: value.detach().clone() for name, value in self.model.policy.state_dict().items()}
        self.seen.append((weights, self.model.rollout_buffer.segment))


def _log_probs(model: TRPOPlus, weights: dict[str, th.Tensor], segment: Segment) -> np.ndarray:
    current = {name: value.detach().clone() for name, value in model.policy.state_dict().items()}
    model.policy.load_state_dict(weights)
    try:
        with th.no_grad():
            observations = th.as_tensor(segment.observations[: segment.n_steps].reshape(segment.n_samples, -1))
            actions = th.as_tensor(segment.actions.reshape(segment.n_samples, -1))
            _, log_prob, _ = model.policy.evaluate_actions(observations, actions)
    finally:
        model.policy.load_state_dict(current)
    return log_prob.numpy().reshape(segment.n_steps, segment.n_envs)


def test_each_segment_was_collected_by_the_weights_before_the_last_update() -> None:
    pool = InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=0)
    try:
        model = TRPOPlus("MlpPolicy", pool, seed=0, sample_reuse="generalized", overlap_collection=True, **TINY)
        behaviour = _Behaviour()
        model.learn(4 * 32 * 4, callback=behaviour)
        assert pool.collecting  # the next segment, ordered before the last update
        assert len(behaviour.seen) == 4
        for (previous, _), (now, segment) in zip(behaviour.seen, behaviour.seen[1:], strict=False):
            np.testing.assert_allclose(_log_probs(model, previous, segment), segment.log_probs, atol=1e-5)
            assert not np.allclose(_log_probs(model, now, segment), segment.log_probs, atol=1e-5)  # one update behind
        first_weights, first = behaviour.seen[0]
        np.testing.assert_allclose(_log_probs(model, first_weights, first), first.log_probs, atol=1e-5)
        logged = model.logger.name_to_value
        assert logged["train/reuse_batches"] == 4 and logged["train/reuse_offpolicy_tv"] > 0
        assert logged["train/kl_divergence_loss"] <= logged["train/reuse_radius"] * (1 + 1e-6)
    finally:
        pool.close()


def test_a_fresh_batch_of_the_current_policy_evaluated_as_a_stored_one_is_the_buffered_batch() -> None:
    """Off-policy GAE with all ratios 1 and the current critic is SB3's GAE: the overlapped path's fresh batch equals
    the on-policy one where the segment is the current policy's (no VecNormalize: the same observations)."""
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=1)
    model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", normalize_advantage=False, **TINY)
    model.learn(32 * 2)  # one update: collect_rollouts then train
    model.collect_rollouts(model.env, model._setup_learn(64, None)[1], model.rollout_buffer, 32)  # type: ignore[arg-type]
    segment = model.rollout_buffer.segment
    settings = ReuseSettings(model.reuse, model.reuse_trace_clip, model.reuse_kl_vary)
    args: tuple[Any, ...] = (model._reevaluate, settings, 0.01, model.action_tensor)
    buffered = generalized_batch(model.policy, next(model.rollout_buffer.get(batch_size=None)), [], *args)
    overlapped = generalized_batch(model.policy, None, [segment], *args)
    assert buffered.batch.n_current == len(buffered.batch.advantages) and overlapped.batch.n_current == 0

    def rows(reused: Any) -> np.ndarray:  # one row per sample, sorted (SB3's buffer hands its samples out shuffled)
        batch = reused.batch
        columns = [
            batch.observations,
            batch.actions,
            batch.sampling_log_prob[:, None],
            batch.advantages[:, None],
            batch.sample_weights[:, None],
            reused.critic_returns[:, None],
        ]
        table = th.cat([c.reshape(len(c), -1) for c in columns], dim=1).numpy()
        return table[np.lexsort(table[:, ::-1].T)]

    np.testing.assert_allclose(rows(overlapped), rows(buffered), rtol=1e-5, atol=1e-5)
    assert overlapped.offpolicy_tv == pytest.approx(0.0, abs=1e-6) and overlapped.radius == buffered.radius


def test_process_workers_learn_across_learn_calls_and_save_and_load(tmp_path: Path) -> None:
    pool = ProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=0)
    env = VecNormalize(pool)
    waited: list[int] = []  # rollouts collected while the learner waited
    collect = pool.collect_segments
    pool.collect_segments = lambda *args: waited.append(1) or collect(*args)  # type: ignore[method-assign]
    try:
        model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", overlap_collection=True, **TINY)
        model.learn(3 * 128)
        assert pool.collecting and len(waited) == 1  # only the first rollout was collected while the learner waited
        model.learn(2 * 128, reset_num_timesteps=False)  # the segment ordered by the first call is its first
        assert model.num_timesteps == 5 * 128 and len(waited) == 1
        assert all(th.isfinite(p).all() for p in model.policy.parameters())
        model.save(tmp_path / "model.zip")
        loaded = TRPOPlus.load(tmp_path / "model.zip", env=env)
        assert loaded.overlap_collection
        loaded.learn(128, reset_num_timesteps=False)
    finally:
        env.close()


def test_make_model_builds_the_recipe_on_rollout_workers() -> None:
    model = make_model(
        "Reacher2D-v1", seed=0, workers="inprocess:2", overlap_collection=True, sample_reuse="generalized", replay_memory=0
    )
    try:
        pool = model.get_vec_normalize_env().venv if model.get_vec_normalize_env() is not None else model.get_env()
        assert isinstance(pool, InProcessRollouts) and pool.num_workers == 2
        assert model.overlap_collection
    finally:
        model.get_env().close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"workers": "process"}, "workers: expected 'BACKEND:N'"),
        ({"workers": "thread:2"}, "workers: expected 'BACKEND:N'"),
        ({"workers": "process:3"}, "does not split over 3 workers"),
        ({"workers": "process:1", "algo": "ppo"}, "algo='trpo_plus' only"),
        ({"workers": "process:1", "vec_env": "dummy"}, "vec_env='dummy' does not apply"),
    ],
)
def test_make_model_names_bad_workers(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        make_model("Reacher2D-v1", **{"n_envs": 4, **kwargs})


def test_overlap_needs_generalized_reuse_and_rollout_workers() -> None:
    with pytest.raises(ValueError, match=r"overlap_collection=True .* needs sample_reuse=.generalized."):
        TRPOPlus("MlpPolicy", "Pendulum-v1", overlap_collection=True)
    with pytest.raises(ValueError, match=r"the env is DummyVecEnv, not a pool of sb3_trpo_plus\.rollouts"):
        TRPOPlus("MlpPolicy", "Pendulum-v1", sample_reuse="generalized", overlap_collection=True, **TINY)
    with pytest.raises(ValueError, match="`overlap_collection` must be a bool"):
        TRPOPlus("MlpPolicy", "Pendulum-v1", sample_reuse="generalized", overlap_collection=1)


def test_a_script_without_a_main_guard_is_told_to_add_one(tmp_path: Path) -> None:
    """Worker processes import the script that starts them: an unguarded one fails at the pool's start, and the
    error says what to add."""
    script = tmp_path / "train.py"
    script.write_text('from sb3_trpo_plus.rollouts import ProcessRollouts\n\nProcessRollouts("Reacher2D-v1", 1, 2)\n')
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert result.returncode != 0
    assert "died: exit code 1 while starting" in result.stderr
    assert 'guard its entry point with `if __name__ == "__main__":`' in result.stderr


def test_closing_the_pool_while_a_segment_is_collected_stops_the_worker_cleanly() -> None:
    pool = ProcessRollouts("Reacher2D-v1", num_workers=1, envs_per_worker=2, seed=0)
    policy = TRPOPlus("MlpPolicy", "Reacher2D-v1", seed=0, **TINY).policy
    pool.reset()
    process = pool._backend.processes[0]  # type: ignore[attr-defined]
    pool.submit_segments(policy, 512, 0.99, None)
    pool.close()  # as after learn() with a segment ordered: the worker finds the pipe closed and stops
    assert process.exitcode == 0


class _AsksThePool(BaseCallback):
    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:  # after the next segment was ordered
        self.training_env.get_attr("spec")


def test_a_callback_that_uses_the_pool_drops_the_ordered_segment_with_a_warning() -> None:
    pool = InProcessRollouts("Reacher2D-v1", num_workers=1, envs_per_worker=2, seed=0)
    try:
        model = TRPOPlus("MlpPolicy", pool, seed=0, sample_reuse="generalized", overlap_collection=True, **TINY)
        with pytest.warns(UserWarning, match="the segment ordered during the last update was dropped"):
            model.learn(2 * 32 * 2, callback=_AsksThePool())
        assert model.num_timesteps == 2 * 32 * 2
    finally:
        pool.close()


def test_load_checks_overlap_collection_as_the_constructor_does(tmp_path: Path) -> None:
    TRPOPlus("MlpPolicy", "Pendulum-v1", **TINY).save(tmp_path / "model.zip")
    loaded = TRPOPlus.load(tmp_path / "model.zip", env=make_vec_env("Pendulum-v1"), overlap_collection=True)
    with pytest.raises(ValueError, match="needs sample_reuse='generalized'"):
        loaded.learn(64)
