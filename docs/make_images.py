"""Render one PNG per environment for docs/environments.md (run: python docs/make_images.py).

Each image shows the state after a few steps of the scripted controller from a seeded reset.
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import gymnasium as gym
import numpy as np
from PIL import Image

from grasp_envs.scripted import SCRIPTED_POLICIES

STEPS = {  # the envs with a picture in docs/environments.md (the v1 reachers look like v0)
    "Reacher2D-v0": 10,
    "Reacher3D-v0": 20,
    "Grasper3D-v0": 45,
    "Grasper3D-v1": 60,
    "Grasper3D-v2": 85,  # the cube held up
    "WallReacher3D-v0": 25,
}


def main() -> None:
    out = Path(__file__).parent / "images"
    out.mkdir(exist_ok=True)
    for env_id, steps in STEPS.items():
        env = gym.make(env_id, render_mode="rgb_array", width=480, height=360)
        env.reset(seed=2)
        for _ in range(steps):
            env.step(SCRIPTED_POLICIES[env_id](env.unwrapped))
        frame = np.asarray(env.render())
        Image.fromarray(frame).save(out / f"{env_id}.png")
        env.close()
        print(f"wrote {out / f'{env_id}.png'}")


if __name__ == "__main__":
    main()
