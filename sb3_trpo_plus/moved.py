"""The import paths of the flat layout of 0.1 (every module directly under ``sb3_trpo_plus``), kept for one release.

The modules now live in the sub-packages ``common``, ``algorithm``, ``rollouts`` and ``application``. Importing an
old path (``import sb3_trpo_plus.segment``, ``from sb3_trpo_plus.agents import load_agent``, or a pickle that names
``sb3_trpo_plus.segment.SegmentRolloutBuffer``, as models saved by 0.1 do) warns with a ``DeprecationWarning`` naming
the new path and gives the names of the module(s) that hold them now. The old paths go in the release after next.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import types
import warnings
from typing import Any

MOVED: dict[str, tuple[str, ...]] = {
    "sb3_trpo_plus.arguments": ("sb3_trpo_plus.common.arguments",),
    "sb3_trpo_plus.persistence": ("sb3_trpo_plus.common.persistence",),
    **{
        f"sb3_trpo_plus.{name}": (f"sb3_trpo_plus.algorithm.{name}",)
        for name in (
            "baselines",
            "collection",
            "critic",
            "generalized",
            "hyperparameters",
            "natural_gradient",
            "replay",
            "reuse",
            "segment",
            "trpo_plus",
            "update",
            "worker_failures",
        )
    },
    # the statistics as data stayed with the algorithm; reading them from a run's file went to the application
    "sb3_trpo_plus.normalization": ("sb3_trpo_plus.algorithm.normalization", "sb3_trpo_plus.application.run_files"),
    "sb3_trpo_plus.engines": ("sb3_trpo_plus.rollouts.engines",),
    "sb3_trpo_plus.ray_cluster": ("sb3_trpo_plus.rollouts.ray_cluster",),
    "sb3_trpo_plus.rollouts.steps": ("sb3_trpo_plus.algorithm.segment_pool",),
    **{
        f"sb3_trpo_plus.{name}": (f"sb3_trpo_plus.application.{name}",)
        for name in ("agents", "callbacks", "cli", "evaluation", "experiment", "plotting", "recipes", "run_folders", "zoo")
    },
}
"""Old module path -> the modules that hold its names now, searched in order."""


class MovedModule(types.ModuleType):
    """An old module path: each name is looked up in the new modules."""

    def __init__(self, name: str, targets: tuple[str, ...]):
        super().__init__(name, f"Moved to {', '.join(targets)}.")
        self.__moved_to__ = targets

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        for target in self.__moved_to__:
            module = importlib.import_module(target)
            if hasattr(module, name):
                return getattr(module, name)
        raise AttributeError(f"module {self.__name__!r} (moved to {', '.join(self.__moved_to__)}) has no attribute {name!r}")

    def __dir__(self) -> list[str]:
        return sorted({name for target in self.__moved_to__ for name in dir(importlib.import_module(target))})


class MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old paths of :data:`MOVED` (on ``sys.meta_path`` once ``sb3_trpo_plus`` is imported)."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        return MovedModule(spec.name, MOVED[spec.name])

    def exec_module(self, module: types.ModuleType) -> None:
        assert isinstance(module, MovedModule)
        warnings.warn(
            f"{module.__name__} moved to {' and '.join(module.__moved_to__)}; the old path goes in the release after next",
            DeprecationWarning,
            stacklevel=2,  # warnings skips importlib's own frames: this points at the import
        )


def install() -> None:
    """Put the finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(finder, MovedModuleFinder) for finder in sys.meta_path):
        sys.meta_path.append(MovedModuleFinder())
