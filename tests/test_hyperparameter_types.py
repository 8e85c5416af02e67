"""Every constructor argument of TRPOPlus accepts its type and range only, and a bad value's error names it.

The table below has one row per argument of ``TRPOPlus.__init__``; a new argument without a row fails
``test_table_covers_every_argument``. Booleans are ``bool`` only, integers never ``bool`` or ``float``, numbers
``int`` or ``float`` (never ``bool`` or ``str``) or a schedule where SB3 takes one, and ``None`` only where the
default is ``None`` (and ``env``, which SB3's ``load`` gives after construction).
"""

from __future__ import annotations

import inspect
import pathlib
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.buffers import DictRolloutBuffer, ReplayBuffer, RolloutBuffer
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.trpo_plus import HYPERPARAMETER_RULES, validate_hyperparameters


class Row(NamedTuple):
    valid: list[Any]
    invalid: list[Any]


def _schedule(progress_remaining: float) -> float:
    return 0.001 + 0.009 * progress_remaining


NOT_BOOL = ["no", "False", 0, 1, 1.0, np.float64(1.0)]
NOT_INT = [True, False, 1.0, 64.0, "64", np.float32(64)]
NOT_NUMBER = [True, False, "0.5", [0.5], float("nan"), float("inf")]

TABLE: dict[str, Row] = {
    "policy": Row(["MlpPolicy", ActorCriticPolicy], ["NoSuchPolicy", 42, BasePolicy, ActorCriticPolicy.__init__]),
    "env": Row(["Pendulum-v1", None], [42, 1.5, ["Pendulum-v1"], object()]),
    "learning_rate": Row([3e-4, 1, _schedule], [0.0, -1e-3, *NOT_NUMBER, float]),
    "n_steps": Row([64, 2048, np.int64(64)], [0, -1, *NOT_INT]),
    "batch_size": Row([1, 8], [0, *NOT_INT]),
    "gamma": Row([0.0, 0.99, 1, 1.0], [-0.1, 1.5, *NOT_NUMBER]),
    "cg_max_steps": Row([1, 15], [0, *NOT_INT]),
    "cg_damping": Row([0.0, 0.1, 1], [-0.1, *NOT_NUMBER]),
    "line_search_shrinking_factor": Row([0.5, 0.8], [0.0, 1.0, 1, *NOT_NUMBER]),
    "line_search_max_iter": Row([1, 10], [0, *NOT_INT]),
    "n_critic_updates": Row([0, 10], [-1, *NOT_INT]),
    "gae_lambda": Row([0.0, 0.95, 1], [-0.1, 1.01, *NOT_NUMBER]),
    "use_sde": Row([False, True], NOT_BOOL),
    "sde_sample_freq": Row([-1, 0, 4], [-2, *NOT_INT]),
    "rollout_buffer_class": Row([None, RolloutBuffer, DictRolloutBuffer], [ReplayBuffer, "RolloutBuffer", 1]),
    "rollout_buffer_kwargs": Row([None, {}, {"gamma": 0.9}], [[], "gamma=0.9", 1]),
    "normalize_advantage": Row([True, False], NOT_BOOL),
    "target_kl": Row([0.01, 1, _schedule], [0.0, -0.01, "lin_0.01", *NOT_NUMBER]),
    "sub_sampling_factor": Row([1, 4], [0, *NOT_INT]),
    "fisher_sub_sampling": Row([1, 4], [0, *NOT_INT]),
    "replay_memory": Row([0, 3], [-1, *NOT_INT]),
    "replay_is_clip": Row([None, 2.0, 1], [0.0, -1.0, *NOT_NUMBER]),
    "replay_critic": Row([False, True], NOT_BOOL),
    "cg_warm_start": Row([False, True], NOT_BOOL),
    "cg_warm_start_rescale": Row([True, False], NOT_BOOL),
    "value_baseline": Row(["critic", "linear"], ["quadratic", "Critic", 0, True]),
    "linear_baseline_l2": Row([0.0, 2.0, 2], [-2.0, *NOT_NUMBER]),
    "stats_window_size": Row([1, 100], [0, *NOT_INT]),
    "tensorboard_log": Row([None, "runs", pathlib.Path("runs")], [1, True, ["runs"]]),
    "policy_kwargs": Row([None, {}, {"net_arch": [16]}], [[16], "net_arch=[16]", 1]),
    "verbose": Row([0, 1, 2], [-1, *NOT_INT]),
    "seed": Row([None, 0, 7], [-1, *NOT_INT]),
    "device": Row(["auto", "cpu", th.device("cpu")], ["gpu0", "", 0, 1.5, True]),
    "_init_setup_model": Row([False, True], NOT_BOOL),
}

PARAMETERS = inspect.signature(TRPOPlus).parameters

# the default batch_size (128) is larger than the rollout of these models (8 samples)
pytestmark = pytest.mark.filterwarnings("ignore:You have specified a mini-batch size")


def _default_is_none(name: str) -> bool:
    default = PARAMETERS[name].default
    return default is None or (default is inspect.Parameter.empty and name == "env")


@pytest.fixture(scope="module")
def env() -> DummyVecEnv:
    return DummyVecEnv([lambda: gym.make("Pendulum-v1")])


def _build(env: DummyVecEnv, name: str, value: Any) -> TRPOPlus:
    """A model on ``env`` with ``name=value``, its networks built only where ``_init_setup_model`` is the row."""
    kwargs: dict[str, Any] = {"policy": "MlpPolicy", "env": env, "n_steps": 8, "batch_size": 8, "_init_setup_model": False}
    kwargs[name] = value
    if kwargs["_init_setup_model"]:
        kwargs["policy_kwargs"] = kwargs.get("policy_kwargs") or {"net_arch": [8]}
    return TRPOPlus(**kwargs)


def test_table_covers_every_argument() -> None:
    assert set(TABLE) == set(PARAMETERS), "every TRPOPlus argument needs a row (valid and invalid values)"
    assert set(HYPERPARAMETER_RULES) == set(PARAMETERS), "every TRPOPlus argument needs a validation rule"
    for name, row in TABLE.items():
        assert row.valid and row.invalid, name


def _valid_values() -> list[tuple[str, Any]]:
    cases = [(name, value) for name, row in TABLE.items() for value in row.valid]
    # every default is valid
    cases += [(name, p.default) for name, p in PARAMETERS.items() if p.default is not inspect.Parameter.empty]
    return cases


@pytest.mark.parametrize(("name", "value"), _valid_values())
def test_valid_value_is_accepted(env: DummyVecEnv, name: str, value: Any) -> None:
    _build(env, name, value)


def _invalid_values() -> list[tuple[str, Any]]:
    cases = [(name, value) for name, row in TABLE.items() for value in row.invalid]
    # None is a value only where the default is None
    cases += [(name, None) for name in TABLE if not _default_is_none(name)]
    return cases


@pytest.mark.parametrize(("name", "value"), _invalid_values())
def test_invalid_value_is_named(env: DummyVecEnv, name: str, value: Any) -> None:
    with pytest.raises(ValueError, match=f"TRPOPlus hyperparameter `{name}` must be ") as error:
        _build(env, name, value)
    assert str(error.value).endswith(f"got {value!r}")


def test_string_for_a_bool_is_refused() -> None:
    with pytest.raises(ValueError, match="`cg_warm_start` must be a bool \\(True or False\\), got 'no'"):
        TRPOPlus("MlpPolicy", "Pendulum-v1", cg_warm_start="no", _init_setup_model=False)  # type: ignore[arg-type]


def test_validation_knows_only_the_constructor_arguments() -> None:
    with pytest.raises(TypeError, match="no hyperparameter `n_epochs`"):
        validate_hyperparameters(n_epochs=10)


def test_numbers_reach_sb3_schedules_as_floats(env: DummyVecEnv) -> None:
    """SB3's FloatSchedule takes int and float: a numpy learning rate or radius is stored as a Python float."""
    model = TRPOPlus("MlpPolicy", env, learning_rate=np.float32(1e-3), target_kl=np.float32(0.02), n_steps=8, batch_size=8)
    assert type(model.learning_rate) is float and type(model.target_kl) is float
    assert model.current_target_kl == pytest.approx(0.02)
