"""TRPOPlus as an SB3 algorithm: validation, SB3 habits, replay memory, warm start, save/load."""

import os
import pathlib

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecNormalize

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.baselines import LinearFeatureBaseline
from sb3_trpo_plus.algorithm.update import surrogate_advantages

TINY = dict(n_steps=64, batch_size=64, n_critic_updates=2, cg_max_steps=5, policy_kwargs=dict(net_arch=[16]))


def _params(model: TRPOPlus) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy().copy() for k, v in model.policy.state_dict().items()}


# ----------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("replay_memory", -1),
        ("replay_memory", 1.5),
        ("target_kl", 0.0),
        ("target_kl", -0.01),
        ("target_kl", float("nan")),
        ("target_kl", "lin_0.01"),  # rl-zoo's spelling is the zoo's to turn into a schedule, not the algorithm's
        ("cg_max_steps", 0),
        ("cg_damping", -0.1),
        ("line_search_shrinking_factor", 1.0),
        ("line_search_shrinking_factor", 0.0),
        ("line_search_max_iter", 0),
        ("value_baseline", "quadratic"),
        ("replay_is_clip", 0.0),
        ("gamma", 1.5),
        ("gae_lambda", -0.1),
        ("n_steps", 0),
        ("batch_size", 0),
        ("sub_sampling_factor", 0),
        ("fisher_sub_sampling", 0),
        ("n_critic_updates", -1),
        ("learning_rate", -1e-3),
        ("linear_baseline_l2", -2.0),
    ],
)
def test_invalid_hyperparameter_is_named(name: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"`{name}`"):
        TRPOPlus("MlpPolicy", "Pendulum-v1", **{**TINY, name: value})


def shrinking_kl(progress_remaining: float) -> float:
    """A trust region that shrinks from 0.02 to 0.002 over training (module level, so a saved model can pickle it)."""
    return 0.002 + 0.018 * progress_remaining


def test_target_kl_schedule_sets_each_updates_trust_region(tmp_path: pathlib.Path) -> None:
    """``target_kl`` may be a schedule of the remaining progress, as SB3's ``learning_rate``: each update's radius is
    its value at that update (logged as ``train/target_kl``), the line search keeps the KL within it, and a saved
    model keeps the schedule."""
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", seed=0, **{**TINY, "target_kl": shrinking_kl})
    updates: list[tuple[float, float, float]] = []
    train = model.train

    def train_and_record() -> None:
        train()
        values = model.logger.name_to_value
        updates.append((model._current_progress_remaining, values["train/target_kl"], values["train/kl_divergence_loss"]))

    model.train = train_and_record  # type: ignore[method-assign]
    model.learn(8 * 64)
    assert len(updates) == 8
    for progress, radius, kl in updates:
        assert radius == pytest.approx(shrinking_kl(progress))
        assert kl <= radius
    assert updates[0][1] > 4 * updates[-1][1]  # it shrank: 0.0178 at the first update, 0.002 at the last
    model.save(tmp_path / "model.zip", exclude=["train"])
    loaded = TRPOPlus.load(tmp_path / "model.zip")
    assert loaded.target_kl is shrinking_kl and loaded.current_target_kl == pytest.approx(updates[-1][1])


def test_target_kl_schedule_that_leaves_the_range_is_named() -> None:
    model = TRPOPlus(
        "MlpPolicy", "Pendulum-v1", seed=0, **{**TINY, "target_kl": lambda progress: 0.01 - 0.02 * (progress < 1)}
    )
    with pytest.raises(ValueError, match=r"`target_kl`: its schedule gave -0\.01 at remaining progress 0\.5000"):
        model.learn(2 * 64)


def test_batch_of_one_sample_is_rejected() -> None:
    with pytest.raises(ValueError, match="n_steps \\* n_envs"):
        TRPOPlus("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=1), n_steps=1)


def test_replay_needs_array_observations() -> None:
    class DictObs(gym.Env):
        observation_space = gym.spaces.Dict({"a": gym.spaces.Box(-1, 1, (2,))})
        action_space = gym.spaces.Box(-1, 1, (1,))

    with pytest.raises(ValueError, match="array observation space"):
        TRPOPlus("MultiInputPolicy", DummyVecEnv([DictObs]), replay_memory=2)


# ----------------------------------------------------------------------------- spaces and vec envs
@pytest.mark.parametrize("env_id", ["Pendulum-v1", "CartPole-v1"])
@pytest.mark.parametrize("vec_env_cls", [DummyVecEnv, SubprocVecEnv])
@pytest.mark.parametrize("variant", [dict(), dict(replay_memory=2, cg_warm_start=True, value_baseline="linear")])
def test_box_and_discrete_with_vec_envs(env_id: str, vec_env_cls: type, variant: dict) -> None:
    kwargs = dict(start_method="forkserver") if vec_env_cls is SubprocVecEnv else None
    env = make_vec_env(env_id, n_envs=2, seed=0, vec_env_cls=vec_env_cls, vec_env_kwargs=kwargs)
    try:
        model = TRPOPlus("MlpPolicy", env, seed=0, **TINY, **variant).learn(3 * 128)
        action, _ = model.predict(env.observation_space.sample(), deterministic=True)
        assert env.action_space.contains(action)
    finally:
        env.close()


def test_gsde_and_subsampling() -> None:
    model = TRPOPlus(
        "MlpPolicy", "Pendulum-v1", use_sde=True, sde_sample_freq=4, sub_sampling_factor=2, replay_memory=1, **TINY
    )
    model.learn(256)
    assert model.logger.name_to_value["train/replay_samples"] == 32  # 64 replayed samples, every 2nd one


def test_callbacks_progress_bar_and_tensorboard(tmp_path: pathlib.Path) -> None:
    eval_env = make_vec_env("Pendulum-v1", n_envs=1, seed=1)
    callbacks = [
        EvalCallback(eval_env, eval_freq=64, n_eval_episodes=1, log_path=str(tmp_path / "eval"), verbose=0),
        CheckpointCallback(save_freq=128, save_path=str(tmp_path / "ckpt"), name_prefix="trpo_plus"),
    ]
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", tensorboard_log=str(tmp_path / "tb"), replay_memory=1, **TINY)
    model.learn(256, callback=callbacks, progress_bar=True)
    assert (tmp_path / "eval" / "evaluations.npz").exists()
    assert sorted(p.name for p in (tmp_path / "ckpt").iterdir())
    events = list((tmp_path / "tb").rglob("events.out.tfevents*"))
    assert events and events[0].parent.name.startswith("TRPOPlus")
    mean, _ = evaluate_policy(model, eval_env, n_eval_episodes=1)
    assert np.isfinite(mean)


def test_episode_stats_records_every_finished_training_episode() -> None:
    """``EpisodeStats``: (return, success, length) of each episode the Monitor closes, as the Monitor counts them."""
    import grasp_envs  # noqa: F401  (registers the envs)
    from sb3_trpo_plus.application.callbacks import EpisodeStats

    env = make_vec_env("Reacher2D-v1", n_envs=2, seed=0)  # 50-step episodes
    stats = EpisodeStats()
    TRPOPlus("MlpPolicy", env, seed=0, **TINY).learn(2 * 64 * 2, callback=stats)  # 128 steps per env: 2 episodes each
    monitors = env.envs  # type: ignore[attr-defined]
    returns = sorted(r for m in monitors for r in m.get_episode_rewards())
    assert sorted(r for r, _, _ in stats.episodes) == pytest.approx(returns, abs=1e-5)  # the Monitor's rounded record
    assert [length for _, _, length in stats.episodes] == [50] * 4
    assert all(isinstance(success, bool) for _, success, _ in stats.episodes)


def test_logs_the_promised_keys(tmp_path: pathlib.Path) -> None:
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", replay_memory=1, cg_warm_start=True, **TINY)
    model.set_logger(configure(str(tmp_path), ["csv"]))
    model.learn(192)
    header = (tmp_path / "progress.csv").read_text().splitlines()[0].split(",")
    for key in [
        "train/policy_objective",
        "train/value_loss",
        "train/kl_divergence_loss",
        "train/explained_variance",
        "train/is_line_search_success",
        "train/std",
        "train/cg_iterations",
        "train/cg_residual",
        "train/cg_warm_start_cosine",
        "train/line_search_steps",
        "train/step_size",
        "train/replay_samples",
        "train/replay_ess",
        "train/update_time",
        "train/fisher_vector_products",
    ]:
        assert key in header, key


# ----------------------------------------------------------------------------- replay memory
def test_replay_memory_is_bounded_and_replayed() -> None:
    model = TRPOPlus("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=2), replay_memory=2, **TINY)
    model.learn(5 * 128)
    assert len(model.rollout_memory) == 2
    assert sum(r.n_samples for r in model.rollout_memory) == 2 * 64 * 2
    assert model.logger.name_to_value["train/replay_samples"] == 2 * 64 * 2
    assert 0 < model.logger.name_to_value["train/replay_ess"] <= 1


def test_replay_with_vecnormalize_stores_raw_observations() -> None:
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=0), norm_reward=True)
    model = TRPOPlus("MlpPolicy", env, replay_memory=1, replay_critic=True, **TINY).learn(3 * 128)
    stored = model.rollout_memory[0]
    # Pendulum's raw observation is (cos, sin, angular velocity): on the unit circle before normalisation
    np.testing.assert_allclose(np.hypot(stored.raw_observations[..., 0], stored.raw_observations[..., 1]), 1.0, rtol=1e-5)
    assert np.all(stored.raw_rewards <= 0)  # raw Pendulum rewards are costs
    assert not np.allclose(stored.rewards, stored.raw_rewards)  # the policy saw them scaled by the return statistics
    assert np.isfinite(model.logger.name_to_value["train/value_loss"])


@pytest.mark.parametrize("replay_critic", [False, True])
def test_critic_is_fit_on_current_rollout_unless_replay_critic(replay_critic: bool) -> None:
    """By default the critic sees the current rollout only (as the thesis); ``replay_critic=True`` adds the replayed
    rollouts: 0, 1, 2, 3 of them at the four updates of a memory of 3."""
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", replay_memory=3, replay_critic=replay_critic, **TINY)
    batches = []
    original = model._critic_minibatches

    def spy(replayed):
        for obs, ret, weights in original(replayed):
            batches.append(len(obs))
            yield obs, ret, weights

    model._critic_minibatches = spy  # type: ignore[method-assign]
    model.learn(4 * 64)
    rollouts_seen = (1 + 2 + 3 + 4) if replay_critic else 4
    assert max(batches) == 64 and sum(batches) == rollouts_seen * TINY["n_critic_updates"] * 64


def test_replay_is_clip_truncates_the_replayed_samples_weights() -> None:
    """``replay_is_clip=c`` scales a replayed sample's advantage by ``min(1, c / rho)``, ``rho = pi_current / q``, so
    that its weight in the surrogate is ``min(rho, c)``; the current rollout's samples are left as they are."""
    clip = 1.0
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", seed=0, replay_memory=1, replay_is_clip=clip, **TINY)
    model.learn(2 * 64)  # the memory holds the first rollout, sampled by an older policy than the current one
    batch = model._policy_batch(model._reevaluate_memory())
    assert batch.n_current == 64 and batch.n_replayed == 64
    log_prob = model.policy.get_distribution(batch.observations).log_prob(batch.actions).detach()
    clipped = surrogate_advantages(batch, log_prob, normalize=True, replay_is_clip=clip)
    unclipped = surrogate_advantages(batch, log_prob, normalize=True, replay_is_clip=None)
    rho = th.exp(log_prob - batch.sampling_log_prob)[64:]
    assert bool((rho > clip).any()), "no weight above the clip: the test would prove nothing"
    th.testing.assert_close(clipped.advantages[:64], unclipped.advantages[:64])
    th.testing.assert_close(clipped.advantages[64:], unclipped.advantages[64:] * th.clamp(clip / rho, max=1.0))
    assert 0 < unclipped.replay_ess <= 1 and 0 < clipped.replay_ess <= 1


@pytest.mark.parametrize("replay_memory", [0, 1])
def test_linear_baseline_fits_each_sample_with_its_own_step_in_the_episode(replay_memory: int) -> None:
    """The baseline's time features belong to the samples they stand beside: with several envs whose episodes end at
    different steps, the fit equals one on the segment's arrays in its own [step, env] order."""
    model = TRPOPlus(
        "MlpPolicy",
        make_vec_env("CartPole-v1", n_envs=2, seed=0),
        seed=0,
        value_baseline="linear",
        replay_memory=replay_memory,
        **TINY,
    )
    model.learn(2 * 2 * 64)
    segment = model.rollout_buffer.segment  # type: ignore[attr-defined]
    steps = segment.episode_timesteps[: segment.n_steps]
    assert not np.array_equal(steps[:, 0], steps[:, 1]), "the envs' episodes are in step: the test would prove nothing"
    buffer = model.rollout_buffer
    assert buffer.generator_ready  # the update read the buffer: its arrays are flattened env by env

    def step_major(array: np.ndarray) -> np.ndarray:
        return (
            array.reshape(buffer.n_envs, buffer.buffer_size, -1).swapaxes(0, 1).reshape(buffer.buffer_size * buffer.n_envs, -1)
        )

    expected = LinearFeatureBaseline(l2_reg=model.linear_baseline_l2)
    expected.fit(step_major(buffer.observations), steps.reshape(-1), step_major(buffer.returns))
    assert model.linear_baseline is not None and model.linear_baseline.weights is not None
    np.testing.assert_allclose(model.linear_baseline.weights, expected.weights, rtol=1e-10, atol=1e-12)


def test_linear_baseline_l2_is_the_ridge_coefficient() -> None:
    """``linear_baseline_l2`` is the baseline's ridge coefficient: on the same rollout a larger one shrinks its weights."""
    norms = []
    for l2 in (0.0, 2.0, 1000.0):
        model = TRPOPlus("MlpPolicy", "Pendulum-v1", seed=0, value_baseline="linear", linear_baseline_l2=l2, **TINY)
        assert model.linear_baseline is not None and model.linear_baseline.l2_reg == l2
        model.learn(64)  # one rollout (the same for all: the baseline does not act), one fit
        assert model.linear_baseline.weights is not None
        norms.append(float(np.linalg.norm(model.linear_baseline.weights)))
    assert norms[0] > norms[1] > norms[2]


def test_warm_start_resets_after_rejected_line_search(monkeypatch) -> None:
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", cg_warm_start=True, **TINY)
    model.learn(64)
    assert model.previous_step is not None and np.any(model.previous_step != 0)
    monkeypatch.setattr(model, "target_kl", 1e-30)  # no step can satisfy the constraint
    before = _params(model)
    model.learn(64, reset_num_timesteps=False)
    assert model.previous_step is None
    assert model.logger.name_to_value["train/is_line_search_success"] == 0.0
    after = _params(model)
    for name in before:
        if "value" not in name:  # the critic still trains; actor weights are restored exactly
            np.testing.assert_array_equal(after[name], before[name], err_msg=name)


def test_nan_never_reaches_the_policy(monkeypatch) -> None:
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", **TINY)
    model.learn(64)
    before = _params(model)
    model.rollout_buffer.advantages[:] = np.nan  # what the policy step and the critic read
    model.rollout_buffer.returns[:] = np.nan
    monkeypatch.setattr(model, "collect_rollouts", lambda *a, **k: True)
    model.train()
    for name, value in _params(model).items():
        assert np.all(np.isfinite(value)), name
        np.testing.assert_array_equal(value, before[name], err_msg=name)
    assert model.logger.name_to_value["train/critic_skipped_steps"] > 0


# ----------------------------------------------------------------------------- save / load
@pytest.mark.parametrize("variant", [dict(), dict(replay_memory=2, cg_warm_start=True), dict(value_baseline="linear")])
def test_save_load_resume_equals_uninterrupted(tmp_path: pathlib.Path, variant: dict) -> None:
    n = 3 * 128

    def make(seed: int = 5) -> tuple[TRPOPlus, object]:
        env = make_vec_env("Pendulum-v1", n_envs=2, seed=seed)
        return TRPOPlus("MlpPolicy", env, seed=seed, **TINY, **variant), env

    straight, _ = make()
    straight.learn(2 * n)

    first, env = make()
    first.learn(n)
    first.save(tmp_path / "model")
    del first
    resumed = TRPOPlus.load(tmp_path / "model.zip", env=env, force_reset=False)
    resumed.learn(n, reset_num_timesteps=False)

    assert resumed.num_timesteps == straight.num_timesteps == 2 * n
    a, b = _params(straight), _params(resumed)
    for name in a:
        np.testing.assert_allclose(b[name], a[name], rtol=1e-6, atol=1e-7, err_msg=name)
    if variant.get("replay_memory"):
        assert len(resumed.rollout_memory) == 2


def test_save_can_leave_replay_memory_out(tmp_path: pathlib.Path) -> None:
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", replay_memory=3, **TINY).learn(4 * 64)
    model.save(tmp_path / "with.zip")
    model.save(tmp_path / "without.zip", exclude=["rollout_memory"])
    assert os.path.getsize(tmp_path / "without.zip") < os.path.getsize(tmp_path / "with.zip")
    loaded = TRPOPlus.load(tmp_path / "without.zip", env=make_vec_env("Pendulum-v1"))
    assert len(loaded.rollout_memory) == 0
    loaded.learn(64)


def test_save_is_atomic(tmp_path: pathlib.Path, monkeypatch) -> None:
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", **TINY)
    target = tmp_path / "model.zip"
    model.save(target)
    good = target.read_bytes()

    import stable_baselines3.common.base_class as base_class

    def crash(*args, **kwargs):
        raise KeyboardInterrupt("crash mid-save")

    monkeypatch.setattr(base_class, "save_to_zip_file", crash)
    with pytest.raises(KeyboardInterrupt):
        model.save(target)
    assert target.read_bytes() == good
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]  # no temporary file left behind


def test_save_keeps_the_usual_file_mode(tmp_path: pathlib.Path) -> None:
    # the temporary file of the atomic save is private (0600) when made; the saved model must not be
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", **TINY)
    previous = os.umask(0o022)
    try:
        model.save(tmp_path / "model.zip")
    finally:
        os.umask(previous)
    assert (tmp_path / "model.zip").stat().st_mode & 0o777 == 0o644


def test_predict_deterministic_after_load(tmp_path: pathlib.Path) -> None:
    model = TRPOPlus("MlpPolicy", "CartPole-v1", **TINY).learn(128)
    model.save(tmp_path / "m")
    loaded = TRPOPlus.load(tmp_path / "m")
    obs = np.array([0.01, -0.02, 0.03, 0.0], dtype=np.float32)
    assert model.predict(obs, deterministic=True)[0] == loaded.predict(obs, deterministic=True)[0]
    th.testing.assert_close(model.policy.state_dict()["action_net.weight"], loaded.policy.state_dict()["action_net.weight"])


def test_load_seeds_as_sb3_and_resuming_restores_the_runs_generators(tmp_path: pathlib.Path) -> None:
    """Loading a model seeds the global generators with the model's seed, as SB3's load does; the run's own saved
    states come back only when ``learn(reset_num_timesteps=False)`` resumes it, also after a second save."""
    model = TRPOPlus("MlpPolicy", "Pendulum-v1", seed=7, **TINY).learn(64)
    model.save(tmp_path / "m.zip")
    saved_next = np.random.random()  # what the run's numpy generator gives next
    loaded = TRPOPlus.load(tmp_path / "m.zip", env=make_vec_env("Pendulum-v1"), force_reset=False)
    assert np.random.random() == np.random.RandomState(7).random()  # SB3's set_random_seed(model.seed)
    loaded.save(tmp_path / "again.zip")  # a loaded run saved again keeps its own states
    resumed = TRPOPlus.load(tmp_path / "again.zip", env=make_vec_env("Pendulum-v1"), force_reset=False)
    resumed._setup_learn(64, reset_num_timesteps=False)
    assert np.random.random() == saved_next


# ----------------------------------------------------------------------------- the collection path
class _NaNAfter(gym.Wrapper):
    """Pendulum whose observation turns NaN at its ``after``-th step."""

    def __init__(self, env: gym.Env, after: int = 5):
        super().__init__(env)
        self.after, self.steps = after, 0

    def step(self, action):  # type: ignore[no-untyped-def]
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        return (obs * np.nan if self.steps >= self.after else obs), reward, terminated, truncated, info


def test_a_non_finite_observation_is_named_before_the_policy_sees_it() -> None:
    env = DummyVecEnv([lambda: gym.make("Pendulum-v1"), lambda: _NaNAfter(gym.make("Pendulum-v1"))])
    model = TRPOPlus("MlpPolicy", env, seed=0, **TINY)
    before = _params(model)
    with pytest.raises(ValueError, match="env 1 returned a non-finite observation"):
        model.learn(64 * 2)
    assert all(np.array_equal(before[k], v) for k, v in _params(model).items())


def test_collection_leaves_torch_distribution_checks_as_they_were() -> None:
    from torch.distributions import Distribution

    previous = Distribution._validate_args
    try:
        for setting in (True, False):
            Distribution.set_default_validate_args(setting)
            TRPOPlus("MlpPolicy", "Pendulum-v1", seed=0, **TINY).learn(64)
            assert Distribution._validate_args is setting
        Distribution.set_default_validate_args(True)
        env = DummyVecEnv([lambda: _NaNAfter(gym.make("Pendulum-v1"), after=3)])
        with pytest.raises(ValueError, match="non-finite observation"):
            TRPOPlus("MlpPolicy", env, seed=0, **TINY).learn(64)
        assert Distribution._validate_args is True  # restored when collection raised
    finally:
        Distribution.set_default_validate_args(previous)


def test_critic_minibatches_are_the_rollout_buffers() -> None:
    """The critic reads its minibatches straight from the buffer's arrays: the same samples, in the same order, from
    the same draws of NumPy's generator as ``RolloutBuffer.get``."""
    model = TRPOPlus("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=2, seed=0), seed=0, **{**TINY, "batch_size": 48})
    model.learn(128)  # a full, flattened buffer
    buffer = model.rollout_buffer
    state = np.random.get_state()
    expected = [(data.observations, data.returns) for data in buffer.get(model.batch_size)]
    np.random.set_state(state)
    got = list(model._critic_minibatches([]))
    assert [len(r) for _, r, _ in got] == [48, 48, 32]
    assert len(got) == len(expected)
    for (obs, returns, weights), (obs_expected, returns_expected) in zip(got, expected, strict=True):
        assert th.equal(obs, obs_expected) and th.equal(returns, returns_expected) and weights is None
