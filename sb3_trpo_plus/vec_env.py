"""A subprocess pool that steps *several* environments per worker (the thesis' parallel sampler, 6.3).

SB3's ``SubprocVecEnv`` runs one environment per process: one pipe round trip per env per step, and
on a 2-core machine 16 processes fight for 2 cores. ``ShardedSubprocVecEnv`` splits the environments
into ``n_workers`` shards, each a ``DummyVecEnv`` in its own process, so a step costs one round trip per
worker and the workers step their shards in parallel. Observations, rewards, dones and infos come back
in env order, with SB3's auto-reset and ``terminal_observation`` semantics (those of ``DummyVecEnv``).
With ``in_process=True`` the learner process steps the last shard itself, as the thesis' master process
sampled too: on a 2-core machine, 2 workers are then one worker process plus the learner.

A worker that dies (killed, out of memory, a crash in native code) raises :class:`RolloutWorkerError`
naming the worker, its process and the envs it stepped, instead of a bare ``EOFError`` /
``BrokenPipeError``; :func:`worker_failure` gives SB3's ``SubprocVecEnv`` the same message. Workers
ignore SIGINT: Ctrl-C reaches the learner alone, which stops and closes them.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import time
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sb3_trpo_plus.arguments import Rule, boolean, check_arguments, choice, integer


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
    if command == "env_ids":
        return [_env_id(env) for env in venv.envs]
    raise NotImplementedError(f"ShardedSubprocVecEnv worker: unknown command {command!r}")


def _env_id(env: gym.Env) -> str:
    spec = getattr(env, "spec", None)
    return spec.id if spec is not None else type(env.unwrapped).__name__


class RolloutWorkerError(RuntimeError):
    """A rollout worker process died; the message names the worker, its process and its envs."""


def _death_cause(process: Any) -> str:
    """How a worker process ended, waiting up to a second for the operating system to report it."""
    deadline = time.monotonic() + 1.0
    while process.exitcode is None and time.monotonic() < deadline:
        process.join(timeout=0.05)
    code = process.exitcode
    if code is None:
        return "its pipe closed while the process still runs"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"


def _worker(remote: Connection, parent_remote: Connection, env_fns: CloudpickleWrapper) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the learner's to handle: it stops and closes us
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


SHARDED_ARGUMENT_RULES: dict[str, Rule] = {
    "env_fns": Rule(
        lambda value: isinstance(value, list | tuple) and len(value) >= 1 and all(callable(fn) for fn in value),
        "a list or tuple of at least one environment constructor (callables)",
    ),
    "n_workers": integer(1, optional=True),
    "start_method": choice(mp.get_all_start_methods(), optional=True),
    "in_process": boolean(),
}
"""Every constructor argument of :class:`ShardedSubprocVecEnv` and what it accepts."""


class ShardedSubprocVecEnv(VecEnv):
    """``n_workers`` workers, each stepping ``len(env_fns) / n_workers`` environments.

    Every argument is checked before any worker starts (``SHARDED_ARGUMENT_RULES``): a value of the wrong type or
    out of range raises ``ValueError`` naming the argument and the value.

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
        check_arguments(
            type(self).__name__, SHARDED_ARGUMENT_RULES,
            {"env_fns": env_fns, "n_workers": n_workers, "start_method": start_method, "in_process": in_process},
        )  # fmt: skip
        n_envs = len(env_fns)
        n_workers = min(mp.cpu_count() if n_workers is None else int(n_workers), n_envs)
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
        self._env_ids: list[str] = [f"env {i}" for i in range(n_envs)]
        self._send(0, ("spaces", None))
        observation_space, action_space, self.render_mode = self._recv(0)
        for worker in range(len(self.remotes)):
            self._send(worker, ("env_ids", None))
        self._env_ids = [env_id for worker in range(len(self.remotes)) for env_id in self._recv(worker)]
        super().__init__(n_envs, observation_space, action_space)

    def _send(self, worker: int, message: tuple[str, Any]) -> None:
        try:
            self.remotes[worker].send(message)
        except (ConnectionError, EOFError) as error:
            raise self._worker_died(worker, error) from error

    def _recv(self, worker: int) -> Any:
        try:
            return self.remotes[worker].recv()
        except (ConnectionError, EOFError) as error:
            raise self._worker_died(worker, error) from error

    def _worker_died(self, worker: int, error: BaseException) -> RolloutWorkerError:
        self.waiting = False
        process = self.processes[worker] if worker < len(self.processes) else None
        cause = _death_cause(process) if process is not None else repr(error)
        envs = ", ".join(f"{i} ({self._env_ids[i]})" for i in self._shards[worker])
        pid = f" (pid {process.pid})" if process is not None else ""
        return RolloutWorkerError(
            f"ShardedSubprocVecEnv worker {worker}{pid} stepping envs {envs} died: {cause} [{type(error).__name__}]"
        )

    @property
    def n_workers(self) -> int:
        return len(self.remotes)

    @property
    def in_process(self) -> bool:
        return isinstance(self.remotes[-1], _InProcessShard)

    def step_async(self, actions: np.ndarray) -> None:
        for worker, chunk in enumerate(np.split(np.asarray(actions), self._splits)):
            self._send(worker, ("step", chunk))
        self.waiting = True

    def step_wait(self) -> VecEnvStepReturn:
        results = [self._recv(worker) for worker in range(len(self.remotes))]
        self.waiting = False
        obs, rewards, dones, infos = zip(*results, strict=True)
        return (
            self._concat_obs(obs),
            np.concatenate(rewards),
            np.concatenate(dones),
            [info for shard_infos in infos for info in shard_infos],
        )

    def reset(self) -> VecEnvObs:
        for worker, shard in enumerate(self._shards):
            self._send(worker, ("reset", ([self._seeds[i] for i in shard], [self._options[i] for i in shard])))
        results = [self._recv(worker) for worker in range(len(self.remotes))]
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
        """Close every shard; a dead worker is skipped, one that does not exit within 10 s is terminated."""
        if self.closed:
            return
        for remote in self.remotes:
            try:
                if self.waiting:
                    remote.recv()
                remote.send(("close", None))
            except (ConnectionError, EOFError):
                pass  # a dead worker: nothing to close
        self.waiting = False
        for process in self.processes:
            process.join(timeout=10)
            if process.is_alive():
                process.terminate()
                process.join()
        self.closed = True

    def get_images(self) -> Sequence[np.ndarray | None]:
        for worker in range(len(self.remotes)):
            self._send(worker, ("get_images", None))
        return [image for worker in range(len(self.remotes)) for image in self._recv(worker)]

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
            self._send(worker, (command, payload(local)))
        return [value for worker, _ in routes for value in self._recv(worker)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._ask("get_attr", indices, lambda local: (attr_name, local))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for worker, local in self._route(indices):
            self._send(worker, ("set_attr", (attr_name, value, local)))
            self._recv(worker)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        return self._ask("env_method", indices, lambda local: (method_name, local, method_args, method_kwargs))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._ask("env_is_wrapped", indices, lambda local: (wrapper_class, local))


def _innermost(venv: VecEnv) -> VecEnv:
    while isinstance(venv, VecEnvWrapper):
        venv = venv.venv
    return venv


def subprocess_env_ids(venv: VecEnv | None) -> list[str] | None:
    """The env ids of an SB3 ``SubprocVecEnv`` (under any wrappers), asked while its workers live; else None."""
    inner = _innermost(venv) if venv is not None else None
    if not isinstance(inner, SubprocVecEnv):
        return None
    try:
        return [spec.id if spec is not None else f"env {i}" for i, spec in enumerate(inner.get_attr("spec"))]
    except (ConnectionError, EOFError, AttributeError):
        return None


def worker_failure(venv: VecEnv | None, error: BaseException, env_ids: list[str] | None = None) -> RolloutWorkerError | None:
    """For a pipe error of an SB3 ``SubprocVecEnv``: a :class:`RolloutWorkerError` naming the dead worker and its env.

    None when ``venv`` is no ``SubprocVecEnv`` or none of its workers died (the error has another cause).
    """
    inner = _innermost(venv) if venv is not None else None
    if not isinstance(inner, SubprocVecEnv):
        return None
    deadline = time.monotonic() + 1.0
    dead: list[int] = []
    while not dead and time.monotonic() < deadline:
        dead = [i for i, process in enumerate(inner.processes) if not process.is_alive()]
        if not dead:
            time.sleep(0.05)
    if not dead:
        return None
    inner.waiting = False
    names = env_ids or [f"env {i}" for i in range(inner.num_envs)]
    described = "; ".join(
        f"worker {i} (pid {inner.processes[i].pid}) stepping env {i} ({names[i]}) died: {_death_cause(inner.processes[i])}"
        for i in dead
    )
    return RolloutWorkerError(f"SubprocVecEnv {described} [{type(error).__name__}]")
