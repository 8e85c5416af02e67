"""The run's half of :class:`~sb3_trpo_plus.TRPOPlus` (a mixin before sb3-contrib's ``TRPO``): ``learn`` that names
a rollout worker process that died, atomic saves that carry the random generators' states, and loads that name a
damaged file and read the saves of older versions."""

from __future__ import annotations

import io
import pathlib
import random
from collections import deque
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
import torch as th
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback

from sb3_trpo_plus.algorithm.replay import StoredRollout
from sb3_trpo_plus.common.persistence import atomic_write

if TYPE_CHECKING:
    from sb3_contrib import TRPO

    _Algorithm = TRPO
else:
    _Algorithm = object

SelfRun = TypeVar("SelfRun", bound="SavedRun")


class SavedRun(_Algorithm):
    """``learn``, ``save`` and ``load`` of :class:`~sb3_trpo_plus.TRPOPlus`."""

    _rng_states: dict[str, Any] | None

    def learn(
        self: SelfRun,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "TRPOPlus",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfRun:
        """SB3's ``learn``. A rollout worker process that dies raises
        :class:`~sb3_trpo_plus.algorithm.worker_failures.RolloutWorkerError` naming the worker and its env; the weights
        are those of the last completed update (an update starts only once its rollout is complete).
        Ctrl-C: see :class:`~sb3_trpo_plus.application.callbacks.SaveOnInterrupt`.
        """
        from sb3_trpo_plus.algorithm.worker_failures import subprocess_env_ids, worker_failure

        env_ids = subprocess_env_ids(self.env)  # asked now: a dead worker cannot say which env it stepped
        try:
            return super().learn(
                total_timesteps=total_timesteps,
                callback=callback,
                log_interval=log_interval,
                tb_log_name=tb_log_name,
                reset_num_timesteps=reset_num_timesteps,
                progress_bar=progress_bar,
            )
        except (EOFError, ConnectionError) as error:
            failure = worker_failure(self.env, error, env_ids)
            if failure is None:
                raise
            raise failure from error

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_actor_params", "projection_optimizer"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, tensors = super()._get_torch_save_params()
        if getattr(self, "projection_optimizer", None) is not None:  # policy_update="projection": its Adam moments
            state_dicts = [*state_dicts, "projection_optimizer"]
        return state_dicts, tensors

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
    ) -> None:
        """Save atomically (temporary file + rename). ``exclude=["rollout_memory"]`` leaves the replay memory out.

        The random generators' states are saved too, so that ``load`` + ``learn`` continues a run exactly.
        """
        pending = self._rng_states  # a loaded run not resumed yet: its own states, not this program's
        self._rng_states = pending or {
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
            atomic_write(target, lambda file: super(SavedRun, self).save(file, exclude=exclude, include=include))
        finally:
            self._rng_states = pending

    @classmethod
    def load(
        cls: type[SelfRun],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfRun:
        """Load a model with its replay memory, warm-start step and random generators' states (restored when
        ``learn(..., reset_num_timesteps=False)`` resumes the run, not before).

        Unpickles parts of the zip: load only files you trust (``sb3_trpo_plus.application.agents`` reads a policy as data).
        A truncated or corrupted file raises ``ValueError`` naming it and what failed.
        """
        try:
            model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        except OSError:  # a missing or unreadable file is no damaged one
            raise
        except Exception as error:  # whatever a damaged zip's unpickling or decoding raises
            where = path if isinstance(path, str | pathlib.Path) else "the model stream"
            cause = f"{type(error).__name__}: {error}"
            raise ValueError(f"{where}: cannot load the model (truncated or corrupted?): {cause}") from error
        # the run's random generators' states stay with the model until learn(reset_num_timesteps=False) resumes it
        # (_setup_learn); until then the program's generators are as SB3's load leaves them (seeded with model.seed)
        _upgrade_from_0_1(model)
        return model


def _upgrade_from_0_1(model: Any) -> None:
    """A model saved by version 0.1.0: its replay records as segments, its episode step counters renamed."""
    state = model.__dict__
    if "_episode_timesteps" in state:
        state["_last_episode_timesteps"] = state.pop("_episode_timesteps")
    state.pop("_last_original_obs", None)
    memory = model.rollout_memory
    if memory and any(isinstance(record, StoredRollout) for record in memory):
        model.rollout_memory = deque(
            (record.to_segment() if isinstance(record, StoredRollout) else record for record in memory),
            maxlen=memory.maxlen,
        )
