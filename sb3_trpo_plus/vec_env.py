"""A subprocess pool that steps *several* environments per worker (the thesis' parallel sampler, 6.3).

SB3's ``SubprocVecEnv`` runs one environment per process: one pipe round trip per env per step, and
on a 2-core machine 16 processes fight for 2 cores. ``ShardedSubprocVecEnv`` splits the environments
into ``n_workers`` shards, each a ``DummyVecEnv`` in its own process, so a step costs one round trip per
worker and the workers step their shards in parallel. Observations, rewards, dones and infos come back
in env order, with SB3's auto-reset and ``terminal_observation`` semantics (those of ``DummyVecEnv``).
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper, VecEnvIndices, VecEnvObs, VecEnvStepReturn


def _worker(remote: Connection, parent_remote: Connection, env_fns: CloudpickleWrapper) -> None:
    parent_remote.close()
    venv = DummyVecEnv(env_fns.var)
    try:
        while True:
            command, data = remote.recv()
            if command == "step":
                venv.step_async(data)
                remote.send(venv.step_wait())
            elif command == "reset":
                seeds, options = data
                venv._seeds, venv._options = seeds, options
                remote.send((venv.reset(), venv.reset_infos))
            elif command == "get_images":
                remote.send(venv.get_images())
            elif command == "get_attr":
                remote.send(venv.get_attr(*data))
            elif command == "set_attr":
                venv.set_attr(*data)
                remote.send(None)
            elif command == "env_method":
                name, indices, args, kwargs = data
                remote.send(venv.env_method(name, *args, indices=indices, **kwargs))
            elif command == "env_is_wrapped":
                remote.send(venv.env_is_wrapped(*data))
            elif command == "spaces":
                remote.send((venv.observation_space, venv.action_space, venv.render_mode))
            elif command == "close":
                venv.close()
                remote.close()
                break
            else:
                raise NotImplementedError(f"ShardedSubprocVecEnv worker: unknown command {command!r}")
    except (KeyboardInterrupt, EOFError):
        pass


class ShardedSubprocVecEnv(VecEnv):
    """``n_workers`` processes, each stepping ``len(env_fns) / n_workers`` environments.

    :param env_fns: environment constructors (as for ``SubprocVecEnv``)
    :param n_workers: number of worker processes (default: ``os.cpu_count()``, at most ``len(env_fns)``)
    :param start_method: multiprocessing start method (default: forkserver where available, as SB3)
    """

    def __init__(
        self, env_fns: Sequence[Callable[[], gym.Env]], n_workers: int | None = None, start_method: str | None = None
    ):
        n_envs = len(env_fns)
        if n_envs < 1:
            raise ValueError("ShardedSubprocVecEnv needs at least one environment")
        n_workers = min(n_workers or mp.cpu_count(), n_envs)
        if n_workers < 1:
            raise ValueError(f"n_workers must be >= 1, got {n_workers}")
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        context = mp.get_context(start_method)
        bounds = np.linspace(0, n_envs, n_workers + 1).round().astype(int)
        self._shards = [list(range(bounds[i], bounds[i + 1])) for i in range(n_workers)]
        self._splits = bounds[1:-1]
        self.remotes, self.processes = [], []
        for shard in self._shards:
            remote, work_remote = context.Pipe()
            fns = CloudpickleWrapper([env_fns[i] for i in shard])
            process = context.Process(target=_worker, args=(work_remote, remote, fns), daemon=True)  # type: ignore[attr-defined]
            process.start()
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(process)
        self.waiting = False
        self.closed = False
        self.remotes[0].send(("spaces", None))
        observation_space, action_space, self.render_mode = self.remotes[0].recv()
        super().__init__(n_envs, observation_space, action_space)

    @property
    def n_workers(self) -> int:
        return len(self.remotes)

    def step_async(self, actions: np.ndarray) -> None:
        for remote, chunk in zip(self.remotes, np.split(np.asarray(actions), self._splits), strict=True):
            remote.send(("step", chunk))
        self.waiting = True

    def step_wait(self) -> VecEnvStepReturn:
        results = [remote.recv() for remote in self.remotes]
        self.waiting = False
        obs, rewards, dones, infos = zip(*results, strict=True)
        return (
            self._concat_obs(obs),
            np.concatenate(rewards),
            np.concatenate(dones),
            [info for shard_infos in infos for info in shard_infos],
        )

    def reset(self) -> VecEnvObs:
        for remote, shard in zip(self.remotes, self._shards, strict=True):
            remote.send(("reset", ([self._seeds[i] for i in shard], [self._options[i] for i in shard])))
        results = [remote.recv() for remote in self.remotes]
        obs, reset_infos = zip(*results, strict=True)
        self.reset_infos = [info for shard_infos in reset_infos for info in shard_infos]
        self._reset_seeds()
        self._reset_options()
        return self._concat_obs(obs)

    def _concat_obs(self, parts: Sequence[Any]) -> VecEnvObs:
        if isinstance(parts[0], dict):
            return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
        return np.concatenate(parts)

    def close(self) -> None:
        if self.closed:
            return
        if self.waiting:
            for remote in self.remotes:
                remote.recv()
        for remote in self.remotes:
            remote.send(("close", None))
        for process in self.processes:
            process.join()
        self.closed = True

    def get_images(self) -> Sequence[np.ndarray | None]:
        for remote in self.remotes:
            remote.send(("get_images", None))
        return [image for remote in self.remotes for image in remote.recv()]

    def _route(self, indices: VecEnvIndices) -> list[tuple[int, list[int]]]:
        """(worker, local indices) pairs covering ``indices``, in worker order."""
        wanted = set(self._get_indices(indices))
        routes = []
        for worker, shard in enumerate(self._shards):
            local = [position for position, env_index in enumerate(shard) if env_index in wanted]
            if local:
                routes.append((worker, local))
        return routes

    def _ask(self, command: str, indices: VecEnvIndices, payload: Callable[[list[int]], Any]) -> list[Any]:
        routes = self._route(indices)
        for worker, local in routes:
            self.remotes[worker].send((command, payload(local)))
        return [value for worker, _ in routes for value in self.remotes[worker].recv()]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._ask("get_attr", indices, lambda local: (attr_name, local))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for worker, local in self._route(indices):
            self.remotes[worker].send(("set_attr", (attr_name, value, local)))
            self.remotes[worker].recv()

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        return self._ask("env_method", indices, lambda local: (method_name, local, method_args, method_kwargs))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._ask("env_is_wrapped", indices, lambda local: (wrapper_class, local))
