"""Test configuration: one torch thread per process (pytest-xdist runs one process per core)."""

import os

import torch as th

os.environ.setdefault("MUJOCO_GL", "egl")
th.set_num_threads(1)
