"""The one collection loop (``collect_segment``), its record (``Segment``) and the buffer filled from it."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.normalization import NormalizationStats
from sb3_trpo_plus.algorithm.segment import (
    LoopState,
    Segment,
    SegmentRolloutBuffer,
    StepLocals,
    collect_segment,
    sampling_forward,
)


def after_reset(observation: Any, raw_observation: Any = None) -> LoopState:
    """The loop's state right after a reset: every env starts an episode at step 0."""
    n_envs = len(next(iter(observation.values())) if isinstance(observation, dict) else observation)
    raw = observation if raw_observation is None else raw_observation
    return LoopState(observation, raw, np.ones(n_envs, dtype=bool), np.zeros(n_envs, dtype=np.int64))


def _pendulum(n_envs: int = 2, max_episode_steps: int = 15) -> VecNormalize:
    """Pendulum with a short time limit (truncations in every segment), normalised."""
    return VecNormalize(
        make_vec_env("Pendulum-v1", n_envs=n_envs, seed=3, env_kwargs={"max_episode_steps": max_episode_steps})
    )


def _policy(env) -> th.nn.Module:
    return PPO("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, seed=0, device="cpu").policy


def test_the_segment_records_what_the_env_and_vec_normalize_gave() -> None:
    env = _pendulum()
    policy = _policy(env)
    obs = env.reset()
    state = after_reset(obs, env.get_original_obs())
    raw_seen, rewards_seen = [env.get_original_obs()], []
    steps = []

    def watch(step: StepLocals) -> bool:
        raw_seen.append(env.get_original_obs())
        rewards_seen.append(env.get_original_reward())
        steps.append(step)
        return True

    segment = collect_segment(policy, env, 40, state, gamma=0.9, on_step=watch)
    assert segment is not None and (segment.n_steps, segment.n_envs) == (40, 2)
    np.testing.assert_array_equal(segment.raw_observations, np.stack(raw_seen))
    np.testing.assert_array_equal(segment.raw_rewards, np.stack(rewards_seen))
    for t, step in enumerate(steps):  # what a callback saw is what was stored
        assert step.n_steps == t
        np.testing.assert_array_equal(step.rewards, segment.rewards[t])
        np.testing.assert_array_equal(step.dones, segment.dones[t])
    # 40 steps of 15-step episodes: truncations at steps 14 and 29 of both envs, each bootstrapped
    np.testing.assert_array_equal(segment.truncated_steps, [[14, 0], [14, 1], [29, 0], [29, 1]])
    np.testing.assert_array_equal(segment.terminal_timesteps, [15, 15, 15, 15])
    assert segment.terminal_observations is not None and segment.terminal_observations.shape == (4, 3)
    changed = segment.buffer_rewards != segment.rewards
    assert changed.sum() == 4 and changed[14].all() and changed[29].all()
    # the raw terminal observation is the last observation of the episode (cos, sin on the unit circle)
    np.testing.assert_allclose(np.hypot(*segment.terminal_observations[:, :2].T), 1.0, rtol=1e-5)
    # the loop state moved on: the episode clocks and the next observation
    np.testing.assert_array_equal(state.episode_timesteps, segment.episode_timesteps[-1])
    np.testing.assert_array_equal(segment.episode_timesteps[:, 0], [*range(15), *range(15), *range(11)])
    np.testing.assert_array_equal(state.observation, segment.last_observation)
    env.close()


def test_a_step_that_returns_false_stops_the_loop() -> None:
    env = _pendulum()
    policy = _policy(env)
    state = after_reset(env.reset(), env.get_original_obs())
    calls = []

    def stop_at_third(step: StepLocals) -> bool:
        calls.append(step.n_steps)
        return step.n_steps < 2

    assert collect_segment(policy, env, 10, state, gamma=0.9, on_step=stop_at_third) is None
    assert calls == [0, 1, 2]
    env.close()


def test_a_normalizer_with_a_vec_normalize_env_is_refused() -> None:
    env = _pendulum()
    normalizer = NormalizationStats.of(env)
    state = after_reset(env.reset())
    with pytest.raises(ValueError, match="normalises itself"):
        collect_segment(_policy(env), env, 2, state, gamma=0.9, normalizer=normalizer)
    env.close()


def test_a_frozen_normalizer_on_a_bare_env_gives_what_the_vec_normalize_would() -> None:
    """The workers' way (raw env, frozen statistics) and the learner's (VecNormalize) agree while the statistics
    stay frozen."""
    normalized = _pendulum()
    normalized.reset()
    for _ in range(30):  # some statistics
        normalized.step(np.ones((2, 1), dtype=np.float32))
    normalized.training = False  # frozen from here on
    bare = make_vec_env("Pendulum-v1", n_envs=2, seed=3, env_kwargs={"max_episode_steps": 15})
    policy = _policy(normalized)
    segments = []
    for env, normalizer in ((normalized, None), (bare, NormalizationStats.of(normalized))):
        env.seed(11)  # the same episodes in both
        raw = env.reset() if normalizer is not None else None
        obs = normalizer.normalize_obs(raw) if normalizer is not None else env.reset()
        state = after_reset(obs, raw if raw is not None else env.get_original_obs())
        th.manual_seed(0)
        segments.append(collect_segment(policy, env, 20, state, gamma=0.9, normalizer=normalizer))
    a, b = segments
    assert a is not None and b is not None
    for name in ("observations", "raw_observations", "actions", "rewards", "buffer_rewards", "raw_rewards", "values"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-6, atol=1e-6, err_msg=name)
    normalized.close()
    bare.close()


def test_concatenated_segments_name_their_envs_by_pool_position() -> None:
    env = _pendulum()
    policy = _policy(env)
    parts = []
    for _ in range(2):
        state = after_reset(env.reset(), env.get_original_obs())
        part = collect_segment(policy, env, 16, state, gamma=0.9)
        assert part is not None
        parts.append(part)
    whole = Segment.concatenate(parts)
    assert (whole.n_steps, whole.n_envs) == (16, 4)
    np.testing.assert_array_equal(whole.truncated_steps, [[14, 0], [14, 1], [14, 2], [14, 3]])
    assert [env_index for env_index, _ in whole.ended[14]] == [0, 1, 2, 3]
    np.testing.assert_array_equal(whole.raw_observations[:, 2:], parts[1].raw_observations)
    env.close()


def test_the_rollout_buffer_keeps_the_segment_it_was_filled_from() -> None:
    model = TRPOPlus("MlpPolicy", _pendulum(), n_steps=32, batch_size=32, policy_kwargs={"net_arch": [8]}, seed=0)
    assert isinstance(model.rollout_buffer, SegmentRolloutBuffer)
    model.learn(64)
    segment = model.rollout_buffer.segment
    assert segment is not None
    # the update read the buffer, which SB3 flattens env by env
    np.testing.assert_array_equal(model.rollout_buffer.observations, segment.observations.swapaxes(0, 1).reshape(64, 3))
    np.testing.assert_array_equal(model.rollout_buffer.rewards, segment.buffer_rewards)
    model.rollout_buffer.reset()
    assert model.rollout_buffer.segment is None


def test_a_rollout_buffer_that_cannot_hold_segments_is_refused() -> None:
    from stable_baselines3.common.buffers import RolloutBuffer

    with pytest.raises(ValueError, match="rollout_buffer_class"):
        TRPOPlus("MlpPolicy", _pendulum(), rollout_buffer_class=RolloutBuffer)


class _DictObservations(gym.Env):
    observation_space = gym.spaces.Dict({"position": gym.spaces.Box(-1, 1, (2,)), "speed": gym.spaces.Box(-1, 1, (1,))})
    action_space = gym.spaces.Box(-1, 1, (1,))

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return self.observation_space.sample(), {}

    def step(self, action):
        self.t += 1
        return self.observation_space.sample(), float(action[0]), False, self.t >= 10, {}


def test_dict_observations_are_collected_and_learned_from() -> None:
    env = DummyVecEnv([_DictObservations, _DictObservations])
    model = TRPOPlus("MultiInputPolicy", env, n_steps=16, batch_size=16, policy_kwargs={"net_arch": [8]}, seed=0)
    model.learn(64)
    segment = model.rollout_buffer.segment  # type: ignore[attr-defined]
    assert isinstance(segment.observations, dict) and segment.observations["position"].shape == (16, 2, 2)
    flat = segment.observations["speed"].swapaxes(0, 1).reshape(32, 1)
    np.testing.assert_array_equal(model.rollout_buffer.observations["speed"], flat)
    assert model.num_timesteps == 64


@pytest.mark.parametrize("share", [True, False])
def test_the_lean_forward_pass_is_the_policys_bit_for_bit(share: bool) -> None:
    """SB3's MLP policy with Gaussian actions is sampled by the lean forward pass: the same actions (the same draws from
    torch's generator), values and log probabilities as ``policy(obs)``, under no-grad and inference mode."""
    env = make_vec_env("Pendulum-v1", n_envs=4, seed=1)
    kwargs = {"net_arch": [16, 16], "log_std_init": -0.7, "share_features_extractor": share}
    policy = PPO("MlpPolicy", env, policy_kwargs=kwargs, seed=0, device="cpu").policy
    policy.set_training_mode(False)
    forward = sampling_forward(policy)
    assert forward is not policy
    obs = th.as_tensor(np.random.default_rng(0).normal(size=(64, 3)))  # float64, as obs_as_tensor gives them
    for mode in (th.no_grad, th.inference_mode):
        with mode():
            th.manual_seed(5)
            expected = policy(obs)
            th.manual_seed(5)
            lean = forward(obs)
            after = th.randn(1)
            th.manual_seed(5)
            policy(obs)
            assert th.equal(th.randn(1), after)  # as many draws
        for got, want in zip(lean, expected, strict=True):
            assert got.dtype == want.dtype and got.shape == want.shape
            assert th.equal(got, want)


def test_other_policies_are_sampled_by_their_own_forward_pass() -> None:
    env = make_vec_env("Pendulum-v1", n_envs=2, seed=1)
    sde = PPO("MlpPolicy", env, use_sde=True, seed=0, device="cpu").policy
    assert sampling_forward(sde) is sde
    discrete = PPO("MlpPolicy", make_vec_env("CartPole-v1", n_envs=2, seed=1), seed=0, device="cpu").policy
    assert sampling_forward(discrete) is discrete
