"""``trpo-plus train`` as an rl-zoo3 experiment: one :class:`ExperimentManager` subclass holds everything the command
adds to rl-zoo3's training (:func:`sb3_trpo_plus.application.rl_zoo.train` runs rl-zoo3's own ``train`` with it).

What the subclass adds, each as an override of the rl-zoo3 method it concerns:

- ``create_envs``: the training envs come from a ``make_vec_env``-like factory where one is given (the batched
  engine, a pool of rollout workers: :mod:`sb3_trpo_plus.application.zoo`; a recipe's ``rollout_workers`` chooses the pool
  unless the command line chose); evaluation envs get the YAML's ``env_wrapper`` without its training aids
  (:func:`sb3_trpo_plus.application.zoo.evaluation_wrappers`);
- ``learn``: TensorBoard runs under ``<tensorboard-log>/<env>/seed<seed>/<Algorithm>_<n>``, and Ctrl-C stops at the
  next env step (not inside an update) so that the model is saved in the state of its last complete update;
- ``save_trained_model``: the VecNormalize statistics are written atomically;
- ``_maybe_normalize`` / ``_load_pretrained_agent``: resuming from a damaged ``<ENV>.zip`` or ``vecnormalize.pkl``
  raises :class:`~sb3_trpo_plus.application.agents.RunFileError` naming the file.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

from rl_zoo3.exp_manager import ExperimentManager

TrainingEnvs = Callable[..., Any]
"""A factory of an rl-zoo3 run's training envs: ``(env_id, *, n_envs, seed, env_kwargs, monitor_dir, wrapper_class,
monitor_kwargs)`` -> VecEnv, the arguments as rl-zoo3 would give ``make_vec_env`` (``wrapper_class``: the YAML's
``env_wrapper``; ``monitor_dir``: None where rl-zoo3 logs no episodes)."""
RecipeWorkers = Callable[[str], TrainingEnvs]
"""What a recipe's ``rollout_workers: BACKEND:N`` means for one command line: the factory of the pool's training envs
(or an error naming the conflict with the command line's own choice)."""


class TRPOPlusExperimentManager(ExperimentManager):
    """rl-zoo3's experiment manager with the training habits of ``trpo-plus train`` (module docstring).

    ``training_envs`` (a class attribute, set by :meth:`with_training_envs`): the factory of the training envs, None
    for rl-zoo3's own ``make_vec_env``; ``recipe_workers``: the factory for a recipe's ``rollout_workers``, which
    replaces ``training_envs`` (None: a recipe with ``rollout_workers`` is refused).
    """

    training_envs: TrainingEnvs | None = None
    recipe_workers: RecipeWorkers | None = None

    @classmethod
    def with_training_envs(
        cls, training_envs: TrainingEnvs | None, recipe_workers: RecipeWorkers | None = None
    ) -> type[TRPOPlusExperimentManager]:
        """This manager with its training envs built by ``training_envs``, or by ``recipe_workers`` where the recipe
        names rollout workers (rl-zoo3 constructs the manager itself, so the factories travel on a subclass)."""
        attributes = {
            "training_envs": staticmethod(training_envs) if training_envs else None,
            "recipe_workers": staticmethod(recipe_workers) if recipe_workers else None,
        }
        return type(cls.__name__, (cls,), attributes)

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]) -> Any:
        from rl_zoo3.utils import get_wrapper_class

        from sb3_trpo_plus.application.zoo import evaluation_wrappers

        workers = hyperparams.pop("rollout_workers", None)  # ours, not the constructor's
        if workers is not None:
            if self.recipe_workers is None:
                raise ValueError(f"rollout_workers={workers!r}: this command collects with its own envs")
            self.training_envs = self.recipe_workers(workers)
        self.evaluation_env_wrapper = get_wrapper_class({"env_wrapper": evaluation_wrappers(hyperparams.get("env_wrapper"))})
        return super()._preprocess_hyperparams(hyperparams)

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> Any:
        if eval_env:
            training_wrapper, self.env_wrapper = self.env_wrapper, getattr(self, "evaluation_env_wrapper", None)
            try:
                return super().create_envs(n_envs, eval_env, no_log)
            finally:
                self.env_wrapper = training_wrapper
        if self.training_envs is None:
            return super().create_envs(n_envs, eval_env, no_log)
        # rl-zoo3 hands make_vec_env's arguments to vec_env_cls as the env count: the factory builds the envs there,
        # and rl-zoo3 adds its VecEnv wrappers, VecNormalize and frame stacking as for its own envs
        vec_env_class, self.vec_env_class = self.vec_env_class, self._training_vec_env(no_log)  # type: ignore[assignment]
        try:
            return super().create_envs(n_envs, eval_env, no_log)
        finally:
            self.vec_env_class = vec_env_class

    def _training_vec_env(self, no_log: bool) -> Callable[..., Any]:
        assert self.training_envs is not None
        factory = self.training_envs

        def build(env_fns: Sequence[Callable[[], Any]], **_: Any) -> Any:
            return factory(
                self.env_name.gym_id,
                n_envs=len(env_fns),
                seed=self.seed,
                env_kwargs=self.env_kwargs,
                monitor_dir=None if no_log else self.save_path,
                wrapper_class=self.env_wrapper,
                monitor_kwargs=self.monitor_kwargs,
            )

        return build

    def learn(self, model: Any) -> None:
        from sb3_trpo_plus.application.callbacks import StopTrainingOnInterrupt

        if model.tensorboard_log:  # a plain string attribute: the model stays picklable for checkpoints
            model.tensorboard_log = os.path.join(model.tensorboard_log, f"seed{self.seed}")
        stop = StopTrainingOnInterrupt(verbose=1)
        self.callbacks.append(stop)  # last: callbacks[0] is the one rl-zoo3 closes after an interrupt
        try:
            super().learn(model)
        finally:
            self.callbacks.remove(stop)
        if stop.interrupted:
            print("trpo-plus train: interrupted, saving the model, its replay memory and the VecNormalize statistics")

    def save_trained_model(self, model: Any) -> None:
        from sb3_trpo_plus.application.callbacks import save_vec_normalize

        normalize, self.normalize = self.normalize, False
        try:
            super().save_trained_model(model)
        finally:
            self.normalize = normalize
        if normalize:
            save_vec_normalize(model.get_vec_normalize_env(), os.path.join(self.params_path, "vecnormalize.pkl"))

    def _maybe_normalize(self, env: Any, eval_env: bool) -> Any:
        from sb3_trpo_plus.application.agents import load_trusted_file

        path = os.path.join(os.path.dirname(self.trained_agent), self.env_name, "vecnormalize.pkl")  # rl-zoo3's choice
        if not os.path.exists(path):
            return super()._maybe_normalize(env, eval_env)
        return load_trusted_file(lambda: super(TRPOPlusExperimentManager, self)._maybe_normalize(env, eval_env), path)

    def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: Any) -> Any:
        from sb3_trpo_plus.application.agents import load_trusted_file

        return load_trusted_file(
            lambda: super(TRPOPlusExperimentManager, self)._load_pretrained_agent(hyperparams, env), self.trained_agent
        )
