"""Reacher3D-v1: Reacher3D-v0 with a bounded bonus for being close to the target (grasp_envs.near_bonus)."""

from __future__ import annotations

from grasp_envs import reacher3d_v0
from grasp_envs.near_bonus import NearTargetBonus, v1_docstring


class Reacher3DEnv(NearTargetBonus, reacher3d_v0.Reacher3DEnv):
    __doc__ = v1_docstring(
        reacher3d_v0.Reacher3DEnv.__doc__ or "",
        "Reacher3D",
        "palm",
        "Measured (docs/results.md, 5 seeds): every\n      TRPO variant, and PPO, ends 1M steps at 0.97-1.00 success.",
    )
