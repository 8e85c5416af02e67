"""sb3-trpo-plus: TRPO for Stable-Baselines3 with generalized sample reuse, the grasp_envs arm tasks on a batched
MuJoCo engine, and weights-only loading of trained runs.

Three sub-packages, each importing only those below it:

* :mod:`sb3_trpo_plus.application`: the ``trpo-plus`` command over rl-zoo3, the recipes (``make_model``), loading,
  evaluating and plotting trained agents;
* :mod:`sb3_trpo_plus.rollouts`: rollout workers that collect whole segments in-process, in local processes or on a
  Ray cluster, and the batched-engine choice;
* :mod:`sb3_trpo_plus.algorithm`: :class:`TRPOPlus` and what it needs to learn from any SB3 ``VecEnv``;

and :mod:`sb3_trpo_plus.common` below them all (argument rules, atomic writes).
"""

from importlib.metadata import PackageNotFoundError, version

import grasp_envs  # noqa: F401  (registers the thesis' environments, so `TRPOPlus(..., "Grasper3D-v0")` works)
from sb3_trpo_plus import moved
from sb3_trpo_plus.algorithm.trpo_plus import TRPOPlus
from sb3_trpo_plus.application.agents import load_agent, load_eval_agent
from sb3_trpo_plus.application.recipes import make_model, recipe

moved.install()

try:
    __version__ = version("sb3-trpo-plus")
except PackageNotFoundError:  # pragma: no cover - running from a source tree without installation
    __version__ = "0.0.0"

__all__ = ["TRPOPlus", "__version__", "load_agent", "load_eval_agent", "make_model", "recipe"]
