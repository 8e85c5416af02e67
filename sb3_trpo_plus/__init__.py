"""sb3-trpo-plus: TRPO for Stable-Baselines3 with generalized sample reuse, the grasp_envs arm tasks on a batched
MuJoCo engine, and weights-only loading of trained runs."""

from importlib.metadata import PackageNotFoundError, version

import grasp_envs  # noqa: F401  (registers the thesis' environments, so `TRPOPlus(..., "Grasper3D-v0")` works)
from sb3_trpo_plus.agents import load_agent, load_eval_agent
from sb3_trpo_plus.recipes import make_model, recipe
from sb3_trpo_plus.trpo_plus import TRPOPlus

try:
    __version__ = version("sb3-trpo-plus")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without installation
    __version__ = "0.0.0"

__all__ = ["TRPOPlus", "__version__", "load_agent", "load_eval_agent", "make_model", "recipe"]
