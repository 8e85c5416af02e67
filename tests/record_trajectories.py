"""Record the reference trajectories that ``tests/test_env_presets.py`` replays.

Each registered id (and a few option sets a documented result uses) is stepped for three seeded episodes:
the scripted controller's actions, uniform random actions, and the controller's actions with noise. The
observations, rewards, terminations, truncations and numeric infos are saved with the actions, so a later
version of the code can replay the actions and compare. The files are frozen: regenerate them only for a new id.

    python tests/record_trajectories.py [ID ...]
"""

from __future__ import annotations

import sys
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import grasp_envs
from grasp_envs.scripted import SCRIPTED_POLICIES
from grasp_envs.wrappers import ScriptedStarts

OUT = Path(__file__).resolve().parent / "data" / "trajectories"
EPISODES = 3


def record(
    env_id: str, env_kwargs: dict[str, Any], wrapper: Any = None, seed: int = 7, episodes: int = EPISODES
) -> dict[str, np.ndarray]:
    env = gym.make(env_id, **env_kwargs)
    if wrapper is not None:
        env = wrapper(env)
    policy = SCRIPTED_POLICIES[env_id]
    rng = np.random.default_rng(seed)
    observations, actions, rewards, terminated, truncated, infos = [], [], [], [], [], []
    for episode in range(episodes):
        observation, info = env.reset(seed=seed if episode == 0 else None)
        observations.append(observation)
        infos.append(info)
        actions.append(np.full(env.action_space.shape, np.nan))
        rewards.append(np.nan)
        terminated.append(False)
        truncated.append(False)
        done = False
        while not done:
            if episode % 3 == 1:
                action = rng.uniform(env.action_space.low, env.action_space.high)
            else:
                action = policy(env.unwrapped)
                if episode % 3 == 2:
                    action = np.clip(
                        action + rng.normal(0, 0.2, size=action.shape), env.action_space.low, env.action_space.high
                    )
            observation, reward, term, trunc, info = env.step(action)
            done = term or trunc
            observations.append(observation)
            actions.append(np.asarray(action, dtype=np.float64))
            rewards.append(reward)
            terminated.append(term)
            truncated.append(trunc)
            infos.append(info)
    keys = sorted({k for info in infos for k, v in info.items() if isinstance(v, (bool, int, float, np.floating, np.bool_))})
    data = {
        "observations": np.array(observations),
        "actions": np.array(actions),
        "rewards": np.array(rewards, dtype=np.float64),
        "terminated": np.array(terminated),
        "truncated": np.array(truncated),
        "info_keys": np.array(keys),
        "infos": np.array([[float(info.get(k, np.nan)) for k in keys] for info in infos]),
        "seed": np.array(seed),
    }
    env.close()
    return data


# documented option sets beyond the ids' defaults: name -> (id, env kwargs)
OPTION_SETS: dict[str, tuple[str, dict[str, Any]]] = {
    "Grasper3D-v6_ready": ("Grasper3D-v6", {"start_pose": "ready"}),
    "Grasper3D-v0_thesis": ("Grasper3D-v0", {"reward_mode": "thesis"}),
}
# training aids (the ScriptedStarts wrapper), recorded over six episodes: name -> (id, env kwargs, wrapper kwargs)
SCRIPTED_SETS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "Grasper3D-v6_ready_scripted_late": ("Grasper3D-v6", {"start_pose": "ready"}, {"probability": 0.5, "steps": (50, 100)}),
    "Grasper3D-v4_scripted_hold": ("Grasper3D-v4", {}, {"probability": 0.6, "steps": (0, 100), "hold_height": 0.07}),
}


def main(names: list[str]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    targets = {env_id: (env_id, {}) for env_id in grasp_envs.ENV_IDS} | OPTION_SETS
    for name in names or [*targets, *SCRIPTED_SETS]:
        if name in targets:
            env_id, kwargs = targets[name]
            data = record(env_id, kwargs)
        else:
            env_id, kwargs, starts = SCRIPTED_SETS[name]
            data = record(env_id, kwargs, partial(ScriptedStarts, **starts), episodes=2 * EPISODES)
        np.savez_compressed(OUT / f"{name}.npz", **data)
        print(name)


if __name__ == "__main__":
    main(sys.argv[1:])
