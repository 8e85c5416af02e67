"""TRPOPlus: sb3-contrib's TRPO with generalized sample reuse, and the thesis' replay memory and warm-started
conjugate gradient (chapter 5.3) as options."""

from __future__ import annotations

import math
import random
import time
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from sb3_contrib import TRPO
from stable_baselines3.common.buffers import DictRolloutBuffer, RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import FloatSchedule, explained_variance
from stable_baselines3.common.vec_env import VecEnv

from sb3_trpo_plus.algorithm.baselines import LinearFeatureBaseline
from sb3_trpo_plus.algorithm.collection import SegmentCollection
from sb3_trpo_plus.algorithm.critic import Minibatch, buffer_minibatches, fit_critic, fit_linear_baseline, shuffled_minibatches
from sb3_trpo_plus.algorithm.generalized import ReuseSettings, fit_weighted_critic, generalized_batch
from sb3_trpo_plus.algorithm.hyperparameters import (
    HYPERPARAMETER_RULES,
    check_combinations,
    float_or_schedule,
    validate_hyperparameters,
)
from sb3_trpo_plus.algorithm.natural_gradient import detached_distribution
from sb3_trpo_plus.algorithm.projection import ProjectionSettings, projected_policy_step
from sb3_trpo_plus.algorithm.replay import (
    RolloutEvaluation,
    recompute_advantages,
)
from sb3_trpo_plus.algorithm.reuse import ReuseWeights, reuse_weights
from sb3_trpo_plus.algorithm.saving import SavedRun
from sb3_trpo_plus.algorithm.segment import (
    Segment,
    SegmentDictRolloutBuffer,
    SegmentRolloutBuffer,
)
from sb3_trpo_plus.algorithm.segment_pool import rollout_workers
from sb3_trpo_plus.algorithm.update import (
    NaturalGradientSettings,
    PolicyBatch,
    PolicyStep,
    UpdateTimings,
    ValueFit,
    actor_parameters,
    natural_gradient_step,
    no_warm_start,
    record_policy_step,
    replay_policy_batch,
    surrogate_advantages,
    warm_start_from,
)
from sb3_trpo_plus.common.arguments import ArgumentError, Rule, check_arguments

SelfTRPOPlus = TypeVar("SelfTRPOPlus", bound="TRPOPlus")


class TRPOPlus(SavedRun, SegmentCollection, TRPO):
    """
    Trust Region Policy Optimization with generalized sample reuse.

    TRPO: Schulman et al. (2015) https://arxiv.org/abs/1502.05477. ``sample_reuse="generalized"``: each update also
    learns from the last ``reuse_batches`` batches, importance-weighted, inside a trust region that accounts for
    their age (Queeney et al. 2021, GeTRPO); it measured ahead of plain TRPO over seven tasks (docs/results.md). The
    thesis' two proposals stay as options, measured and not recommended: P. Kovacs, *Learning of object grasping in a
    robotic system* (master's thesis, 2017), section 5.3: a replay memory of the last ``k`` rollouts (5.3.1) and CG
    warm-started with the previous update step (5.3.2, after Martens 2010). With ``sample_reuse="none"``,
    ``replay_memory=0``, ``cg_warm_start=False`` and ``value_baseline="critic"`` one update is sb3-contrib's TRPO
    update. See ``docs/algorithm.md``.
    Every argument is checked at construction (``HYPERPARAMETER_RULES``): a value of the wrong type or
    out of range raises ``ValueError`` naming the argument and the value.

    :param policy: The policy model to use (MlpPolicy, CnnPolicy, ...)
    :param env: The environment to learn from (if registered in Gymnasium, can be str;
        ``grasp_envs`` ids work once ``sb3_trpo_plus`` is imported, which registers them)
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
    :param rollout_buffer_class: Rollout buffer class (default: ``SegmentRolloutBuffer``, SB3's ``RolloutBuffer`` filled
        from a collected segment; ``SegmentDictRolloutBuffer`` for ``Dict`` observations)
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
    :param sample_reuse: ``"generalized"``: every update also learns from the last batches of earlier policies with a
        generalized trust region (GeTRPO, Queeney et al. 2021, https://arxiv.org/abs/2111.00072): batch weights by age
        that maximise the effective sample size (``reuse_batches``, ``reuse_max_batches``), off-policy GAE with
        truncated traces for the advantages and the critic's targets, a weighted surrogate, Fisher matrix and KL, and
        the radius ``target_kl / reuse_batches**2`` (``epsilon = sqrt(2 target_kl)`` scaled by ``1 / B``). Collect
        ``1 / B`` of the on-policy batch per update (``n_steps``): the same samples buy ``B`` times the updates.
        ``"none"``: on-policy (or the thesis' ``replay_memory``)
    :param reuse_batches: ``B``, how many fresh batches' worth of samples one generalized update weighs (GePPO: 2)
    :param reuse_max_batches: ``M_max``, the oldest batch a generalized update may reuse (GePPO: 10; ``B = 2`` then
        uses 4 batches weighted 0.4, 0.3, 0.2, 0.1)
    :param reuse_trace_clip: truncation of the importance ratios that carry off-policy GAE's traces (V-trace: 1)
    :param reuse_kl_vary: the generalized radius ``epsilon = sqrt(2 target_kl)`` less the weighted mean
        ``|pi_k / q - 1|`` the old batches already spent (GeTRPO's ``eps_vary``), instead of the ``1 / B`` scaling
    :param overlap_collection: the rollout workers collect the next segment while the learner updates (both run at
        once): each segment after the first (collected while the learner waits, as is the first after the pool's
        reset) is collected with the weights from before the last update, one update behind, and the
        generalized update treats it as off-policy data (importance ratios against the behaviour log-probabilities
        it recorded, off-policy GAE, the radius as for the stored batches). Needs ``sample_reuse="generalized"`` and
        an env that is a pool of rollout workers (``sb3_trpo_plus.rollouts``, bare or under one ``VecNormalize``)
    :param replay_is_clip: Truncate the importance weights ``pi_current / q`` of replayed samples at this
        value (``None``: no truncation). Their effective sample size is logged as ``train/replay_ess``.
    :param replay_critic: Also fit the critic on replayed rollouts (default: current rollout only, as the thesis)
    :param cg_warm_start: Start CG from the previous update's full parameter step (thesis 5.3.2), zero at the
        first update and after a rejected line search
    :param cg_warm_start_rescale: Rescale the warm start to its exact line minimiser
        ``(x0^T g / x0^T F x0) x0`` (free: it reuses the product the warm start needs anyway)
    :param covariance_kl: ``None``: one trust region on the whole KL, as TRPO. A number: a decoupled trust region
        (MPO's, Abdolmaleki et al. 2018) for a diagonal Gaussian policy: the KL of the mean stays within
        ``target_kl`` and the KL of the covariance (the log-std) within ``covariance_kl``, each half of the
        natural-gradient step scaled to its own radius, so that the exploration noise moves at its own pace
        (:func:`~sb3_trpo_plus.algorithm.update.decoupled_gaussian_kl`). Where generalized sample reuse narrows the
        mean's radius below ``target_kl``, the covariance's narrows by the same factor. With
        ``policy_update="projection"``: the covariance's radius of the projection (None: the mean's)
    :param policy_update: ``"natural_gradient"``: TRPO's step (CG, line search). ``"projection"``: the projected
        trust region of Otto et al. 2021 (https://arxiv.org/abs/2101.09207) for a diagonal Gaussian policy with a
        state-independent log-std: Adam epochs over minibatches, as PPO's, on the surrogate of the policy projected
        state by state into the trust region (the mean's part of the KL within the update's radius, the covariance's
        within ``covariance_kl``'s), a regression of the network to the projected policy, and the update's mean KL
        bounded by the two radii as TRPO's line search bounds it (:mod:`sb3_trpo_plus.algorithm.projection`). The CG
        settings do not apply; the line-search ones shrink a change whose KL is above the radii
    :param projection_epochs: ``policy_update="projection"``: passes over the update's batch
    :param projection_minibatches: ``policy_update="projection"``: minibatches per pass
    :param projection_learning_rate: ``policy_update="projection"``: the actor's Adam step size (the critic keeps
        ``learning_rate``)
    :param projection_regression: ``policy_update="projection"``: weight of ``KL(network || projected)`` in the loss
    :param projection_max_grad_norm: ``policy_update="projection"``: the actor's gradient clipped to this norm per
        step (as PPO's ``max_grad_norm``)
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
        sample_reuse: str = "none",
        reuse_batches: float = 2.0,
        reuse_max_batches: int = 10,
        reuse_trace_clip: float = 1.0,
        reuse_kl_vary: bool = False,
        overlap_collection: bool = False,
        replay_is_clip: float | None = None,
        replay_critic: bool = False,
        cg_warm_start: bool = False,
        cg_warm_start_rescale: bool = True,
        covariance_kl: float | None = None,
        policy_update: str = "natural_gradient",
        projection_epochs: int = 10,
        projection_minibatches: int = 32,
        projection_learning_rate: float = 3e-4,
        projection_regression: float = 1.0,
        projection_max_grad_norm: float = 0.5,
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
        arguments = dict(locals())  # every constructor argument, by name, before anything else is bound
        validate_hyperparameters(**{name: arguments[name] for name in HYPERPARAMETER_RULES})
        if env is not None and not isinstance(env, str) and normalize_advantage:
            n_envs = env.num_envs if isinstance(env, VecEnv) else 1
            if n_steps * n_envs <= 1:
                raise ArgumentError(f"TRPOPlus needs `n_steps * n_envs` > 1 to normalise advantages, got {n_steps} * {n_envs}")
        super().__init__(
            policy,
            env,
            learning_rate=float_or_schedule(learning_rate),
            n_steps=n_steps,
            batch_size=batch_size,
            gamma=gamma,
            cg_max_steps=cg_max_steps,
            cg_damping=cg_damping,
            line_search_shrinking_factor=line_search_shrinking_factor,
            line_search_max_iter=line_search_max_iter,
            n_critic_updates=n_critic_updates,
            gae_lambda=gae_lambda,
            use_sde=use_sde,
            sde_sample_freq=sde_sample_freq,
            rollout_buffer_class=rollout_buffer_class,
            rollout_buffer_kwargs=rollout_buffer_kwargs,
            normalize_advantage=normalize_advantage,
            target_kl=float_or_schedule(target_kl),  # type: ignore[arg-type]  # a schedule too (sb3-contrib's TRPO only stores it)
            sub_sampling_factor=sub_sampling_factor,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self.fisher_sub_sampling = int(fisher_sub_sampling)
        self.replay_memory = int(replay_memory)
        self.sample_reuse = sample_reuse
        self.reuse_batches = float(reuse_batches)
        self.reuse_max_batches = int(reuse_max_batches)
        self.reuse_trace_clip = float(reuse_trace_clip)
        self.reuse_kl_vary = reuse_kl_vary
        self.overlap_collection = overlap_collection
        self.replay_is_clip = None if replay_is_clip is None else float(replay_is_clip)
        self.replay_critic = replay_critic
        self.cg_warm_start = cg_warm_start
        self.cg_warm_start_rescale = cg_warm_start_rescale
        self.covariance_kl = None if covariance_kl is None else float(covariance_kl)
        self.policy_update = policy_update
        self.projection_epochs = int(projection_epochs)
        self.projection_minibatches = int(projection_minibatches)
        self.projection_learning_rate = float(projection_learning_rate)
        self.projection_regression = float(projection_regression)
        self.projection_max_grad_norm = float(projection_max_grad_norm)
        self.value_baseline = value_baseline
        self.linear_baseline_l2 = float(linear_baseline_l2)
        self._check_combinations({name: arguments[name] for name in _COMBINED})  # as the caller wrote them
        array_spaces = spaces.Box | spaces.Discrete | spaces.MultiDiscrete | spaces.MultiBinary
        if self._needs_rollout_record and not isinstance(self.observation_space, array_spaces):
            raise ArgumentError(
                "`replay_memory` > 0 and `value_baseline='linear'` need an array observation space, "
                f"got {type(self.observation_space).__name__}"
            )
        # State that survives save/load (see `_setup_model`, which keeps loaded values)
        self.rollout_memory: deque[Segment] | None = None
        self.linear_baseline: LinearFeatureBaseline | None = None
        self.previous_step: np.ndarray | None = None
        # beside SB3's _last_obs and _last_episode_starts: the step index of _last_obs in its episode, per env
        self._last_episode_timesteps: np.ndarray | None = None
        self._rng_states: dict[str, Any] | None = None
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------------ set-up
    @property
    def _needs_rollout_record(self) -> bool:
        return self.replay_memory > 0 or self.value_baseline == "linear" or self.sample_reuse == "generalized"

    @property
    def reuse(self) -> ReuseWeights | None:
        """The batch weights of ``sample_reuse="generalized"`` (None otherwise)."""
        if self.sample_reuse != "generalized":
            return None
        return reuse_weights(self.reuse_batches, self.reuse_max_batches)

    def _check_combinations(self, hyperparameters: dict[str, Any] | None = None) -> None:
        """Refuse hyperparameters that do not work together
        (:func:`~sb3_trpo_plus.algorithm.hyperparameters.check_combinations`; ``hyperparameters``: default, this
        model's), and ``overlap_collection`` on an env that is no pool of rollout
        workers: it collects on them while the learner updates. At construction, and again at ``learn``: SB3's
        ``load`` and ``set_env`` skip ``__init__``."""
        check_combinations(hyperparameters or {name: getattr(self, name) for name in _COMBINED})
        if self.overlap_collection and self.env is not None and rollout_workers(self.env) is None:
            raise ArgumentError(
                "TRPOPlus: overlap_collection=True collects on rollout workers while the learner updates; the env is "
                f"{type(self.env).__name__}, not a pool of sb3_trpo_plus.rollouts (bare or under one VecNormalize)"
            )

    def _setup_model(self) -> None:
        self._overlap_ordered = False  # a segment was ordered during the last update (overlap_collection)
        # None, or SB3's own classes in a model saved by version 0.1.0: the buffers that hold their segment
        if self.rollout_buffer_class in (None, RolloutBuffer, DictRolloutBuffer):
            dict_space = isinstance(self.observation_space, spaces.Dict)
            self.rollout_buffer_class = SegmentDictRolloutBuffer if dict_space else SegmentRolloutBuffer
        else:  # the buffer is built here, for the env's observations: a class for the other kind is named
            rules = _buffer_rules(self.observation_space)
            check_arguments("TRPOPlus", rules, {"rollout_buffer_class": self.rollout_buffer_class})
        super()._setup_model()
        self._update_target_kl()
        self._actor_params = actor_parameters(self.policy)
        projected = getattr(self, "policy_update", "natural_gradient") == "projection"  # older saves: TRPO's step
        if (getattr(self, "covariance_kl", None) is not None or projected) and not (
            isinstance(self.policy.action_dist, DiagGaussianDistribution) and self._actor_params[-1] is self.policy.log_std
        ):
            option = "policy_update='projection' projects" if projected else "covariance_kl decouples"
            raise ArgumentError(
                f"TRPOPlus: {option} the trust region of a diagonal Gaussian policy with a state-independent log-std; "
                f"this policy's action distribution is {type(self.policy.action_dist).__name__}"
            )
        self.projection_optimizer = (
            th.optim.Adam(self._actor_params, lr=self.projection_learning_rate, eps=1e-5) if projected else None
        )
        memory = getattr(self, "rollout_memory", None)
        reuse = self.reuse
        capacity = reuse.n_batches - 1 if reuse is not None else self.replay_memory
        self.rollout_memory = deque(memory or [], maxlen=max(capacity, 1))
        if self.value_baseline == "linear" and getattr(self, "linear_baseline", None) is None:
            self.linear_baseline = LinearFeatureBaseline(l2_reg=self.linear_baseline_l2)

    def _setup_learn(
        self,
        total_timesteps: int,
        callback: MaybeCallback = None,
        reset_num_timesteps: bool = True,
        tb_log_name: str = "run",
        progress_bar: bool = False,
    ) -> tuple[int, BaseCallback]:
        reset = reset_num_timesteps or self._last_obs is None
        self._check_combinations()  # again: SB3's load() sets the arguments it is given without __init__'s checks
        if reset:  # SB3 resets the env, which drops a segment ordered before
            self._overlap_ordered = False
        states, self._rng_states = self._rng_states, None
        if states and not reset_num_timesteps:  # resuming a loaded run: its generators continue where it was saved
            th.set_rng_state(states["torch"])
            np.random.set_state(states["numpy"])
            random.setstate(states["python"])
        result = super()._setup_learn(total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar)
        if reset or self._last_episode_timesteps is None:  # SB3 reset the env: every episode at its first step
            self._last_episode_timesteps = np.zeros(self.n_envs, dtype=np.int64)
        return result

    # ------------------------------------------------------------------ update
    def train(self) -> None:
        """One TRPOPlus update: advantages, policy step (gradient, CG, line search), value baseline, memory.

        Learns from the segment in the rollout buffer (``collect_rollouts`` filled it) and the replay memory's.
        """
        start = time.perf_counter()
        segment = self.rollout_buffer.segment  # type: ignore[attr-defined]
        if segment is None:
            raise RuntimeError("TRPOPlus.train: the rollout buffer holds no segment; collect_rollouts fills it")
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        self._update_target_kl()
        if self.value_baseline == "linear":
            self._write_linear_baseline_advantages(segment)
        reuse = self.reuse
        if reuse is not None:
            batch, policy_step, value_fit, (prepared, stepped) = self._generalized_update(segment, reuse)
        else:
            batch, policy_step, value_fit, (prepared, stepped) = self._replay_update(segment)
        self.previous_step = policy_step.applied_step  # the next update's CG warm start
        if self.replay_memory > 0 or (reuse is not None and reuse.n_batches > 1):
            assert self.rollout_memory is not None
            self.rollout_memory.append(segment)
        self._n_updates += 1
        end = time.perf_counter()
        timings = UpdateTimings(prepare=prepared - start, policy=stepped - prepared, value=end - stepped)
        self._log_update(batch, policy_step, value_fit, timings)

    def _generalized_update(
        self, segment: Segment, reuse: ReuseWeights
    ) -> tuple[PolicyBatch, PolicyStep, ValueFit, tuple[float, float]]:
        """GeTRPO's update: the fresh batch and the stored ones weighted by age, off-policy advantages, the generalized
        radius, the weighted critic fit (:mod:`sb3_trpo_plus.algorithm.generalized`). With ``overlap_collection`` the fresh
        segment is one update old and is evaluated as the stored ones."""
        settings = ReuseSettings(reuse, self.reuse_trace_clip, self.reuse_kl_vary)
        stored = list(reversed(self.rollout_memory or []))  # newest first
        if self.overlap_collection:
            current, stored = None, [segment, *stored]
        else:
            current = next(self.rollout_buffer.get(batch_size=None))
        reused = generalized_batch(
            self.policy,
            current,
            stored,
            self._reevaluate,
            settings,
            self.current_target_kl,
            self.action_tensor,
            self.sub_sampling_factor,
        )
        prepared = time.perf_counter()
        policy_step = self.update_policy(reused.batch, reused.radius)
        stepped = time.perf_counter()
        if reused.batch.n_replayed:
            value_fit = fit_weighted_critic(self.policy, reused, self.n_critic_updates, self.batch_size, self._critic_step)
        else:
            value_fit = self._update_value_baseline(segment, [])
        self.logger.record("train/reuse_batches", reused.n_batches)
        self.logger.record("train/reuse_radius", reused.radius)
        self.logger.record("train/reuse_offpolicy_tv", reused.offpolicy_tv)
        return reused.batch, policy_step, value_fit, (prepared, stepped)

    def _replay_update(self, segment: Segment) -> tuple[PolicyBatch, PolicyStep, ValueFit, tuple[float, float]]:
        """The thesis' update: the current rollout and the replay memory's (none without one), the stored rollouts
        evaluated once (the value function does not change before the critic's fit)."""
        replayed = self._reevaluate_memory()
        batch = self._policy_batch(replayed)
        prepared = time.perf_counter()
        policy_step = self.update_policy(batch)
        stepped = time.perf_counter()
        return batch, policy_step, self._update_value_baseline(segment, replayed), (prepared, stepped)

    def _update_target_kl(self) -> None:
        """This update's trust-region radius, ``target_kl`` at the remaining progress (constant unless a schedule)."""
        value = FloatSchedule(self.target_kl)(self._current_progress_remaining)
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
            return self.policy.predict_values(obs_tensor).cpu().numpy().reshape(-1)

    def _reevaluate(
        self, segment: Segment, trace_ratios: Callable[[np.ndarray], np.ndarray] | None = None
    ) -> RolloutEvaluation:
        """``segment`` under the current value function and ``VecNormalize`` statistics (off-policy GAE with
        ``trace_ratios``)."""
        vec_normalize = self.get_vec_normalize_env()
        return recompute_advantages(
            segment,
            self._value_function,
            gamma=self.gamma,
            gae_lambda=self.gae_lambda,
            normalize_obs=vec_normalize.normalize_obs if vec_normalize is not None else None,  # type: ignore[arg-type]
            normalize_reward=vec_normalize.normalize_reward
            if vec_normalize is not None and vec_normalize.norm_reward
            else None,
            trace_ratios=trace_ratios,
        )

    def _reevaluate_memory(self) -> list[RolloutEvaluation]:
        """Every stored rollout, re-evaluated now (none without a replay memory)."""
        if self.replay_memory == 0 or not self.rollout_memory:
            return []
        return [self._reevaluate(segment) for segment in self.rollout_memory]

    def _write_linear_baseline_advantages(self, segment: Segment) -> None:
        """Replace the critic's values / advantages / returns of the current segment by the linear baseline's."""
        evaluation = self._reevaluate(segment)
        self.rollout_buffer.values[:] = evaluation.values
        self.rollout_buffer.advantages[:] = evaluation.advantages
        self.rollout_buffer.returns[:] = evaluation.returns

    def _policy_batch(self, replayed: Sequence[RolloutEvaluation]) -> PolicyBatch:
        """Current rollout (as SB3 buffered it) followed by the replayed rollouts."""
        current = next(self.rollout_buffer.get(batch_size=None))
        return replay_policy_batch(current, replayed, self.policy, self.sub_sampling_factor)

    def _critic_step(self, value_loss: th.Tensor) -> float | None:
        """One Adam step of the critic on ``value_loss``; the actor's parameters move by the trust-region step only.
        A non-finite loss (finite inputs and weights give finite gradients: the one way in) is skipped: None."""
        loss = value_loss.item()
        if not math.isfinite(loss):
            return None
        self.policy.optimizer.zero_grad()
        value_loss.backward()
        for param in self._actor_params:
            param.grad = None
        self.policy.optimizer.step()
        return loss

    def action_tensor(self, actions: th.Tensor) -> th.Tensor:
        """The batch's actions as the policy's distribution takes them (indices for a ``Discrete`` space)."""
        return actions.long().flatten() if isinstance(self.action_space, spaces.Discrete) else actions

    def update_policy(self, batch: PolicyBatch, radius: float | None = None) -> PolicyStep:
        """The update's policy step: one natural-gradient step inside the trust region of ``radius`` (default
        ``current_target_kl``; :func:`~sb3_trpo_plus.algorithm.update.natural_gradient_step`), CG warm-started from the
        previous update's step with ``cg_warm_start``; the batch's sample weights, where it has them, weigh the surrogate, the
        Fisher matrix and the KL. A subclass that changes the policy step overrides this method and calls the public
        functions of :mod:`sb3_trpo_plus.algorithm.update`."""
        radius = self.current_target_kl if radius is None else radius
        actions = self.action_tensor(batch.actions)
        if self.projection_optimizer is not None:  # policy_update="projection"
            return projected_policy_step(
                self.policy,
                self._actor_params,
                self.projection_optimizer,
                batch,
                actions,
                mean_radius=radius,
                covariance_radius=self.covariance_radius(radius) or radius,
                normalize_advantage=self.normalize_advantage,
                replay_is_clip=self.replay_is_clip,
                settings=self.projection_settings,
                record=self.logger.record,
            )
        distribution = self.policy.get_distribution(batch.observations)
        # Anchor of the KL constraint and of the Fisher matrix: the current policy on all states
        anchor = detached_distribution(distribution)
        surrogate = surrogate_advantages(
            batch, distribution.log_prob(actions).detach(), self.normalize_advantage, self.replay_is_clip
        )
        return natural_gradient_step(
            self.policy,
            self._actor_params,
            batch,
            actions,
            distribution,
            surrogate,
            anchor,
            step_kl=radius,
            max_kl=radius,
            settings=self.natural_gradient_settings,
            warm_start=warm_start_from(self.previous_step) if self.cg_warm_start else no_warm_start,
            covariance_kl=self.covariance_radius(radius),
        )

    def covariance_radius(self, radius: float) -> float | None:
        """The covariance's radius of a step whose mean's radius is ``radius`` (``covariance_kl``): it narrows with
        the mean's, as generalized reuse narrows that below ``target_kl``. None: one trust region."""
        covariance_kl = getattr(self, "covariance_kl", None)  # None in a model saved before the option existed
        return None if covariance_kl is None else covariance_kl * radius / self.current_target_kl

    @property
    def projection_settings(self) -> ProjectionSettings:
        """This model's ``projection_*`` and line-search hyperparameters, as
        :func:`~sb3_trpo_plus.algorithm.projection.projected_policy_step` takes them."""
        return ProjectionSettings(
            epochs=self.projection_epochs,
            minibatches=self.projection_minibatches,
            regression=self.projection_regression,
            max_grad_norm=self.projection_max_grad_norm,
            line_search_shrinking_factor=self.line_search_shrinking_factor,
            line_search_max_iter=self.line_search_max_iter,
        )

    @property
    def natural_gradient_settings(self) -> NaturalGradientSettings:
        """This model's CG and line-search hyperparameters, as :func:`~sb3_trpo_plus.algorithm.update.natural_gradient_step`
        takes them."""
        return NaturalGradientSettings(
            cg_max_steps=self.cg_max_steps,
            cg_damping=self.cg_damping,
            cg_warm_start_rescale=self.cg_warm_start_rescale,
            fisher_sub_sampling=self.fisher_sub_sampling,
            line_search_shrinking_factor=self.line_search_shrinking_factor,
            line_search_max_iter=self.line_search_max_iter,
        )

    def _update_value_baseline(self, segment: Segment, replayed: Sequence[RolloutEvaluation]) -> ValueFit:
        """Fit the critic (Adam epochs) or refit the linear baseline; ``replayed`` only with ``replay_critic``."""
        if self.value_baseline == "linear":
            assert self.linear_baseline is not None
            used = replayed if self.replay_critic else ()
            loss = fit_linear_baseline(self.linear_baseline, self.rollout_buffer, segment, used)
            return ValueFit(loss=loss, skipped_steps=0)
        return fit_critic(self.policy, lambda: self._critic_minibatches(replayed), self.n_critic_updates, self._critic_step)

    def _critic_minibatches(self, replayed: Sequence[RolloutEvaluation]) -> Iterable[Minibatch]:
        """One epoch's minibatches: the current rollout's, with ``replay_critic`` the replayed ones' too."""
        if not (self.replay_critic and replayed):
            return buffer_minibatches(self.rollout_buffer, self.batch_size, self.device)
        current = next(self.rollout_buffer.get(batch_size=None))
        stored = [self.policy.obs_to_tensor(e.observations)[0] for e in replayed]  # flat arrays: tensors
        observations = th.cat([current.observations, *stored])  # type: ignore[list-item]
        returns = th.cat([current.returns, *(th.as_tensor(e.returns.reshape(-1), device=self.device) for e in replayed)])
        return shuffled_minibatches(observations, returns, self.batch_size)

    def _log_update(self, batch: PolicyBatch, step: PolicyStep, value_fit: ValueFit, timings: UpdateTimings) -> None:
        record = self.logger.record
        record_policy_step(record, batch, step)
        record("train/value_loss", value_fit.loss)
        record("train/target_kl", self.current_target_kl)
        record(
            "train/explained_variance",
            explained_variance(self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten()),
        )
        if hasattr(self.policy, "log_std"):
            record("train/std", th.exp(self.policy.log_std).mean().item())
        record("train/n_updates", self._n_updates, exclude="tensorboard")
        record("train/critic_skipped_steps", value_fit.skipped_steps)
        record("train/update_time", timings.prepare + timings.policy + timings.value)
        record("train/prepare_time", timings.prepare)
        record("train/policy_step_time", timings.policy)
        record("train/value_fit_time", timings.value)


_COMBINED = (
    "sample_reuse",
    "replay_memory",
    "value_baseline",
    "replay_critic",
    "replay_is_clip",
    "reuse_batches",
    "reuse_max_batches",
    "overlap_collection",
    "policy_update",
    "cg_warm_start",
    "fisher_sub_sampling",
    "cg_max_steps",
    "cg_damping",
    "projection_epochs",
    "projection_minibatches",
    "projection_learning_rate",
    "projection_regression",
    "projection_max_grad_norm",
)
"""The hyperparameters :func:`~sb3_trpo_plus.algorithm.hyperparameters.check_combinations` reads."""


def _buffer_rules(observation_space: spaces.Space) -> dict[str, Rule]:
    """``rollout_buffer_class`` for the env's observations: the ``Dict`` buffer for ``Dict`` observations only."""
    dict_space = isinstance(observation_space, spaces.Dict)
    fits = SegmentDictRolloutBuffer if dict_space else SegmentRolloutBuffer
    space = f"the env's {type(observation_space).__name__} observation space"

    def accepts(value: type | None) -> bool:
        return value is None or issubclass(value, DictRolloutBuffer) == dict_space

    return {"rollout_buffer_class": Rule(accepts, f"None or a subclass of {fits.__name__} for {space}")}
