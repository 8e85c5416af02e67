"""What the verbs of ``trpo-plus`` share: the algorithms they know, off-screen rendering without a display, and a
one-line stop."""

from __future__ import annotations

import argparse
import os
from typing import NoReturn

ALGO_CHOICES = ("trpo_plus", "trpo", "ppo")
ALGO_HELP = "trpo_plus (TRPOPlus), trpo (sb3-contrib's TRPO) or ppo (SB3's PPO); default: trpo_plus"


def headless() -> None:
    """Render off-screen when there is no display (MuJoCo reads MUJOCO_GL when it first renders)."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("MUJOCO_GL", "egl")


def fail(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    """Stop the command with one line, ``<prog>: error: <message>``, exit status 2 (as argparse's errors)."""
    parser.exit(2, f"{parser.prog}: error: {message}\n")
