"""Callbacks: per-term reward logging and hyperparameters in TensorBoard."""

from __future__ import annotations

from collections import defaultdict
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import HParam

HPARAM_NAMES = (
    "learning_rate", "n_steps", "batch_size", "gamma", "gae_lambda", "target_kl", "cg_max_steps", "cg_damping",
    "n_critic_updates", "replay_memory", "replay_is_clip", "cg_warm_start", "cg_warm_start_rescale",
    "value_baseline", "normalize_advantage", "use_sde", "sub_sampling_factor", "seed", "n_envs",
)  # fmt: skip


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
