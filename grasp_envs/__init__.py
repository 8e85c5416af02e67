"""The thesis' MuJoCo arm tasks as Gymnasium environments, registered on import.

``gymnasium.make("Grasper3D-v0")`` after ``import grasp_envs`` (or ``import sb3_trpo_plus``), or
``gymnasium.make("grasp_envs:Grasper3D-v0")`` anywhere. Importing also asks multiprocessing's
forkserver to preload this package, so ``SubprocVecEnv`` workers know the ids too.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver

from gymnasium.envs.registration import register, registry

from grasp_envs.grasper3d_v0 import Grasper3DEnv
from grasp_envs.grasper3d_v1 import Grasper3DEnv as Grasper3DEnvV1
from grasp_envs.grasper3d_v2 import Grasper3DEnv as Grasper3DEnvV2
from grasp_envs.grasper3d_v3 import Grasper3DEnv as Grasper3DEnvV3
from grasp_envs.grasper3d_v4 import Grasper3DEnv as Grasper3DEnvV4
from grasp_envs.grasper3d_v5 import Grasper3DEnv as Grasper3DEnvV5
from grasp_envs.grasper3d_v6 import Grasper3DEnv as Grasper3DEnvV6
from grasp_envs.reacher2d_v0 import Reacher2DEnv
from grasp_envs.reacher2d_v1 import Reacher2DEnv as Reacher2DEnvV1
from grasp_envs.reacher3d_v0 import Reacher3DEnv
from grasp_envs.reacher3d_v1 import Reacher3DEnv as Reacher3DEnvV1
from grasp_envs.wall_reacher3d_v0 import WallReacher3DEnv

__all__ = [
    "ENV_IDS",
    "Grasper3DEnv",
    "Grasper3DEnvV1",
    "Grasper3DEnvV2",
    "Grasper3DEnvV3",
    "Grasper3DEnvV4",
    "Grasper3DEnvV5",
    "Grasper3DEnvV6",
    "Reacher2DEnv",
    "Reacher2DEnvV1",
    "Reacher3DEnv",
    "Reacher3DEnvV1",
    "WallReacher3DEnv",
]

# id -> (entry point, max_episode_steps, reward_threshold). Thresholds are measured returns of a solution:
# the hand-written controllers of grasp_envs.scripted (mean of 20 seeded episodes: Reacher3D -8.2,
# WallReacher3D -45.1, Grasper3D 91.7, Grasper3D-v1 214.9, Grasper3D-v2 210.8, Grasper3D-v3 243.0,
# Grasper3D-v4 253.4, Grasper3D-v6 303.0, Reacher2D-v1 5.4, Reacher3D-v1 30.6) and, for Reacher2D-v0, TRPOPlus after
# `make train` (-3.9; the controller's large torques cost -8.0 there).
_SPECS = {
    "Reacher2D-v0": ("grasp_envs.reacher2d_v0:Reacher2DEnv", 50, -4.0),
    "Reacher2D-v1": ("grasp_envs.reacher2d_v1:Reacher2DEnv", 50, 5.0),
    "Reacher3D-v0": ("grasp_envs.reacher3d_v0:Reacher3DEnv", 100, -8.0),
    "Reacher3D-v1": ("grasp_envs.reacher3d_v1:Reacher3DEnv", 100, 30.0),
    "Grasper3D-v0": ("grasp_envs.grasper3d_v0:Grasper3DEnv", 100, 90.0),
    "Grasper3D-v1": ("grasp_envs.grasper3d_v1:Grasper3DEnv", 100, 210.0),
    "Grasper3D-v2": ("grasp_envs.grasper3d_v2:Grasper3DEnv", 100, 210.0),
    "Grasper3D-v3": ("grasp_envs.grasper3d_v3:Grasper3DEnv", 100, 240.0),
    "Grasper3D-v4": ("grasp_envs.grasper3d_v4:Grasper3DEnv", 100, 250.0),
    "Grasper3D-v5": ("grasp_envs.grasper3d_v5:Grasper3DEnv", 100, 250.0),  # v4's dynamics and reward
    "Grasper3D-v6": ("grasp_envs.grasper3d_v6:Grasper3DEnv", 100, 300.0),
    "WallReacher3D-v0": ("grasp_envs.wall_reacher3d_v0:WallReacher3DEnv", 100, -45.0),
}
ENV_IDS = tuple(_SPECS)

for _env_id, (_entry_point, _steps, _threshold) in _SPECS.items():
    if _env_id not in registry:
        register(id=_env_id, entry_point=_entry_point, max_episode_steps=_steps, reward_threshold=_threshold)


def _preload_in_forkserver() -> None:
    """Make forkserver children (SB3's default SubprocVecEnv start method) import this package."""
    server = multiprocessing.forkserver._forkserver
    modules = list(getattr(server, "_preload_modules", ["__main__"]))
    if __name__ not in modules:
        multiprocessing.forkserver.set_forkserver_preload([*modules, __name__])


_preload_in_forkserver()
