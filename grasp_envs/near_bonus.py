"""The v1 reachers' precision term: a bounded bonus ``w (1 - tanh(d / sigma))`` added to a v0 reward.

With the v0 (thesis) reward ``-d - |a|^2`` the last centimetres before the target pay 0.01 per step, lost in
the exploration noise of the return, and the policies stop 2-5 cm short of the 2 cm success radius. The
bonus is steepest at the target and bounded in [0, w], so it cannot outweigh the rest of the task.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np
from gymnasium import utils
from numpy.typing import NDArray


class NearTargetBonus:
    """Mixin placed before a v0 reacher class: adds ``reward_near`` to its ``_get_rew``.

    The v0 class must report ``info["distance"]`` (the distance that decides success).
    """

    _reward_near_weight: float
    _near_scale: float

    def __init__(self, reward_near_weight: float = 0.5, near_scale: float = 0.05, **kwargs: Any):
        if not near_scale > 0:
            raise ValueError(f"near_scale must be positive, got {near_scale}")
        if not reward_near_weight >= 0:
            raise ValueError(f"reward_near_weight must be non-negative, got {reward_near_weight}")
        super().__init__(**kwargs)
        utils.EzPickle.__init__(self, reward_near_weight=reward_near_weight, near_scale=near_scale, **kwargs)  # type: ignore[arg-type]
        self._reward_near_weight = reward_near_weight
        self._near_scale = near_scale

    def _get_rew(self, action: NDArray[np.float64]) -> tuple[float, dict[str, Any]]:
        reward, info = super()._get_rew(action)  # type: ignore[misc]
        info["reward_near"] = self._reward_near_weight * (1.0 - float(np.tanh(info["distance"] / self._near_scale)))
        return reward + info["reward_near"], info


def v1_docstring(v0_doc: str, task: str, point: str, measured: str) -> str:
    """The v1 class docstring: v0's, with the bonus in Description, Rewards, Arguments and Version History."""
    doc = v0_doc.replace(
        "## Description\n", f"## Description\n    {task}-v0 with a bounded precision bonus in the reward.\n\n", 1
    )
    doc = re.sub(r"`reward = ([^`]*)`", r"`reward = \1 + reward_near`", doc, count=1)
    bullets = list(re.finditer(r"^    - `reward_\w+`.*(\n      .*)*$", doc.split("## Starting State")[0], flags=re.MULTILINE))
    end = bullets[-1].end()
    term = (
        f"\n    - `reward_near` $= w_{{near}} (1 - \\tanh(d / \\sigma))$ with $d$ the {point}-target distance,"
        "\n      `reward_near_weight` (default 0.5) and $\\sigma$ = `near_scale` (default 0.05 m): bounded in"
        "\n      $[0, w_{near}]$ and steepest at the target, so that the last centimetres pay"
    )
    doc = doc[:end] + term + doc[end:]
    rows = (
        "    | `reward_near_weight` | `0.5` | weight of `reward_near` |\n"
        "    | `near_scale` | `0.05` | distance scale $\\sigma$ of `reward_near` (m) |\n"
    )
    doc = doc.replace("    | `reset_noise_scale` |", rows + "    | `reset_noise_scale` |", 1)
    return (
        doc.rstrip()
        + f"\n    * v1: adds `reward_near`; dynamics, spaces, success rule and time limit are v0's. {measured}\n    "
    )
