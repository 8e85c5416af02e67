"""Callbacks: per-term reward logging and hyperparameters in TensorBoard, every training episode's return and success;
Ctrl-C that stops cleanly and saves."""

from __future__ import annotations

import pickle
import signal
import threading
from collections import defaultdict
from pathlib import Path
from types import FrameType
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import HParam
from stable_baselines3.common.vec_env import VecNormalize

HPARAM_NAMES = (
    "learning_rate",
    "n_steps",
    "batch_size",
    "gamma",
    "gae_lambda",
    "target_kl",
    "cg_max_steps",
    "cg_damping",
    "n_critic_updates",
    "replay_memory",
    "replay_is_clip",
    "cg_warm_start",
    "cg_warm_start_rescale",
    "value_baseline",
    "normalize_advantage",
    "use_sde",
    "sub_sampling_factor",
    "seed",
    "n_envs",
    "sample_reuse",
    "reuse_batches",
    "reuse_max_batches",
    "reuse_trace_clip",
    "reuse_kl_vary",
    "overlap_collection",
)


class RewardTermsCallback(BaseCallback):
    """Log the mean of every ``info["reward_<term>"]`` over each rollout as ``rollout/reward_<term>``.

    Also writes the algorithm's hyperparameters to TensorBoard's HParams tab at the start of training,
    so one sees which reward term moves and under which settings.
    """

    def __init__(self, verbose: int = 0):
        super().__init__(verbose)
        self._sums: dict[str, float] = defaultdict(float)
        self._counts: dict[str, int] = defaultdict(int)

    def _on_training_start(self) -> None:
        hparams: dict[str, Any] = {"algorithm": type(self.model).__name__}
        for name in HPARAM_NAMES:
            value = getattr(self.model, name, None)
            if isinstance(value, bool | int | float | str):
                hparams[name] = value
        metrics = {"rollout/ep_rew_mean": 0.0, "rollout/success_rate": 0.0}
        self.logger.record("hparams", HParam(hparams, metrics), exclude=("stdout", "log", "json", "csv"))

    def _on_rollout_start(self) -> None:
        self._sums.clear()
        self._counts.clear()

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            for key, value in info.items():
                if key.startswith("reward_"):
                    self._sums[key] += float(value)
                    self._counts[key] += 1
        return True

    def _on_rollout_end(self) -> None:
        for key, total in self._sums.items():
            self.logger.record(f"rollout/{key}", total / max(self._counts[key], 1))


class EpisodeStats(BaseCallback):
    """Collect ``(return, success, length)`` of every finished training episode in ``episodes``.

    Reads SB3's ``Monitor`` record (``info["episode"]``) and the env's success flag ``info["is_success"]`` at the
    episode's last step (False where the env gives none).
    """

    def __init__(self, verbose: int = 0):
        super().__init__(verbose)
        self.episodes: list[tuple[float, bool, int]] = []

    def _on_step(self) -> bool:
        for info, done in zip(self.locals["infos"], self.locals["dones"], strict=True):
            if done and "episode" in info:
                episode = info["episode"]
                self.episodes.append((float(episode["r"]), bool(info.get("is_success", False)), int(episode["l"])))
        return True


def save_vec_normalize(vec_normalize: VecNormalize, path: str | Path) -> None:
    """``VecNormalize.save``, atomically: a temporary file renamed over ``path`` once written, so that a crash or a
    full disk leaves the previous statistics intact (``VecNormalize.save`` writes in place)."""
    from sb3_trpo_plus.common.persistence import atomic_write

    # what VecNormalize.save writes (its __getstate__ drops the venv)
    atomic_write(path, lambda file: pickle.dump(vec_normalize, file))


class StopTrainingOnInterrupt(BaseCallback):
    """Ctrl-C (SIGINT) stops ``learn`` at the next environment step instead of wherever it falls.

    A ``KeyboardInterrupt`` raised in the middle of an update would leave the policy between two line-search
    trials and the critic between two minibatches. With this callback the first Ctrl-C only sets a flag: the
    running step or update completes, then ``learn`` returns as after its last step (the partial rollout is
    dropped), so the model is in the state of its last complete update and can be saved. A second Ctrl-C
    interrupts at once (the handler in place before training is restored after the first). Only in the main
    thread, where Python delivers signals, and only where the process handles SIGINT: a process that ignores it
    (started with ``nohup`` or as a background job ``&``) keeps ignoring it.
    """

    def __init__(self, verbose: int = 0):
        super().__init__(verbose)
        self.interrupted = False
        self._previous_handler: Any = None
        self._installed = False

    def _on_training_start(self) -> None:
        self.interrupted = False
        ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        if threading.current_thread() is threading.main_thread() and not ignored:
            self._previous_handler = signal.signal(signal.SIGINT, self._on_sigint)
            self._installed = True

    def _on_sigint(self, signum: int, frame: FrameType | None) -> None:
        self.interrupted = True
        self._restore_handler()
        if self.verbose:
            print("Ctrl-C: stopping after the current step (Ctrl-C again to interrupt at once)")

    def _restore_handler(self) -> None:
        if self._installed:
            signal.signal(signal.SIGINT, self._previous_handler)
            self._installed = False

    def _on_step(self) -> bool:
        return not self.interrupted

    def _on_training_end(self) -> None:
        self._restore_handler()


class SaveOnInterrupt(StopTrainingOnInterrupt):
    """Ctrl-C stops ``learn`` cleanly (see :class:`StopTrainingOnInterrupt`), saves a checkpoint, then raises
    ``KeyboardInterrupt`` from ``learn`` (``reraise=False``: ``learn`` returns instead).

    The checkpoint: ``<save_path>/<name_prefix>.zip`` (the model; a TRPOPlus zip holds the replay memory and the
    random generators' states) and, where the env is normalised, ``<save_path>/<name_prefix>_vecnormalize.pkl``,
    both written atomically. Resume with ``TRPOPlus.load(zip, env=VecNormalize.load(pkl, venv))`` and
    ``learn(..., reset_num_timesteps=False)``.

    :param save_path: folder of the checkpoint
    :param name_prefix: file name stem
    :param reraise: raise ``KeyboardInterrupt`` once saved, as an uncaught Ctrl-C would
    """

    def __init__(self, save_path: str | Path, name_prefix: str = "interrupted", reraise: bool = True, verbose: int = 0):
        super().__init__(verbose)
        self.save_path = Path(save_path)
        self.name_prefix = name_prefix
        self.reraise = reraise

    @property
    def model_path(self) -> Path:
        return self.save_path / f"{self.name_prefix}.zip"

    @property
    def vec_normalize_path(self) -> Path:
        return self.save_path / f"{self.name_prefix}_vecnormalize.pkl"

    def _on_training_end(self) -> None:
        super()._on_training_end()
        if not self.interrupted:
            return
        self.model.save(self.model_path)
        vec_normalize = self.model.get_vec_normalize_env()
        if vec_normalize is not None:
            save_vec_normalize(vec_normalize, self.vec_normalize_path)
        if self.verbose:
            print(f"Ctrl-C: saved {self.model_path}")
        if self.reraise:
            raise KeyboardInterrupt
