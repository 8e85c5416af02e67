"""A run's files read as data: ``vecnormalize.pkl`` becomes :class:`~sb3_trpo_plus.algorithm.normalization.NormalizationStats`
with nothing unpickled running (:func:`load_normalization`); a file that cannot be used raises :class:`RunFileError`
naming it."""

from __future__ import annotations

import importlib
import pickle
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trpo_plus.algorithm.normalization import NormalizationStats


class RunFileError(ValueError):
    """A run file that cannot be used: the message names the file and what is wrong with it."""


class _Inert:
    """Stands in for a pickled object: keeps its constructor arguments and state as data, runs none of its code."""

    qualified_name = ""
    args: tuple[Any, ...]
    state: Any

    def __new__(cls, *args: Any, **kwargs: Any) -> _Inert:
        obj = object.__new__(cls)
        obj.args, obj.state = args, None
        return obj

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def __setstate__(self, state: Any) -> None:
        self.state = state


# numpy's array and scalar reconstruction: builds arrays from bytes, nothing else
_NUMPY_GLOBALS = {
    (module, name)
    for module in ("numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric", "numpy._core.numeric", "numpy")
    for name in ("_reconstruct", "scalar", "_frombuffer", "ndarray", "dtype")
}
_INERT_CLASSES = {
    "stable_baselines3.common.vec_env.vec_normalize.VecNormalize",
    "stable_baselines3.common.running_mean_std.RunningMeanStd",
}
_INERT_PREFIXES = ("gymnasium.spaces.", "numpy.random.")


class StatisticsUnpickler(pickle.Unpickler):
    """Unpickle ``vecnormalize.pkl`` as data: numpy arrays are rebuilt, the VecNormalize, its RunningMeanStd,
    spaces and random generators become :class:`_Inert` records, and any other global is refused."""

    def __init__(self, file: Any, path: Path):
        super().__init__(file)
        self.path = path
        self._inert: dict[str, type[_Inert]] = {}

    def find_class(self, module: str, name: str) -> Any:
        qualified = f"{module}.{name}"
        if (module, name) in _NUMPY_GLOBALS:
            return getattr(importlib.import_module(module), name)
        if module == "collections" and name == "OrderedDict":
            return OrderedDict
        if qualified in _INERT_CLASSES or qualified.startswith(_INERT_PREFIXES):
            if qualified not in self._inert:
                self._inert[qualified] = type(name, (_Inert,), {"qualified_name": qualified})
            return self._inert[qualified]
        raise pickle.UnpicklingError(f"refused the global {qualified}: not part of VecNormalize statistics")


def load_normalization(path: str | Path) -> NormalizationStats:
    """Read ``vecnormalize.pkl`` with :class:`StatisticsUnpickler` (no code runs); names the file on any problem."""
    path = Path(path)
    try:
        with path.open("rb") as file:
            root = StatisticsUnpickler(file, path).load()
    except pickle.UnpicklingError as error:
        raise RunFileError(f"{path}: {error}") from None
    except OSError as error:
        raise RunFileError(f"{path}: cannot read: {error}") from None
    except Exception as error:  # damaged bytes make pickle and numpy's reconstructors raise nearly any type
        raise RunFileError(f"{path}: not a readable VecNormalize pickle (truncated or corrupted): {error!r}") from error
    if not (isinstance(root, _Inert) and root.qualified_name.endswith(".VecNormalize") and isinstance(root.state, dict)):
        raise RunFileError(f"{path}: does not hold a VecNormalize")
    state: dict[str, Any] = root.state
    try:
        obs_mean, obs_var, obs_count = _rms_arrays(state["obs_rms"]) if state.get("norm_obs") else (None, None, None)
        ret_mean, ret_var, ret_count = _rms_arrays(state["ret_rms"])
        return NormalizationStats(
            obs_mean,
            obs_var,
            obs_count,
            ret_mean,
            ret_var,
            ret_count,
            norm_obs=bool(state["norm_obs"]),
            norm_reward=bool(state["norm_reward"]),
            clip_obs=float(state["clip_obs"]),
            clip_reward=float(state["clip_reward"]),
            gamma=float(state["gamma"]),
            epsilon=float(state["epsilon"]),
            norm_obs_keys=state.get("norm_obs_keys"),
        )
    except (KeyError, TypeError, ValueError, OverflowError) as error:
        raise RunFileError(f"{path}: VecNormalize statistics incomplete or malformed: {error!r}") from None


def _rms_arrays(record: Any) -> tuple[Any, Any, Any]:
    if isinstance(record, dict):
        parts = {key: _rms_arrays(value) for key, value in record.items()}
        return ({k: p[0] for k, p in parts.items()}, {k: p[1] for k, p in parts.items()}, {k: p[2] for k, p in parts.items()})
    if not (
        isinstance(record, _Inert) and record.qualified_name.endswith(".RunningMeanStd") and isinstance(record.state, dict)
    ):
        raise TypeError(f"expected a RunningMeanStd, got {getattr(record, 'qualified_name', type(record).__name__)}")
    mean, var = np.asarray(record.state["mean"], dtype=np.float64), np.asarray(record.state["var"], dtype=np.float64)
    if mean.shape != var.shape or not (np.all(np.isfinite(mean)) and np.all(np.isfinite(var))):
        raise ValueError("mean and var must be finite arrays of one shape")
    return mean, var, float(record.state["count"])
