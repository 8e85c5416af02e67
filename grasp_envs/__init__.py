"""The thesis' MuJoCo arm tasks as Gymnasium environments, registered on import.

``gymnasium.make("Grasper3D-v7")`` after ``import grasp_envs`` (or ``import sb3_trpo_plus``), or
``gymnasium.make("grasp_envs:Grasper3D-v7")`` anywhere. One class per task, its options one frozen dataclass
(``Grasper3DOptions``, ...); each id is a preset of its options (``grasp_envs.registration.PRESETS``). Importing
also asks multiprocessing's forkserver to preload this package, so ``SubprocVecEnv`` workers know the ids too.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
from typing import TYPE_CHECKING, Any

from grasp_envs.grasper3d import Grasper3DEnv, Grasper3DOptions
from grasp_envs.reacher2d import Reacher2DEnv, Reacher2DOptions
from grasp_envs.reacher3d import Reacher3DEnv, Reacher3DOptions
from grasp_envs.registration import ENV_IDS, PRESETS, RECOMMENDED_GRASPER, register_presets
from grasp_envs.wall_reacher3d import WallReacher3DEnv, WallReacher3DOptions
from grasp_envs.wrappers import ScriptedStartOptions, ScriptedStarts

__all__ = [
    "ENV_IDS",
    "PRESETS",
    "RECOMMENDED_GRASPER",
    "BatchVecEnv",
    "Grasper3DEnv",
    "Grasper3DOptions",
    "Reacher2DEnv",
    "Reacher2DOptions",
    "Reacher3DEnv",
    "Reacher3DOptions",
    "ScriptedStartOptions",
    "ScriptedStarts",
    "WallReacher3DEnv",
    "WallReacher3DOptions",
    "has_batch_engine",
    "make_batch_env",
]

register_presets()


def has_batch_engine(env_id: str) -> bool:
    """Whether ``make_batch_env`` runs ``env_id`` (every registered id of this package, and no other)."""
    if not isinstance(env_id, str):
        raise TypeError(f"env_id must be a registered Gymnasium id (str), got {env_id!r}")
    return env_id in ENV_IDS


if TYPE_CHECKING:
    from grasp_envs.batch import BatchVecEnv, make_batch_env
else:

    def __getattr__(name: str) -> Any:
        # the batched engine is an SB3 VecEnv: imported on first use, so that making a Gymnasium env never imports
        # stable_baselines3 and torch
        if name in ("BatchVecEnv", "make_batch_env"):
            from grasp_envs import batch

            return getattr(batch, name)
        raise AttributeError(f"module 'grasp_envs' has no attribute {name!r}")


def _preload_in_forkserver() -> None:
    """Make forkserver children (SB3's default SubprocVecEnv start method) import this package."""
    server = multiprocessing.forkserver._forkserver
    modules = list(getattr(server, "_preload_modules", ["__main__"]))
    if __name__ not in modules:
        multiprocessing.forkserver.set_forkserver_preload([*modules, __name__])


_preload_in_forkserver()
