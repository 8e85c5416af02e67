"""TRPOPlus(sample_reuse="generalized"): the generalized trust region's update against plain TRPOPlus, its memory,
and every collection path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.generalized import ReuseSettings, generalized_batch, log_prob_of
from sb3_trpo_plus.rollouts import InProcessRollouts

TINY = dict(n_steps=64, batch_size=64, n_critic_updates=3, policy_kwargs={"net_arch": [16]}, device="cpu")


def _parameters(model: TRPOPlus) -> dict[str, np.ndarray]:
    return {name: value.detach().numpy().copy() for name, value in model.policy.state_dict().items()}


@pytest.mark.parametrize("env_id", ["Pendulum-v1", "CartPole-v1"])
def test_one_batch_is_plain_trpo_plus(env_id: str) -> None:
    """B = M = 1 with the same radius: every update equals plain TRPOPlus' (and so sb3-contrib's) to 1e-6."""
    results = []
    for reuse in ("none", "generalized"):
        env = VecNormalize(make_vec_env(env_id, n_envs=2, seed=1))
        model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse=reuse, reuse_batches=1, **TINY)
        model.learn(4 * 128)
        results.append(_parameters(model))
    for name in results[0]:
        np.testing.assert_allclose(results[1][name], results[0][name], rtol=1e-6, atol=1e-6, err_msg=name)


def test_the_memory_holds_the_older_batches_and_the_update_weighs_them() -> None:
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=1))
    model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", **TINY)  # B = 2, M_max = 10: 4 batches
    assert model.reuse is not None and model.reuse.n_batches == 4
    seen = []
    for _ in range(5):
        model.learn(128, reset_num_timesteps=False)
        logged = model.logger.name_to_value
        seen.append((len(model.rollout_memory), logged["train/reuse_batches"], logged["train/reuse_radius"]))
        assert logged["train/kl_divergence_loss"] <= logged["train/reuse_radius"] * (1 + 1e-6)
    assert [memory for memory, _, _ in seen] == [1, 2, 3, 3, 3]  # M - 1 stored segments at most
    assert [batches for _, batches, _ in seen] == [1, 2, 3, 4, 4]  # the fresh batch and the stored ones
    assert all(radius == pytest.approx(0.01 / 4) for _, _, radius in seen)  # target_kl / B**2


def test_kl_vary_spends_the_radius_the_old_batches_already_used() -> None:
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=1))
    model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", reuse_kl_vary=True, **TINY)
    model.learn(3 * 128)
    logged = model.logger.name_to_value
    spent = 2 * logged["train/reuse_offpolicy_tv"]
    assert spent > 0
    assert logged["train/reuse_radius"] == pytest.approx(max(np.sqrt(2 * 0.01) - spent, 0) ** 2 / 2, rel=1e-5)


def test_the_offpolicy_distance_is_the_current_policys_ratio_to_each_stored_batch() -> None:
    """``offpolicy_tv`` (and so ``reuse_kl_vary``'s spent radius) is ``mean(w * |pi / q - 1|) / 2`` over the stored
    batches, from the log-probabilities the traces computed: equal to a separate forward pass of the policy."""
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=1))
    model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", **TINY).learn(3 * 128)
    assert model.reuse is not None
    stored = list(reversed(model.rollout_memory))
    reused = generalized_batch(
        model.policy, None, stored, model._reevaluate, ReuseSettings(model.reuse), 0.01, model.action_tensor
    )
    weights = model.reuse.per_sample(len(stored))
    distances = []
    for weight, segment in zip(weights, stored, strict=True):
        observations = model.policy.obs_to_tensor(model._reevaluate(segment).observations)[0]
        actions = th.as_tensor(segment.actions.reshape(segment.n_samples, -1).astype(np.float32))
        log_prob = log_prob_of(model.policy, observations, actions, model.action_tensor).numpy()  # type: ignore[arg-type]
        distances.append(weight * np.abs(np.exp(log_prob - segment.log_probs.reshape(-1)) - 1.0))
    assert reused.n_batches == 3
    assert reused.offpolicy_tv > 0
    assert reused.offpolicy_tv == pytest.approx(float(np.concatenate(distances).mean()) / 2, rel=1e-5)


def test_an_evaluation_that_skips_the_traces_is_named() -> None:
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=1))
    model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", **TINY).learn(2 * 128)
    assert model.reuse is not None
    with pytest.raises(RuntimeError, match="must compute the segment's trace ratios"):
        generalized_batch(
            model.policy,
            None,
            list(model.rollout_memory),
            lambda segment, traces: model._reevaluate(segment),
            ReuseSettings(model.reuse),
            0.01,
            model.action_tensor,
        )


def test_save_load_keeps_the_memory_bit_exact(tmp_path: Path) -> None:
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=1))
    model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", **TINY).learn(3 * 128)
    model.save(tmp_path / "model.zip")
    loaded = TRPOPlus.load(tmp_path / "model.zip", env=env)
    assert len(loaded.rollout_memory) == len(model.rollout_memory) == 3  # three updates, M - 1 = 3 kept
    for a, b in zip(model.rollout_memory, loaded.rollout_memory, strict=True):
        for name in ("raw_observations", "actions", "log_probs", "raw_rewards", "dones", "episode_timesteps"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert loaded.reuse is not None and loaded.rollout_memory.maxlen == 3


def test_with_vecnormalize_old_batches_are_stored_raw_and_normalised_with_todays_statistics() -> None:
    """The memory keeps what the env returned (Pendulum's observation is on the unit circle before normalisation,
    its rewards are costs); each update normalises an old batch with the statistics of that update, not of the
    update that collected it."""
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=0), norm_reward=True)
    model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", **TINY).learn(3 * 128)
    oldest = model.rollout_memory[0]
    raw = oldest.raw_observations
    assert isinstance(raw, np.ndarray)
    np.testing.assert_allclose(np.hypot(raw[..., 0], raw[..., 1]), 1.0, rtol=1e-5)
    assert np.all(oldest.raw_rewards <= 0)
    evaluation = model._reevaluate(oldest)
    n_steps, n_envs = oldest.raw_rewards.shape
    today = env.normalize_obs(raw[:n_steps].reshape(n_steps * n_envs, -1)).astype(np.float32)
    np.testing.assert_array_equal(evaluation.observations, today)
    model.learn(128, reset_num_timesteps=False)  # the statistics move on: the same batch, normalised anew
    assert not np.allclose(model._reevaluate(oldest).observations, today)


@pytest.mark.parametrize("collector", ["workers", "batched"])
def test_every_collection_path_learns(collector: str) -> None:
    if collector == "workers":
        env = VecNormalize(InProcessRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=0))
    else:
        from grasp_envs import make_batch_env

        env = VecNormalize(make_batch_env("Grasper3D-v7", 4, seed=0))
    try:
        model = TRPOPlus("MlpPolicy", env, seed=0, sample_reuse="generalized", **TINY).learn(4 * 256)
        logged = model.logger.name_to_value
        assert logged["train/reuse_batches"] == 4 and np.isfinite(logged["train/value_loss"])
        assert all(th.isfinite(p).all() for p in model.policy.parameters())
    finally:
        env.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"replay_memory": 2}, "does not combine with \\['replay_memory'\\]"),
        ({"value_baseline": "linear"}, "value_baseline='linear'"),
        ({"reuse_batches": 6}, "`reuse_batches` must be a finite number in \\[1, 5.5\\] for `reuse_max_batches`=10"),
        ({"reuse_trace_clip": 0}, "`reuse_trace_clip` must be a finite number > 0"),
    ],
)
def test_conflicting_settings_are_named(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        TRPOPlus("MlpPolicy", "Pendulum-v1", sample_reuse="generalized", **kwargs)


def test_unknown_reuse_is_named() -> None:
    with pytest.raises(ValueError, match="`sample_reuse` must be one of \\('none', 'generalized'\\)"):
        TRPOPlus("MlpPolicy", "Pendulum-v1", sample_reuse="thesis")
