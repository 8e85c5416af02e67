"""A subprocess pool that steps *several* environments per worker (the thesis' parallel sampler, 6.3).

SB3's ``SubprocVecEnv`` runs one environment per process: one pipe round trip per env per step, and
on a 2-core machine 16 processes fight for 2 cores. ``ShardedSubprocVecEnv`` splits the environments
into ``n_workers`` shards, each a ``DummyVecEnv`` in its own process, so a step costs one round trip per
worker and the workers step their shards in parallel. Observations, rewards, dones and infos come back
in env order, with SB3's auto-reset and ``terminal_observation`` semantics (those of ``DummyVecEnv``).
With ``in_process=True`` the learner process steps the last shard itself, as the thesis' master process
sampled too: on a 2-core machine, 2 workers are then one worker process plus the learner.
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


def _handle(venv: DummyVecEnv, command: str, data: Any) -> Any:
    """Execute one command on a shard; the reply to send back (the worker loop and the in-process shard share it)."""
    if command == "step":
        venv.step_async(data)
        return venv.step_wait()
    if command == "reset":
        seeds, options = data
        venv._seeds, venv._options = seeds, options
        return venv.reset(), venv.reset_infos
    if command == "get_images":
        return venv.get_images()
    if command == "get_attr":
        return venv.get_attr(*data)
    if command == "set_attr":
        venv.set_attr(*data)
        return None
    if command == "env_method":
        name, indices, args, kwargs = data
        return venv.env_method(name, *args, indices=indices, **kwargs)
    if command == "env_is_wrapped":
        return venv.env_is_wrapped(*data)
    if command == "spaces":
        return venv.observation_space, venv.action_space, venv.render_mode
    raise NotImplementedError(f"ShardedSubprocVecEnv worker: unknown command {command!r}")


def _worker(remote: Connection, parent_remote: Connection, env_fns: CloudpickleWrapper) -> None:
    parent_remote.close()
    venv = DummyVecEnv(env_fns.var)
    try:
        while True:
            command, data = remote.recv()
            if command == "close":
                venv.close()
                remote.close()
                break
            remote.send(_handle(venv, command, data))
    except (KeyboardInterrupt, EOFError):
        pass


class _InProcessShard:
    """A shard stepped by the learner process itself, behind the same send / recv interface as a pipe."""

    def __init__(self, env_fns: Sequence[Callable[[], gym.Env]]):
        self.venv = DummyVecEnv(list(env_fns))
        self._reply: Any = None

    def send(self, message: tuple[str, Any]) -> None:
        command, data = message
        if command == "close":
            self.venv.close()
        else:
            self._reply = _handle(self.venv, command, data)

    def recv(self) -> Any:
        reply, self._reply = self._reply, None
        return reply

    def close(self) -> None:
        pass


class ShardedSubprocVecEnv(VecEnv):
    """``n_workers`` workers, each stepping ``len(env_fns) / n_workers`` environments.

    :param env_fns: environment constructors (as for ``SubprocVecEnv``)
    :param n_workers: number of workers (default: ``os.cpu_count()``, at most ``len(env_fns)``)
    :param start_method: multiprocessing start method (default: forkserver where available, as SB3)
    :param in_process: the learner process is one of the workers: it steps the last shard itself while
        the ``n_workers - 1`` worker processes step theirs (one process fewer, and the learner's core
        works during the step instead of waiting). ``n_workers=1, in_process=True`` is a ``DummyVecEnv``.
    """

    def __init__(
        self,
        env_fns: Sequence[Callable[[], gym.Env]],
        n_workers: int | None = None,
        start_method: str | None = None,
        in_process: bool = False,
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
        self.remotes: list[Any] = []
        self.processes = []
        for index, shard in enumerate(self._shards):
            if in_process and index == len(self._shards) - 1:  # last: its step runs after the others were sent
                self.remotes.append(_InProcessShard([env_fns[i] for i in shard]))
                continue
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

    @property
    def in_process(self) -> bool:
        return isinstance(self.remotes[-1], _InProcessShard)

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
