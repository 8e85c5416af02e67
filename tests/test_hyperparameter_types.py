"""Every user-facing argument accepts its type and range only, and a bad value's error names it and the value.

Each table has one row per argument of its constructor: ``TRPOPlus``, the batched engine (``BatchVecEnv``,
``make_batch_env``), the rollout worker pools and their parts (``InProcessRollouts``,
``ProcessRollouts``, ``RayRollouts``, ``RolloutWorker``, ``WorkerEnvs``, ``rollout_workers``); a new argument without
a row fails the table's coverage test. Booleans are ``bool`` only, integers never ``bool`` or ``float``, numbers
``int`` or ``float`` (never ``bool`` or ``str``) or a schedule where SB3 takes one, names a list or tuple of ``str``
(never one ``str``), and ``None`` only where the default is ``None`` (and ``env``, which SB3's ``load`` gives after
construction).
"""

from __future__ import annotations

import dataclasses
import inspect
import multiprocessing as mp
import pathlib
import re
from collections.abc import Callable
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from stable_baselines3.common.buffers import DictRolloutBuffer, ReplayBuffer, RolloutBuffer
from stable_baselines3.common.policies import ActorCriticPolicy, BasePolicy
from stable_baselines3.common.vec_env import DummyVecEnv

from grasp_envs import make_batch_env
from grasp_envs.batch import BatchVecEnv
from grasp_envs.options import got
from grasp_envs.wrappers import ScriptedStarts
from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.segment import SegmentDictRolloutBuffer, SegmentRolloutBuffer
from sb3_trpo_plus.algorithm.trpo_plus import HYPERPARAMETER_RULES, validate_hyperparameters
from sb3_trpo_plus.rollouts import (
    InProcessRollouts,
    ProcessRollouts,
    RayRollouts,
    RolloutWorker,
    RolloutWorkers,
    WorkerEnvs,
    backends,
    buried_rollout_workers,
    rollout_workers,
)


class Row(NamedTuple):
    valid: list[Any]
    invalid: list[Any]
    context: dict[str, Any] | None = None  # other arguments the row's values need (the task they run on, ...)


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
    # TRPOPlus fills its buffer from collected segments: SB3's own buffers cannot hold one
    "rollout_buffer_class": Row(
        [None, SegmentRolloutBuffer, SegmentDictRolloutBuffer],
        [ReplayBuffer, RolloutBuffer, DictRolloutBuffer, "RolloutBuffer", 1],
    ),
    "rollout_buffer_kwargs": Row([None, {}, {"gamma": 0.9}], [[], "gamma=0.9", 1]),
    "normalize_advantage": Row([True, False], NOT_BOOL),
    "target_kl": Row([0.01, 1, _schedule], [0.0, -0.01, "lin_0.01", *NOT_NUMBER]),
    "sub_sampling_factor": Row([1, 4], [0, *NOT_INT]),
    "fisher_sub_sampling": Row([1, 4], [0, *NOT_INT]),
    "replay_memory": Row([0, 3], [-1, *NOT_INT]),
    "sample_reuse": Row(["none", "generalized"], ["thesis", "Generalized", None, 1, True]),
    "reuse_batches": Row([1, 2, 2.5], [0.5, 0, -1.0, *NOT_NUMBER]),
    "reuse_max_batches": Row([1, 10], [0, -1, *NOT_INT]),
    "reuse_trace_clip": Row([1.0, 0.5, 2], [0.0, -1.0, *NOT_NUMBER]),
    "reuse_kl_vary": Row([False, True], NOT_BOOL),
    "overlap_collection": Row([False], NOT_BOOL),
    "replay_is_clip": Row([None, 2.0, 1], [0.0, -1.0, *NOT_NUMBER]),
    "replay_critic": Row([False, True], NOT_BOOL),
    "cg_warm_start": Row([False, True], NOT_BOOL),
    "cg_warm_start_rescale": Row([True, False], NOT_BOOL),
    "covariance_kl": Row([None, 0.01, 1], [0.0, -1.0, *NOT_NUMBER]),
    "policy_update": Row(["natural_gradient", "projection"], ["Projection", "trpo", None, 1, True]),
    # the projection_* rows are built with policy_update="projection" (_build), which the other values need
    "projection_epochs": Row([1, 10], [0, -1, *NOT_INT]),
    "projection_minibatches": Row([1, 32], [0, *NOT_INT]),
    "projection_learning_rate": Row([3e-4, 1], [0.0, -1e-3, *NOT_NUMBER]),
    "projection_regression": Row([0.0, 1.0, 2], [-1.0, *NOT_NUMBER]),
    "projection_max_grad_norm": Row([0.5, 1], [0.0, -1.0, *NOT_NUMBER]),
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
    if name.startswith("projection_"):
        kwargs["policy_update"] = "projection"
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
    assert str(error.value).endswith(got(value))


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


# ---------------------------------------------------------------------- the other user-facing constructors
NOT_NAMES = ["is_success", b"is_success", [1], ("is_success", None), {"is_success": 1}, True]
NOT_PATH = [1, True, ["monitor"]]
NOT_KEYWORDS = ["probability=0.5", [("probability", 0.5)], {1: 0.5}, True]


def _pendulum() -> gym.Env:
    return gym.make("Pendulum-v1")


class Constructor(NamedTuple):
    """A user-facing constructor (or function) and the table of its arguments.

    ``required``: values of the arguments without a default; ``forwards_to``: the constructor whose arguments its
    ``**kwargs`` takes (the table covers those too); ``error``: the start of the message naming argument ``{}``.
    """

    call: Callable[..., Any]
    required: dict[str, Any]
    table: dict[str, Row]
    error: str
    forwards_to: Callable[..., Any] | None = None


def _arguments(constructor: Constructor) -> dict[str, inspect.Parameter]:
    """Every argument the table must cover: the signature's, the forwarded constructor's, never the task options that
    ``**options`` takes (each task checks its own)."""
    own = inspect.signature(constructor.call).parameters
    forwarded = inspect.signature(constructor.forwards_to).parameters if constructor.forwards_to else {}
    merged = {**forwarded, **own}
    # Ray's tracing adds ``_ray_trace_ctx`` to the signature of a class once ``ray.remote`` wrapped it in this process
    return {
        name: p
        for name, p in merged.items()
        if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL) and not name.startswith("_ray_")
    }


BATCH_TABLE: dict[str, Row] = {
    "env_id": Row(["Reacher2D-v1", "Grasper3D-v7"], [42, b"Reacher2D-v1", ["Reacher2D-v1"]]),
    "n_envs": Row([1, 3, np.int64(2)], [0, -1, *NOT_INT]),
    "n_threads": Row([0, 1, 2, np.int64(1)], [-1, *NOT_INT]),
    "seed": Row([None, 0, 7, np.int64(3)], [-1, *NOT_INT]),
    "scripted_starts": Row([None, {}, {"probability": 0.5, "steps": (0, 5)}], NOT_KEYWORDS, {"env_id": "Grasper3D-v7"}),
    "wrapper_class": Row(
        [None, ScriptedStarts],
        ["ScriptedStarts", gym.wrappers.ClipAction, ScriptedStarts.__init__, 1],
        {"env_id": "Grasper3D-v7"},
    ),
    "wrapper_kwargs": Row(
        [None, {}, {"probability": 0.5}], NOT_KEYWORDS, {"env_id": "Grasper3D-v7", "wrapper_class": ScriptedStarts}
    ),
    "monitor": Row([True, False], NOT_BOOL),
    "monitor_file": Row([None, "batch", pathlib.Path("batch")], NOT_PATH, {"monitor": True}),
    "info_keywords": Row([(), ["is_success"], ("is_success",)], NOT_NAMES),
}

POOL_TABLE: dict[str, Row] = {
    "env_id": Row(["Reacher2D-v1", "Pendulum-v1"], [42, b"Reacher2D-v1", ["Reacher2D-v1"]]),
    "num_workers": Row([1, 2, np.int64(1)], [0, -1, *NOT_INT]),
    "envs_per_worker": Row([1, 2, np.int64(1)], [0, -1, *NOT_INT]),
    "seed": Row([None, 0, 7, np.int64(3)], [-1, *NOT_INT]),
    "sim_threads": Row([0, 1, 2], [-1, *NOT_INT]),
    "env_kwargs": Row([None, {}, {"frame_skip": 2}], ["frame_skip=2", [("frame_skip", 2)], {1: 2}, True]),
    "scripted_starts": Row([None, {}, {"probability": 0.5}], NOT_KEYWORDS, {"env_id": "Grasper3D-v7"}),
    "info_keywords": Row([None, (), ["is_success"], ("is_success",)], NOT_NAMES),
    "monitor_file": Row([None, "pool", pathlib.Path("pool")], NOT_PATH),
    "max_restarts": Row([0, 3, np.int64(1)], [-1, *NOT_INT]),
    # ProcessRollouts
    "start_method": Row([None, *mp.get_all_start_methods()], ["thread", "", 1, True]),
    # RayRollouts
    "address": Row([None, "auto", "127.0.0.1:6379"], [1, True, ["auto"]]),
    "cpus_per_worker": Row([0, 0.5, 1, 2.0], [-1, -0.5, *NOT_NUMBER]),
    "placement_timeout": Row([0.5, 1, 120.0], [0, -1.0, *NOT_NUMBER]),
}

CONSTRUCTORS: dict[str, Constructor] = {
    "BatchVecEnv": Constructor(
        BatchVecEnv, {"env_id": "Reacher2D-v1", "n_envs": 1}, BATCH_TABLE, "BatchVecEnv: `{}` must be "
    ),
    "make_batch_env": Constructor(make_batch_env, {"env_id": "Reacher2D-v1"}, BATCH_TABLE, "make_batch_env: `{}` must be "),
    **{
        pool.__name__: Constructor(
            pool,
            {"env_id": "Reacher2D-v1", "num_workers": 1, "envs_per_worker": 1},
            POOL_TABLE,
            f"{pool.__name__}: `{{}}` must be ",
            forwards_to=RolloutWorkers,
        )
        for pool in (InProcessRollouts, ProcessRollouts, RayRollouts)
    },
    "RolloutWorker": Constructor(
        RolloutWorker,
        {"index": 0, "envs": WorkerEnvs("Reacher2D-v1", 1), "torch_seed": None},
        {
            "index": Row([0, 3, np.int64(1)], [-1, *NOT_INT]),
            "envs": Row([WorkerEnvs("Reacher2D-v1", 2)], ["Reacher2D-v1", {"env_id": "Reacher2D-v1", "n_envs": 1}]),
            "torch_seed": Row([None, 0, 2**32, np.int64(5)], [-1, *NOT_INT]),
        },
        "RolloutWorker: `{}` must be ",
    ),
    "WorkerEnvs": Constructor(
        WorkerEnvs,
        {"env_id": "Reacher2D-v1", "n_envs": 1},
        {
            "env_id": POOL_TABLE["env_id"],
            "n_envs": Row([1, 4, np.int64(2)], [0, *NOT_INT]),
            "sim_threads": POOL_TABLE["sim_threads"],
            "env_kwargs": Row([{}, {"frame_skip": 2}], ["frame_skip=2", [("frame_skip", 2)], {1: 2}, True]),
            "scripted_starts": POOL_TABLE["scripted_starts"],
            "info_keywords": Row([(), ["is_success"], ("is_success",)], NOT_NAMES),
        },
        "WorkerEnvs: `{}` must be ",
    ),
    **{
        function.__name__: Constructor(
            function,
            {},
            {"env": Row([DummyVecEnv([_pendulum])], [42, "Pendulum-v1", object()])},
            f"{function.__name__}: `{{}}` must be ",
        )
        for function in (rollout_workers, buried_rollout_workers)
    },
}


@pytest.fixture
def in_tmp_path(monkeypatch: pytest.MonkeyPatch, tmp_path: pathlib.Path) -> None:
    """Monitor files named by a relative path land in ``tmp_path``."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def pools_in_process(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every pool's workers run in this process (no worker processes, no Ray): the values reach them fast."""
    for pool in (ProcessRollouts, RayRollouts):
        monkeypatch.setattr(pool, "_make_backend", lambda self: backends._InProcessBackend())


@pytest.fixture
def no_workers(monkeypatch: pytest.MonkeyPatch) -> None:
    """A pool that starts a worker (a process, Ray) before it checked its arguments fails the test."""

    def refuse(self: RolloutWorkers) -> Any:
        raise AssertionError(f"{type(self).__name__} started its workers before it checked its arguments")

    for pool in (InProcessRollouts, ProcessRollouts, RayRollouts):
        monkeypatch.setattr(pool, "_make_backend", refuse)


def _run(constructor: Constructor, name: str, value: Any) -> Any:
    """Call the constructor with ``name=value`` (and the row's context), and close what it built."""
    result = constructor.call(**{**constructor.required, **(constructor.table[name].context or {}), name: value})
    close = getattr(result, "close", None)
    if callable(close):
        close()
    return result


@pytest.mark.parametrize("label", CONSTRUCTORS)
def test_constructor_table_covers_every_argument(label: str) -> None:
    constructor = CONSTRUCTORS[label]
    assert set(_arguments(constructor)) <= set(constructor.table), f"every {label} argument needs a row"
    for name, row in constructor.table.items():
        assert row.valid and row.invalid, name


def test_shared_tables_have_no_row_without_an_argument() -> None:
    pools = (InProcessRollouts, ProcessRollouts, RayRollouts)
    arguments = {name for pool in pools for name in _arguments(CONSTRUCTORS[pool.__name__])}
    assert set(POOL_TABLE) == arguments
    assert set(BATCH_TABLE) == set(_arguments(CONSTRUCTORS["BatchVecEnv"])) | set(_arguments(CONSTRUCTORS["make_batch_env"]))


def _default(constructor: Constructor, name: str) -> Any:
    """The argument's default; ``inspect.Parameter.empty`` where it has none or a dataclass field's factory makes it."""
    if dataclasses.is_dataclass(constructor.call):
        field = {field.name: field for field in dataclasses.fields(constructor.call)}[name]
        return inspect.Parameter.empty if field.default is dataclasses.MISSING else field.default
    return _arguments(constructor)[name].default


def _constructor_cases(valid: bool) -> list[Any]:
    cases = []
    for label, constructor in CONSTRUCTORS.items():
        for name in _arguments(constructor):
            row = constructor.table[name]
            values = list(row.valid if valid else row.invalid)
            default = _default(constructor, name)
            if valid and default is not inspect.Parameter.empty:
                values.append(default)  # every default is valid
            if not valid and default is not None and not any(value is None for value in row.valid):
                values.append(None)  # None is a value only where the default is None (or the row says so)
            cases += [pytest.param(label, name, value, id=f"{label}-{name}-{i}") for i, value in enumerate(values)]
    return cases


@pytest.mark.usefixtures("in_tmp_path", "pools_in_process")
@pytest.mark.parametrize(("label", "name", "value"), _constructor_cases(valid=True))
def test_valid_argument_is_accepted(label: str, name: str, value: Any) -> None:
    _run(CONSTRUCTORS[label], name, value)


@pytest.mark.usefixtures("no_workers")
@pytest.mark.parametrize(("label", "name", "value"), _constructor_cases(valid=False))
def test_invalid_argument_is_named(label: str, name: str, value: Any) -> None:
    constructor = CONSTRUCTORS[label]
    with pytest.raises(ValueError) as error:
        _run(constructor, name, value)
    message = str(error.value)
    assert message.startswith(constructor.error.format(name)), message
    assert message.endswith(got(value)), message


def test_one_str_is_no_sequence_of_info_keys() -> None:
    """A str is refused where info keys are asked for (it would be recorded as its characters)."""
    message = "make_batch_env: `info_keywords` must be a list or tuple of str (not one str), got 'is_success'"
    with pytest.raises(ValueError, match=re.escape(message)):
        make_batch_env("Reacher2D-v1", info_keywords="is_success")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="InProcessRollouts: `info_keywords` must be None or a list or tuple of str"):
        InProcessRollouts("Reacher2D-v1", 1, 1, info_keywords="is_success")  # type: ignore[arg-type]
    assert WorkerEnvs("Reacher2D-v1", 1, info_keywords=["is_success"]).info_keywords == ("is_success",)  # type: ignore[arg-type]


def test_monitor_files_given_as_paths_are_written(tmp_path: pathlib.Path) -> None:
    batch = make_batch_env("Reacher2D-v1", 2, monitor_file=tmp_path / "batch")
    batch.close()
    pool = InProcessRollouts("Reacher2D-v1", 1, 2, monitor_file=tmp_path / "pool")
    pool.close()
    assert (tmp_path / "batch.monitor.csv").is_file() and (tmp_path / "pool.monitor.csv").is_file()
