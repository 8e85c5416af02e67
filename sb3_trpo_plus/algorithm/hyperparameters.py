"""What every constructor argument of :class:`~sb3_trpo_plus.TRPOPlus` accepts, and the checks that name a bad one or
a combination that cannot work."""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import torch as th
from sb3_contrib import TRPO
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.common.vec_env import VecEnv

from sb3_trpo_plus.algorithm.segment import SegmentDictRolloutBuffer, SegmentRolloutBuffer
from sb3_trpo_plus.common.arguments import ArgumentError, Rule, boolean, check_arguments, got, integer, number, optional

VALUE_BASELINES = ("critic", "linear")
SAMPLE_REUSE = ("none", "generalized")
POLICY_UPDATES = ("natural_gradient", "projection")
PROJECTION_DEFAULTS = {
    "projection_epochs": 10,
    "projection_minibatches": 32,
    "projection_learning_rate": 3e-4,
    "projection_regression": 1.0,
    "projection_max_grad_norm": 0.5,
}
"""The ``projection_*`` hyperparameters' defaults: another value needs ``policy_update="projection"``."""
CG_DEFAULTS = {"cg_max_steps": 15, "cg_damping": 0.1}
"""The conjugate gradient's defaults (sb3-contrib's): another value needs ``policy_update="natural_gradient"``."""


def _is_environment(value: Any) -> bool:
    if value is None or isinstance(value, str | VecEnv):  # None: SB3's `load` builds the model before the env is set
        return True
    return all(hasattr(value, name) for name in ("reset", "step", "observation_space", "action_space"))


def _is_device(value: Any) -> bool:
    if isinstance(value, th.device):
        return True
    if not isinstance(value, str):
        return False
    if value == "auto":
        return True
    try:
        th.device(value)
    except RuntimeError:
        return False
    return True


HYPERPARAMETER_RULES: dict[str, Rule] = {
    "policy": Rule(
        lambda value: (
            (isinstance(value, str) and value in TRPO.policy_aliases)
            or (isinstance(value, type) and issubclass(value, ActorCriticPolicy))
        ),
        f"one of {sorted(TRPO.policy_aliases)} or an ActorCriticPolicy subclass",
    ),
    "env": Rule(_is_environment, "an environment id (str), a Gymnasium environment or a VecEnv"),
    "learning_rate": number(lambda x: x > 0, "> 0", schedule=True),
    "n_steps": integer(1),
    "batch_size": integer(1),
    "gamma": number(lambda x: 0.0 <= x <= 1.0, "in [0, 1]"),
    "cg_max_steps": integer(1),
    "cg_damping": number(lambda x: x >= 0, ">= 0"),
    "line_search_shrinking_factor": number(lambda x: 0.0 < x < 1.0, "in the open interval (0, 1)"),
    "line_search_max_iter": integer(1),
    "n_critic_updates": integer(0),
    "gae_lambda": number(lambda x: 0.0 <= x <= 1.0, "in [0, 1]"),
    "use_sde": boolean(),
    "sde_sample_freq": integer(-1),
    "rollout_buffer_class": Rule(
        lambda value: (
            value is None or (isinstance(value, type) and issubclass(value, SegmentRolloutBuffer | SegmentDictRolloutBuffer))
        ),
        "None or a subclass of sb3_trpo_plus.algorithm.segment.SegmentRolloutBuffer or SegmentDictRolloutBuffer "
        "(TRPOPlus fills its buffer from collected segments)",
    ),
    "rollout_buffer_kwargs": optional(dict, "a dict"),
    "normalize_advantage": boolean(),
    "target_kl": number(lambda x: x > 0, "> 0", schedule=True),
    "sub_sampling_factor": integer(1),
    "fisher_sub_sampling": integer(1),
    "replay_memory": integer(0),
    "sample_reuse": Rule(lambda value: isinstance(value, str) and value in SAMPLE_REUSE, f"one of {SAMPLE_REUSE}"),
    "reuse_batches": number(lambda x: x >= 1, ">= 1"),
    "reuse_max_batches": integer(1),
    "reuse_trace_clip": number(lambda x: x > 0, "> 0"),
    "reuse_kl_vary": boolean(),
    "overlap_collection": boolean(),
    "replay_is_clip": number(lambda x: x > 0, "> 0", optional=True),
    "replay_critic": boolean(),
    "cg_warm_start": boolean(),
    "cg_warm_start_rescale": boolean(),
    "covariance_kl": number(lambda x: x > 0, "> 0", optional=True),
    "policy_update": Rule(lambda value: isinstance(value, str) and value in POLICY_UPDATES, f"one of {POLICY_UPDATES}"),
    "projection_epochs": integer(1),
    "projection_minibatches": integer(1),
    "projection_learning_rate": number(lambda x: x > 0, "> 0"),
    "projection_regression": number(lambda x: x >= 0, ">= 0"),
    "projection_max_grad_norm": number(lambda x: x > 0, "> 0"),
    "value_baseline": Rule(lambda value: isinstance(value, str) and value in VALUE_BASELINES, f"one of {VALUE_BASELINES}"),
    "linear_baseline_l2": number(lambda x: x >= 0, ">= 0"),
    "stats_window_size": integer(1),
    "tensorboard_log": optional(str | os.PathLike, "a folder path"),
    "policy_kwargs": optional(dict, "a dict"),
    "verbose": integer(0),
    "seed": integer(0, optional=True),
    "device": Rule(_is_device, "a torch.device or a device name ('auto', 'cpu', 'cuda', ...)"),
    "_init_setup_model": boolean(),
}
"""Every constructor argument of :class:`TRPOPlus` and what it accepts.

Booleans are ``bool`` only; integers are ``int`` (or numpy integers), never ``bool`` or ``float``; numbers are
finite ``int`` or ``float`` (or numpy numbers), never ``bool`` or ``str``, or a schedule where SB3 takes one;
``None`` only where the default is ``None`` (and ``env``, which SB3's ``load`` sets after construction).
"""


def validate_hyperparameters(**hyperparameters: Any) -> None:
    """Raise :class:`~sb3_trpo_plus.common.arguments.ArgumentError` naming the first hyperparameter that breaks its rule in
    ``HYPERPARAMETER_RULES``."""
    for name, value in hyperparameters.items():
        rule = HYPERPARAMETER_RULES.get(name)
        if rule is None:
            raise TypeError(f"TRPOPlus has no hyperparameter `{name}`")
        if not rule.accepts(value):
            raise ArgumentError(f"TRPOPlus hyperparameter `{name}` must be {rule.requirement}, {got(value)}")


def float_or_schedule(value: float | Schedule) -> float | Schedule:
    """A validated number as a Python float (SB3's ``FloatSchedule`` takes int and float only), a schedule as is."""
    return value if callable(value) else float(value)


def check_combinations(hyperparameters: Mapping[str, Any]) -> None:
    """Raise :class:`~sb3_trpo_plus.common.arguments.ArgumentError` naming hyperparameters that each pass their rule but do not
    work together (those that need no env; ``hyperparameters``: every constructor argument these checks read, each
    valid by itself):

    - ``sample_reuse="generalized"`` reuses batches its own way: no ``replay_memory``, ``value_baseline="linear"``,
      ``replay_critic`` or ``replay_is_clip`` beside it;
    - its ``reuse_batches`` (``B``) is at most ``(reuse_max_batches + 1) / 2``, what equal weights over every batch
      reach;
    - ``overlap_collection`` learns from segments one update old, which only the generalized update corrects for;
    - ``policy_update="projection"`` solves no CG: no ``cg_warm_start``, ``fisher_sub_sampling``, or ``cg_max_steps``
      and ``cg_damping`` at other values than their defaults beside it; the ``projection_*`` hyperparameters at other
      values than their defaults need it.
    """
    generalized = hyperparameters["sample_reuse"] == "generalized"
    if generalized:
        conflicts = {
            "replay_memory": hyperparameters["replay_memory"] > 0,
            "value_baseline='linear'": hyperparameters["value_baseline"] == "linear",
            "replay_critic": hyperparameters["replay_critic"],
            "replay_is_clip": hyperparameters["replay_is_clip"] is not None,
        }
        if named := [name for name, conflict in conflicts.items() if conflict]:
            raise ArgumentError(
                f"TRPOPlus: sample_reuse='generalized' reuses batches its own way; it does not combine with {named}"
            )
        max_batches = hyperparameters["reuse_max_batches"]
        most = (max_batches + 1) / 2
        reachable = number(
            lambda batches: batches <= most,
            f"in [1, {most}] for `reuse_max_batches`={max_batches} (at most (`reuse_max_batches` + 1) / 2)",
        )
        check_arguments("TRPOPlus", {"reuse_batches": reachable}, {"reuse_batches": hyperparameters["reuse_batches"]})
    if hyperparameters["policy_update"] == "projection":
        conflicts = {
            "cg_warm_start": hyperparameters["cg_warm_start"],
            "fisher_sub_sampling": hyperparameters["fisher_sub_sampling"] > 1,
            "cg_max_steps": hyperparameters["cg_max_steps"] != CG_DEFAULTS["cg_max_steps"],
            "cg_damping": hyperparameters["cg_damping"] != CG_DEFAULTS["cg_damping"],
        }
        if named := [name for name, conflict in conflicts.items() if conflict]:
            raise ArgumentError(
                f"TRPOPlus: policy_update='projection' solves no conjugate gradient; it does not combine with {named}"
            )
    elif named := [name for name, default in PROJECTION_DEFAULTS.items() if hyperparameters[name] != default]:
        raise ArgumentError(
            f"TRPOPlus: {named} set the projected trust region; they need policy_update='projection', "
            f"got policy_update={hyperparameters['policy_update']!r}"
        )
    if hyperparameters["overlap_collection"] and not generalized:
        raise ArgumentError(
            "TRPOPlus: overlap_collection=True learns from segments one update old; it needs "
            f"sample_reuse='generalized' to correct for that, got sample_reuse={hyperparameters['sample_reuse']!r}"
        )
