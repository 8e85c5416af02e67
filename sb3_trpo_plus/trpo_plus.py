"""TRPOPlus: TRPO with a replay memory and warm-started conjugate gradient (thesis chapter 5.3)."""

from __future__ import annotations

import io
import math
import os
import pathlib
import random
import tempfile
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.distributions import Distribution, kl_divergence
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import explained_variance, obs_as_tensor
from stable_baselines3.common.vec_env import VecEnv
from torch import nn
from torch.nn import functional as F

from sb3_trpo_plus.baselines import LinearFeatureBaseline
from sb3_trpo_plus.natural_gradient import (
    LineSearchResult,
    backtracking_line_search,
    conjugate_gradient,
    detached_distribution,
    fisher_vector_product,
    flat_gradient,
)
from sb3_trpo_plus.replay import (
    RolloutRecorder,
    StoredRollout,
    effective_sample_size,
    importance_weights,
    recompute_advantages,
)

SelfTRPOPlus = TypeVar("SelfTRPOPlus", bound="TRPOPlus")

VALUE_BASELINES = ("critic", "linear")


def actor_parameters(policy: ActorCriticPolicy) -> list[nn.Parameter]:
    """The parameters that define the action distribution, selected through the policy's modules.

    Features extractor (shared or actor-only), the actor MLP, the action head and a state-independent
    log-std. The value head and the critic MLP are never included.
    """
    mlp_extractor = policy.mlp_extractor
    if not hasattr(mlp_extractor, "policy_net"):
        raise TypeError(
            f"{type(mlp_extractor).__name__} has no `policy_net`: TRPOPlus needs SB3's MlpExtractor layout "
            "to tell actor parameters from critic parameters"
        )
    extractor = policy.features_extractor if policy.share_features_extractor else policy.pi_features_extractor
    modules: list[nn.Module] = [extractor, mlp_extractor.policy_net, policy.action_net]
    params: list[nn.Parameter] = [p for module in modules for p in module.parameters()]
    log_std = getattr(policy, "log_std", None)
    if isinstance(log_std, nn.Parameter):
        params.append(log_std)
    unique: dict[int, nn.Parameter] = {id(p): p for p in params if p.requires_grad}
    return list(unique.values())


def validate_hyperparameters(
    *,
    learning_rate: float | Schedule,
    n_steps: int,
    batch_size: int,
    gamma: float,
    gae_lambda: float,
    cg_max_steps: int,
    cg_damping: float,
    line_search_shrinking_factor: float,
    line_search_max_iter: int,
    n_critic_updates: int,
    target_kl: float | Schedule,
    sub_sampling_factor: int,
    fisher_sub_sampling: int,
    replay_memory: int,
    replay_is_clip: float | None,
    value_baseline: str,
    linear_baseline_l2: float,
) -> None:
    """Raise ``ValueError`` naming the first invalid hyperparameter."""

    def is_int(value: Any) -> bool:
        return isinstance(value, int | np.integer) and not isinstance(value, bool)

    def is_real(value: Any) -> bool:
        return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)

    def need(condition: bool, name: str, value: Any, rule: str) -> None:
        if not condition:
            raise ValueError(f"TRPOPlus hyperparameter `{name}` must be {rule}, got {value!r}")

    if not callable(learning_rate):
        need(is_real(learning_rate) and learning_rate > 0, "learning_rate", learning_rate, "a positive number or a schedule")
    for name, value in (
        ("n_steps", n_steps),
        ("batch_size", batch_size),
        ("cg_max_steps", cg_max_steps),
        ("line_search_max_iter", line_search_max_iter),
        ("sub_sampling_factor", sub_sampling_factor),
        ("fisher_sub_sampling", fisher_sub_sampling),
    ):
        need(is_int(value) and value >= 1, name, value, "an integer >= 1")
    need(is_int(n_critic_updates) and n_critic_updates >= 0, "n_critic_updates", n_critic_updates, "an integer >= 0")
    need(is_int(replay_memory) and replay_memory >= 0, "replay_memory", replay_memory, "an integer >= 0 (k past rollouts)")
    need(is_real(gamma) and 0.0 <= gamma <= 1.0, "gamma", gamma, "in [0, 1]")
    need(is_real(gae_lambda) and 0.0 <= gae_lambda <= 1.0, "gae_lambda", gae_lambda, "in [0, 1]")
    need(
        is_real(cg_damping) and math.isfinite(cg_damping) and cg_damping >= 0, "cg_damping", cg_damping, "a finite number >= 0"
    )
    if not callable(target_kl):
        need(
            is_real(target_kl) and math.isfinite(target_kl) and target_kl > 0,
            "target_kl",
            target_kl,
            "a finite number > 0 or a schedule",
        )
    need(
        is_real(line_search_shrinking_factor) and 0.0 < line_search_shrinking_factor < 1.0,
        "line_search_shrinking_factor",
        line_search_shrinking_factor,
        "in the open interval (0, 1)",
    )
    if replay_is_clip is not None:
        need(is_real(replay_is_clip) and replay_is_clip > 0, "replay_is_clip", replay_is_clip, "None or a number > 0")
    need(value_baseline in VALUE_BASELINES, "value_baseline", value_baseline, f"one of {VALUE_BASELINES}")
    need(is_real(linear_baseline_l2) and linear_baseline_l2 >= 0, "linear_baseline_l2", linear_baseline_l2, "a number >= 0")


@dataclass(frozen=True)
class PolicyBatch:
    """Samples of one policy update: the current rollout (``n_current`` samples) followed by the replayed ones."""

    observations: th.Tensor
    actions: th.Tensor
    sampling_log_prob: th.Tensor
    advantages: th.Tensor
    n_current: int

    @property
    def n_replayed(self) -> int:
        return len(self.advantages) - self.n_current


class TRPOPlus(TRPO):
    """
    Trust Region Policy Optimization with replay memory and warm-started conjugate gradient.

    TRPO: Schulman et al. (2015) https://arxiv.org/abs/1502.05477. Improvements: P. Kovacs,
    *Learning of object grasping in a robotic system* (master's thesis, 2017), section 5.3:
    a replay memory of the last ``k`` rollouts (5.3.1) and CG warm-started with the previous
    update step (5.3.2, after Martens 2010). With ``replay_memory=0``, ``cg_warm_start=False`` and
    ``value_baseline="critic"`` one update is sb3-contrib's TRPO update. See ``docs/algorithm.md``.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, ...)
    :param env: The environment to learn from (if registered in Gymnasium, can be str;
        ``grasp_envs`` ids work without importing it)
    :param learning_rate: Learning rate of the critic's Adam optimizer (or a schedule of the remaining progress)
    :param n_steps: Steps per environment per rollout (rollout = ``n_steps * n_envs`` samples)
    :param batch_size: Minibatch size of the critic updates
    :param gamma: Discount factor (thesis: 0.995)
    :param cg_max_steps: Maximum conjugate-gradient iterations per update (thesis: 10)
    :param cg_damping: Damping ``lambda`` added to the Fisher matrix, ``(F + lambda I)`` (thesis: 0.1)
    :param line_search_shrinking_factor: Backtracking factor ``beta`` of the line search, in (0, 1)
    :param line_search_max_iter: Maximum number of line-search trials
    :param n_critic_updates: Critic epochs per update (unused with ``value_baseline="linear"``)
    :param gae_lambda: GAE lambda (1.0 gives the thesis' Monte-Carlo returns)
    :param use_sde: Use generalized State Dependent Exploration (gSDE)
    :param sde_sample_freq: Sample a new gSDE noise matrix every n steps (-1: once per rollout)
    :param rollout_buffer_class: Rollout buffer class (default: SB3's ``RolloutBuffer``)
    :param rollout_buffer_kwargs: Keyword arguments for the rollout buffer
    :param normalize_advantage: Normalise advantages over the update batch (current + replayed samples)
    :param target_kl: Trust-region radius ``delta``: maximum mean KL between successive policies (thesis: 0.01),
        or a schedule of the remaining progress (1 to 0), as SB3 takes for ``learning_rate``: each update uses
        its value then (logged as ``train/target_kl``); a shrinking radius lets the policy settle
    :param sub_sampling_factor: Use every n-th sample of the update batch for the policy step (Schulman's thesis p.40)
    :param fisher_sub_sampling: Estimate the Fisher matrix (the CG products) on every n-th sample of the update
        batch only (1: all samples). The gradient, KL and line search still use every sample. With a replay
        memory of ``k`` rollouts, ``k + 1`` keeps the cost of the products at that of plain TRPO.
    :param replay_memory: ``k``, the number of *past* rollouts reused by every policy update
        (thesis 5.3.1 used k=3). Each update recomputes their values, GAE advantages and returns with the
        current value function and weights them by ``pi_theta / q`` where ``q`` sampled them.
        Memory holds at most ``k * n_steps * n_envs`` samples.
    :param replay_is_clip: Truncate the importance weights ``pi_current / q`` of replayed samples at this
        value (``None``: no truncation). Their effective sample size is logged as ``train/replay_ess``.
    :param replay_critic: Also fit the critic on replayed rollouts (default: current rollout only, as the thesis)
    :param cg_warm_start: Start CG from the previous update's full parameter step (thesis 5.3.2), zero at the
        first update and after a rejected line search
    :param cg_warm_start_rescale: Rescale the warm start to its exact line minimiser
        ``(x0^T g / x0^T F x0) x0`` (free: it reuses the product the warm start needs anyway)
    :param value_baseline: ``"critic"`` (SB3's value head) or ``"linear"`` (the thesis' ridge-regression
        baseline on ``[o, o^2, t, t^2, t^3, 1]``, thesis 5.1.3, refit every update)
    :param linear_baseline_l2: Ridge coefficient of the linear baseline (thesis: 2)
    :param stats_window_size: Episodes averaged for the rollout logs
    :param tensorboard_log: The log location for TensorBoard (if None, no logging)
    :param policy_kwargs: Additional arguments for the policy (e.g. ``net_arch``, ``activation_fn``)
    :param verbose: 0 no output, 1 info, 2 debug
    :param seed: Seed for the pseudo random generators
    :param device: Device (cpu, cuda, ...) on which the code should run
    :param _init_setup_model: Whether or not to build the network at the creation of the instance
    """

    policy_aliases: ClassVar = TRPO.policy_aliases

    def __init__(
        self,
        policy: str | type[ActorCriticPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-3,
        n_steps: int = 2048,
        batch_size: int = 128,
        gamma: float = 0.99,
        cg_max_steps: int = 15,
        cg_damping: float = 0.1,
        line_search_shrinking_factor: float = 0.8,
        line_search_max_iter: int = 10,
        n_critic_updates: int = 10,
        gae_lambda: float = 0.95,
        use_sde: bool = False,
        sde_sample_freq: int = -1,
        rollout_buffer_class: type[RolloutBuffer] | None = None,
        rollout_buffer_kwargs: dict[str, Any] | None = None,
        normalize_advantage: bool = True,
        target_kl: float | Schedule = 0.01,
        sub_sampling_factor: int = 1,
        fisher_sub_sampling: int = 1,
        replay_memory: int = 0,
        replay_is_clip: float | None = None,
        replay_critic: bool = False,
        cg_warm_start: bool = False,
        cg_warm_start_rescale: bool = True,
        value_baseline: str = "critic",
        linear_baseline_l2: float = 2.0,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ):
        validate_hyperparameters(
            learning_rate=learning_rate, n_steps=n_steps, batch_size=batch_size, gamma=gamma,
            gae_lambda=gae_lambda, cg_max_steps=cg_max_steps, cg_damping=cg_damping,
            line_search_shrinking_factor=line_search_shrinking_factor, line_search_max_iter=line_search_max_iter,
            n_critic_updates=n_critic_updates, target_kl=target_kl, sub_sampling_factor=sub_sampling_factor,
            fisher_sub_sampling=fisher_sub_sampling, replay_memory=replay_memory, replay_is_clip=replay_is_clip,
            value_baseline=value_baseline, linear_baseline_l2=linear_baseline_l2,
        )  # fmt: skip
        if isinstance(env, str):
            import grasp_envs  # noqa: F401  (registers our ids so that a bare id string works)
        if env is not None and not isinstance(env, str) and normalize_advantage:
            n_envs = env.num_envs if isinstance(env, VecEnv) else 1
            if n_steps * n_envs <= 1:
                raise ValueError(f"TRPOPlus needs `n_steps * n_envs` > 1 to normalise advantages, got {n_steps} * {n_envs}")
        super().__init__(
            policy, env, learning_rate=learning_rate, n_steps=n_steps, batch_size=batch_size, gamma=gamma,
            cg_max_steps=cg_max_steps, cg_damping=cg_damping,
            line_search_shrinking_factor=line_search_shrinking_factor, line_search_max_iter=line_search_max_iter,
            n_critic_updates=n_critic_updates, gae_lambda=gae_lambda, use_sde=use_sde,
            sde_sample_freq=sde_sample_freq, rollout_buffer_class=rollout_buffer_class,
            rollout_buffer_kwargs=rollout_buffer_kwargs, normalize_advantage=normalize_advantage,
            target_kl=target_kl,  # type: ignore[arg-type]  # a schedule too (sb3-contrib's TRPO only stores it)
            sub_sampling_factor=sub_sampling_factor, stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log, policy_kwargs=policy_kwargs, verbose=verbose, seed=seed,
            device=device, _init_setup_model=False,
        )  # fmt: skip
        self.fisher_sub_sampling = int(fisher_sub_sampling)
        self.replay_memory = int(replay_memory)
        self.replay_is_clip = replay_is_clip
        self.replay_critic = bool(replay_critic)
        self.cg_warm_start = bool(cg_warm_start)
        self.cg_warm_start_rescale = bool(cg_warm_start_rescale)
        self.value_baseline = value_baseline
        self.linear_baseline_l2 = float(linear_baseline_l2)
        array_spaces = spaces.Box | spaces.Discrete | spaces.MultiDiscrete | spaces.MultiBinary
        if self._needs_rollout_record and not isinstance(self.observation_space, array_spaces):
            raise ValueError(
                "`replay_memory` > 0 and `value_baseline='linear'` need an array observation space, "
                f"got {type(self.observation_space).__name__}"
            )
        # State that survives save/load (see `_setup_model`, which keeps loaded values)
        self.rollout_memory: deque[StoredRollout] | None = None
        self.linear_baseline: LinearFeatureBaseline | None = None
        self.previous_step: np.ndarray | None = None
        self._last_original_obs: np.ndarray | None = None
        self._episode_timesteps: np.ndarray | None = None
        self._rng_states: dict[str, Any] | None = None
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up
    @property
    def _needs_rollout_record(self) -> bool:
        return self.replay_memory > 0 or self.value_baseline == "linear"

    def _setup_model(self) -> None:
        super()._setup_model()
        self._update_target_kl()
        self._actor_params = actor_parameters(self.policy)  # type: ignore[arg-type]
        memory = getattr(self, "rollout_memory", None)
        self.rollout_memory = deque(memory or [], maxlen=max(self.replay_memory, 1))
        if self.value_baseline == "linear" and getattr(self, "linear_baseline", None) is None:
            self.linear_baseline = LinearFeatureBaseline(l2_reg=self.linear_baseline_l2)
        self._recorder: RolloutRecorder | None = None
        self._current_rollout: StoredRollout | None = None
        # (rollout, observations, values, advantages, returns) of the stored rollouts, for the running update
        self._replayed: list[tuple[StoredRollout, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []

    def _make_recorder(self) -> RolloutRecorder:
        obs_space = self.observation_space
        obs_shape = obs_space.shape if obs_space.shape else (1,)
        assert obs_space.dtype is not None
        action_dim = int(np.prod(self.action_space.shape)) if self.action_space.shape else 1
        return RolloutRecorder(self.n_steps, self.n_envs, tuple(obs_shape), np.dtype(obs_space.dtype), action_dim)

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        reset = reset_num_timesteps or self._last_obs is None
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        vec_normalize = self.get_vec_normalize_env()
        if reset or self._last_original_obs is None or self._episode_timesteps is None:
            self._last_original_obs = vec_normalize.get_original_obs() if vec_normalize is not None else self._last_obs  # type: ignore[assignment]
            self._episode_timesteps = np.zeros(self.n_envs, dtype=np.int64)
        return result

    # ------------------------------------------------------------------ rollouts
    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,
        n_rollout_steps: int,
    ) -> bool:
        """SB3's rollout collection, plus a raw record of the rollout for the replay memory / linear baseline."""
        assert self._last_obs is not None, "No previous observation was provided"
        self.policy.set_training_mode(False)
        n_steps = 0
        rollout_buffer.reset()
        vec_normalize = self.get_vec_normalize_env()
        recorder = None
        if self._needs_rollout_record:
            if self._recorder is None or self._recorder.n_envs != env.num_envs:
                self._recorder = self._make_recorder()
            recorder = self._recorder
            recorder.reset()
        episode_timesteps = self._episode_timesteps
        assert episode_timesteps is not None
        is_box = isinstance(self.action_space, spaces.Box)
        is_discrete = isinstance(self.action_space, spaces.Discrete)
        if self.use_sde:
            self.policy.reset_noise(env.num_envs)

        callback.on_rollout_start()

        while n_steps < n_rollout_steps:
            if self.use_sde and self.sde_sample_freq > 0 and n_steps % self.sde_sample_freq == 0:
                self.policy.reset_noise(env.num_envs)

            with th.no_grad():
                obs_tensor = obs_as_tensor(self._last_obs, self.device)  # type: ignore[arg-type]
                actions_t, values, log_probs = self.policy(obs_tensor)
            actions = actions_t.cpu().numpy()
            clipped_actions = actions
            if is_box:
                if self.policy.squash_output:
                    clipped_actions = self.policy.unscale_action(clipped_actions)
                else:
                    clipped_actions = np.clip(actions, self.action_space.low, self.action_space.high)  # type: ignore[attr-defined]

            new_obs, rewards, dones, infos = env.step(clipped_actions)
            self.num_timesteps += env.num_envs

            callback.update_locals(locals())
            if not callback.on_step():
                return False

            self._update_info_buffer(infos, dones)
            n_steps += 1
            if is_discrete:
                actions = actions.reshape(-1, 1)

            if recorder is not None:
                raw_rewards = vec_normalize.get_original_reward() if vec_normalize is not None else rewards
                recorder.add(
                    self._last_original_obs,  # type: ignore[arg-type]
                    actions,
                    log_probs.cpu().numpy(),
                    raw_rewards,
                    self._last_episode_starts,  # type: ignore[arg-type]
                    episode_timesteps,
                )
            episode_timesteps += 1

            for idx in np.flatnonzero(dones):
                info = infos[idx]
                terminal_obs = info.get("terminal_observation")
                if terminal_obs is not None and info.get("TimeLimit.truncated", False):
                    if recorder is not None:
                        raw_terminal = (
                            vec_normalize.unnormalize_obs(terminal_obs) if vec_normalize is not None else terminal_obs
                        )
                        recorder.add_truncation(int(idx), np.asarray(raw_terminal), int(episode_timesteps[idx]))
                    # Time-limit truncation: bootstrap with the value function (SB3 issue #633)
                    terminal_obs_t = self.policy.obs_to_tensor(terminal_obs)[0]
                    with th.no_grad():
                        terminal_value = self.policy.predict_values(terminal_obs_t)[0]  # type: ignore[arg-type]
                    rewards[idx] += self.gamma * terminal_value
                episode_timesteps[idx] = 0

            rollout_buffer.add(
                self._last_obs,  # type: ignore[arg-type]
                actions,
                rewards,
                self._last_episode_starts,  # type: ignore[arg-type]
                values,
                log_probs,
            )
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_original_obs = vec_normalize.get_original_obs() if vec_normalize is not None else new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones

        with th.no_grad():
            values = self.policy.predict_values(obs_as_tensor(new_obs, self.device))  # type: ignore[arg-type]
        rollout_buffer.compute_returns_and_advantage(last_values=values, dones=dones)
        if recorder is not None:
            self._current_rollout = recorder.finish(self._last_original_obs, dones, episode_timesteps)  # type: ignore[arg-type]

        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    # ------------------------------------------------------------------ update
    def train(self) -> None:
        """One TRPOPlus update: advantages, policy step (gradient, CG, line search), value baseline, memory."""
        start = time.perf_counter()
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        self._update_target_kl()
        if self.value_baseline == "linear":
            self._write_linear_baseline_advantages()
        # Re-evaluate the stored rollouts once: the value function does not change before the critic fit
        replaying = self.replay_memory > 0 and self.rollout_memory
        self._replayed = [(r, *self._recompute(r)) for r in self.rollout_memory] if replaying else []  # type: ignore[union-attr]
        batch = self._policy_batch()
        line_search = self._update_policy(batch)
        value_loss, skipped_critic_steps = self._update_value_baseline()
        self._remember_current_rollout()
        self._replayed = []
        self._n_updates += 1
        self._log_update(batch, line_search, value_loss, skipped_critic_steps, time.perf_counter() - start)

    def _update_target_kl(self) -> None:
        """This update's trust-region radius, ``target_kl`` at the remaining progress (constant unless a schedule)."""
        schedule = self.target_kl
        value = float(schedule(self._current_progress_remaining) if callable(schedule) else schedule)
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(
                f"TRPOPlus hyperparameter `target_kl`: its schedule gave {value!r} at remaining progress "
                f"{self._current_progress_remaining:.4f}; it must give finite numbers >= 0"
            )
        self.current_target_kl = value

    def _value_function(self, observations: np.ndarray, timesteps: np.ndarray) -> np.ndarray:
        """Current value estimate on flat normalised observations (critic or linear baseline)."""
        if self.value_baseline == "linear":
            assert self.linear_baseline is not None
            return self.linear_baseline.predict(observations, timesteps)
        with th.no_grad():
            obs_tensor = self.policy.obs_to_tensor(observations)[0]
            return self.policy.predict_values(obs_tensor).cpu().numpy().reshape(-1)  # type: ignore[arg-type]

    def _recompute(self, rollout: StoredRollout) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        vec_normalize = self.get_vec_normalize_env()
        return recompute_advantages(
            rollout,
            self._value_function,
            gamma=self.gamma,
            gae_lambda=self.gae_lambda,
            normalize_obs=vec_normalize.normalize_obs if vec_normalize is not None else None,  # type: ignore[arg-type]
            normalize_reward=vec_normalize.normalize_reward
            if vec_normalize is not None and vec_normalize.norm_reward
            else None,
        )

    def _write_linear_baseline_advantages(self) -> None:
        """Replace the critic's values / advantages / returns of the current rollout by the linear baseline's."""
        assert self._current_rollout is not None
        _, values, advantages, returns = self._recompute(self._current_rollout)
        self.rollout_buffer.values[:] = values
        self.rollout_buffer.advantages[:] = advantages
        self.rollout_buffer.returns[:] = returns

    def _policy_batch(self) -> PolicyBatch:
        """Current rollout (as SB3 buffered it) followed by every replayed rollout, re-evaluated now."""
        current = next(self.rollout_buffer.get(batch_size=None))
        observations, actions = current.observations, current.actions
        sampling_log_prob, advantages = current.old_log_prob, current.advantages
        n_current = len(advantages)
        if self.replay_memory > 0 and self.rollout_memory:
            obs_list, act_list, logq_list, adv_list = [observations], [actions], [sampling_log_prob], [advantages]
            for rollout, flat_obs, _, rollout_adv, _ in self._replayed:
                obs_list.append(self.policy.obs_to_tensor(flat_obs)[0])  # type: ignore[arg-type]
                act_list.append(th.as_tensor(rollout.actions.reshape(-1, rollout.actions.shape[-1]), device=self.device))
                logq_list.append(th.as_tensor(rollout.log_probs.reshape(-1), device=self.device))
                adv_list.append(th.as_tensor(rollout_adv.reshape(-1), device=self.device))
            observations = th.cat(obs_list)  # type: ignore[arg-type]
            actions, sampling_log_prob, advantages = th.cat(act_list), th.cat(logq_list), th.cat(adv_list)
        if self.sub_sampling_factor > 1:
            k = self.sub_sampling_factor
            n_current = len(range(0, n_current, k))
            observations, actions = observations[::k], actions[::k]
            sampling_log_prob, advantages = sampling_log_prob[::k], advantages[::k]
        return PolicyBatch(observations, actions, sampling_log_prob, advantages, n_current)

    def _importance_weight_scale(self, log_prob: th.Tensor, batch: PolicyBatch) -> tuple[th.Tensor | None, float]:
        """Truncation factors of the replayed samples' weights ``pi_current / q`` and the weights' ESS (a fraction).

        The current rollout is on-policy by construction (weight 1).
        """
        if batch.n_replayed == 0:
            return None, 1.0
        rho, scale = importance_weights(log_prob.cpu().numpy(), batch.sampling_log_prob.cpu().numpy(), self.replay_is_clip)
        rho[: batch.n_current], scale[: batch.n_current] = 1.0, 1.0
        ess = effective_sample_size(rho * scale) / len(rho)
        return th.as_tensor(scale, dtype=th.float32, device=self.device), ess

    def _action_tensor(self, actions: th.Tensor) -> th.Tensor:
        return actions.long().flatten() if isinstance(self.action_space, spaces.Discrete) else actions

    def _update_policy(self, batch: PolicyBatch) -> LineSearchResult:
        """Natural-gradient step within the trust region (gradient, CG, step scaling, line search)."""
        actions = self._action_tensor(batch.actions)
        distribution = self.policy.get_distribution(batch.observations)
        # Anchor of the KL constraint and of the Fisher matrix: the current policy on all states
        anchor = detached_distribution(distribution)
        advantages, ess = self._step_advantages(batch, distribution.log_prob(actions).detach())
        return self._natural_gradient_step(
            batch, distribution, actions, advantages, anchor, self.current_target_kl, self._warm_start, ess
        )

    def _step_advantages(self, batch: PolicyBatch, log_prob: th.Tensor) -> tuple[th.Tensor, float]:
        """The batch's advantages as the surrogate weighs them (normalised, replayed ones truncated) and the ESS."""
        weight_scale, ess = self._importance_weight_scale(log_prob, batch)
        advantages = batch.advantages
        if self.normalize_advantage:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        if weight_scale is not None:
            advantages = advantages * weight_scale
        return advantages, ess

    def _natural_gradient_step(
        self,
        batch: PolicyBatch,
        distribution: Distribution,
        actions: th.Tensor,
        advantages: th.Tensor,
        anchor: Distribution,
        step_kl: float,
        warm_start: Callable[[th.Tensor], th.Tensor | None],
        ess: float,
    ) -> LineSearchResult:
        """One natural-gradient step from the current parameters.

        Gradient of the importance-weighted surrogate and Fisher matrix at ``distribution`` (the policy at the
        current parameters, with its graph), CG started from ``warm_start(gradient)``, a full step of quadratic
        KL ``step_kl``, and a line search that keeps the KL to ``anchor`` within ``current_target_kl``. Records the CG
        statistics, and the step for the next update's warm start.
        """
        log_prob = distribution.log_prob(actions)
        objective = (advantages * th.exp(log_prob - batch.sampling_log_prob)).mean()
        gradient = flat_gradient(objective, self._actor_params, retain_graph=self.fisher_sub_sampling == 1)
        fisher_distribution = distribution
        if self.fisher_sub_sampling > 1:
            fisher_distribution = self.policy.get_distribution(batch.observations[:: self.fisher_sub_sampling])
        fvp = fisher_vector_product(fisher_distribution, self._actor_params, damping=self.cg_damping)

        start = warm_start(gradient)
        cg = conjugate_gradient(
            fvp, gradient, x0=start, max_iter=self.cg_max_steps, warm_start_rescale=self.cg_warm_start_rescale
        )
        direction = cg.solution
        quadratic_form = cg.quadratic_form if cg.quadratic_form > 0 else float(th.dot(direction, fvp(direction)))
        full_step = math.sqrt(2.0 * step_kl / quadratic_form) * direction if quadratic_form > 0 else direction * math.nan

        def evaluate() -> tuple[float, float]:
            new_distribution = self.policy.get_distribution(batch.observations)
            new_log_prob = new_distribution.log_prob(actions)
            new_objective = (advantages * th.exp(new_log_prob - batch.sampling_log_prob)).mean()
            kl = kl_divergence(new_distribution, anchor).mean()
            return float(new_objective), float(kl)

        result = backtracking_line_search(
            self._actor_params, full_step, evaluate, float(objective.detach()), self.current_target_kl,
            self.line_search_shrinking_factor, self.line_search_max_iter,
        )  # fmt: skip
        self.previous_step = (result.coefficient * full_step).cpu().numpy() if result.accepted else None
        self._cg_stats = {
            "cg_iterations": cg.iterations,
            "cg_residual": cg.residual_norm,
            "cg_relative_residual": cg.residual_norm / max(float(th.linalg.vector_norm(gradient)), 1e-12),
            "step_gradient_cosine": _cosine(gradient, direction),
            "fisher_products": cg.matvecs + (0 if cg.quadratic_form > 0 else 1),
            "cg_warm_start_cosine": _cosine(start, direction) if start is not None else 0.0,
            "objective_before": float(objective.detach()),
            "replay_ess": ess,
        }
        return result

    def _warm_start(self, gradient: th.Tensor) -> th.Tensor | None:
        """Previous full step (thesis 5.3.2), or None at the first update / after a rejected line search."""
        if not self.cg_warm_start or self.previous_step is None or self.previous_step.shape != gradient.shape:
            return None
        return th.as_tensor(self.previous_step, dtype=gradient.dtype, device=gradient.device)

    def _update_value_baseline(self) -> tuple[float, int]:
        """Fit the critic (Adam epochs) or refit the linear baseline.

        :return: mean value loss and the number of critic steps skipped for non-finite gradients
        """
        if self.value_baseline == "linear":
            return self._fit_linear_baseline(), 0
        value_losses = []
        skipped = 0
        for _ in range(self.n_critic_updates):
            for observations, returns in self._critic_minibatches():
                values_pred = self.policy.predict_values(observations)
                value_loss = F.mse_loss(returns, values_pred.flatten())
                loss = value_loss.item()
                if not math.isfinite(loss):
                    # finite inputs and weights give finite gradients: a non-finite loss is the one way in
                    skipped += 1
                    continue
                self.policy.optimizer.zero_grad()
                value_loss.backward()
                # Actor parameters are moved by the trust-region step only
                for param in self._actor_params:
                    param.grad = None
                value_losses.append(loss)
                self.policy.optimizer.step()
        return (float(np.mean(value_losses)) if value_losses else math.nan), skipped

    def _critic_minibatches(self) -> Iterable[tuple[th.Tensor, th.Tensor]]:
        if not (self.replay_critic and self.rollout_memory and self.replay_memory > 0):
            for data in self.rollout_buffer.get(self.batch_size):
                yield data.observations, data.returns  # type: ignore[misc]
            return
        current = next(self.rollout_buffer.get(batch_size=None))
        obs_list, ret_list = [current.observations], [current.returns]
        for _, flat_obs, _, _, rollout_returns in self._replayed:
            obs_list.append(self.policy.obs_to_tensor(flat_obs)[0])  # type: ignore[arg-type]
            ret_list.append(th.as_tensor(rollout_returns.reshape(-1), device=self.device))
        observations, returns = th.cat(obs_list), th.cat(ret_list)  # type: ignore[arg-type]
        order = th.as_tensor(np.random.permutation(len(returns)), device=self.device)
        for start in range(0, len(returns), self.batch_size):
            idx = order[start : start + self.batch_size]
            yield observations[idx], returns[idx]

    def _fit_linear_baseline(self) -> float:
        assert self.linear_baseline is not None and self._current_rollout is not None
        buffer = self.rollout_buffer
        obs = buffer.observations.reshape(buffer.buffer_size * buffer.n_envs, -1)  # type: ignore[union-attr]
        timesteps = self._current_rollout.episode_timesteps.reshape(-1)
        returns = buffer.returns.reshape(-1)
        if self.replay_critic and self.replay_memory > 0:
            for rollout, flat_obs, _, _, rollout_returns in self._replayed:
                obs = np.concatenate([obs, flat_obs.reshape(len(flat_obs), -1)])
                timesteps = np.concatenate([timesteps, rollout.episode_timesteps.reshape(-1)])
                returns = np.concatenate([returns, rollout_returns.reshape(-1)])
        self.linear_baseline.fit(obs, timesteps, returns)
        return float(np.mean((self.linear_baseline.predict(obs, timesteps) - returns) ** 2))

    def _remember_current_rollout(self) -> None:
        if self.replay_memory > 0 and self._current_rollout is not None:
            assert self.rollout_memory is not None
            self.rollout_memory.append(self._current_rollout)
        self._current_rollout = None

    def _log_update(
        self, batch: PolicyBatch, line_search: LineSearchResult, value_loss: float, skipped_critic_steps: int, seconds: float
    ) -> None:
        stats = self._cg_stats
        record = self.logger.record
        record("train/policy_objective", line_search.objective if line_search.accepted else stats["objective_before"])
        record("train/value_loss", value_loss)
        record("train/kl_divergence_loss", line_search.kl)
        record("train/target_kl", self.current_target_kl)
        record(
            "train/explained_variance",
            explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten()),
        )
        record("train/is_line_search_success", float(line_search.accepted))
        if hasattr(self.policy, "log_std"):
            record("train/std", th.exp(self.policy.log_std).mean().item())  # type: ignore[operator]
        record("train/n_updates", self._n_updates, exclude="tensorboard")
        record("train/cg_iterations", stats["cg_iterations"])
        record("train/cg_residual", stats["cg_residual"])
        record("train/cg_relative_residual", stats["cg_relative_residual"])
        record("train/step_gradient_cosine", stats["step_gradient_cosine"])
        record("train/fisher_vector_products", stats["fisher_products"])
        record("train/cg_warm_start_cosine", stats["cg_warm_start_cosine"])
        record("train/line_search_steps", line_search.steps)
        record("train/step_size", line_search.coefficient)
        record("train/line_search_nonfinite", float(line_search.nonfinite))
        record("train/replay_samples", batch.n_replayed)
        record("train/replay_ess", stats["replay_ess"])
        record("train/critic_skipped_steps", skipped_critic_steps)
        record("train/update_time", seconds)

    # ------------------------------------------------------------------ learn / save / load
    def learn(
        self: SelfTRPOPlus,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "TRPOPlus",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfTRPOPlus:
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_actor_params", "_recorder", "_cg_stats", "_replayed"]

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
    ) -> None:
        """Save atomically (temporary file + rename). ``exclude=["rollout_memory"]`` leaves the replay memory out.

        The random generators' states are saved too, so that ``load`` + ``learn`` continues a run exactly.
        """
        self._rng_states = {
            "torch": th.get_rng_state(),
            "numpy": np.random.get_state(),
            "python": random.getstate(),
        }
        try:
            if isinstance(path, io.BufferedIOBase):
                super().save(path, exclude=exclude, include=include)
                return
            target = pathlib.Path(path)
            if target.suffix == "":
                target = target.with_suffix(".zip")
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
            os.close(fd)
            try:
                # mkstemp makes the file private (0600); give it the mode a plain open() would, as SB3's save does
                # (os.chmod, not os.fchmod, which Windows lacks before Python 3.13)
                umask = os.umask(0)
                os.umask(umask)
                os.chmod(tmp_name, 0o666 & ~umask)
                with open(tmp_name, "wb") as tmp_file:
                    super().save(tmp_file, exclude=exclude, include=include)  # type: ignore[arg-type]
                    tmp_file.flush()
                    os.fsync(tmp_file.fileno())
                os.replace(tmp_name, target)
            finally:
                if os.path.exists(tmp_name):
                    os.unlink(tmp_name)
        finally:
            self._rng_states = None

    @classmethod
    def load(  # type: ignore[override]
        cls: type[SelfTRPOPlus],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfTRPOPlus:
        """Load a model; restores the replay memory, the warm-start step and the random generators' states."""
        model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        states = model._rng_states
        if states:
            th.set_rng_state(states["torch"])
            np.random.set_state(states["numpy"])
            random.setstate(states["python"])
        model._rng_states = None
        if model._last_obs is None:
            model._last_original_obs = None
        return model


def _cosine(a: th.Tensor, b: th.Tensor) -> float:
    denominator = float(th.linalg.vector_norm(a) * th.linalg.vector_norm(b))
    return float(th.dot(a, b)) / denominator if denominator > 0 else 0.0
