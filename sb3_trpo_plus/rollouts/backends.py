"""Where rollout workers run: in the learner's process, in local processes, or as Ray actors (one interface)."""

from __future__ import annotations

import abc
import contextlib
import multiprocessing as mp
import re
import signal
import traceback
from multiprocessing.connection import Connection
from typing import Any

import torch as th

from sb3_trpo_plus.algorithm.worker_failures import RolloutWorkerError, death_cause
from sb3_trpo_plus.rollouts.worker import RolloutWorker, WorkerEnvs


class _WorkerDied(Exception):
    """A worker's process or node is gone (the pool may restart it)."""

    def __init__(self, cause: str):
        super().__init__(cause)
        self.cause = cause


class _Backend(abc.ABC):
    """Starts workers and runs their methods; ``submit`` returns a handle, ``result`` its value."""

    @abc.abstractmethod
    def start(self, index: int, envs: WorkerEnvs, torch_seed: int | None) -> None: ...

    @abc.abstractmethod
    def submit(self, index: int, method: str, *args: Any) -> Any: ...

    @abc.abstractmethod
    def result(self, index: int, handle: Any) -> Any: ...

    def share(self, value: Any) -> Any:
        """``value`` as the workers' methods take it (Ray puts it in the object store once)."""
        return value

    @abc.abstractmethod
    def stop(self, index: int) -> None: ...


class _InProcessBackend(_Backend):
    def __init__(self) -> None:
        self.workers: dict[int, RolloutWorker] = {}

    def start(self, index: int, envs: WorkerEnvs, torch_seed: int | None) -> None:
        try:
            self.workers[index] = RolloutWorker(index, envs, torch_seed)
        except Exception:
            raise RemoteTraceback(traceback.format_exc()) from None

    def submit(self, index: int, method: str, *args: Any) -> Any:
        try:
            return True, getattr(self.workers[index], method)(*args)
        except Exception:  # raised by result(), as the other backends raise a worker's error when asked
            return False, traceback.format_exc()

    def result(self, index: int, handle: Any) -> Any:
        ok, value = handle
        if not ok:
            raise RemoteTraceback(value)
        return value

    def stop(self, index: int) -> None:
        worker = self.workers.pop(index, None)
        if worker is not None:
            worker.close()


def _process_main(remote: Connection, parent_remote: Connection, index: int, envs: WorkerEnvs, torch_seed: int | None) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the learner's to handle: it stops and closes us
    parent_remote.close()
    th.set_num_threads(1)  # a worker's policy forward is small: one thread, as Ray gives each 1-CPU actor
    try:
        worker = RolloutWorker(index, envs, torch_seed)
    except Exception:
        remote.send((False, traceback.format_exc()))
        return
    remote.send((True, None))
    while True:
        try:
            method, args = remote.recv()
        except (EOFError, KeyboardInterrupt):
            break
        if method == "stop":
            worker.close()
            break
        try:
            reply = (True, getattr(worker, method)(*args))
        except Exception:
            reply = (False, traceback.format_exc())
        try:
            remote.send(reply)
        except (ConnectionError, EOFError):  # the learner closed the pool while this worker collected: stop quietly
            worker.close()
            break
        except Exception:  # e.g. a reply that cannot be pickled: its error instead
            remote.send((False, traceback.format_exc()))


class _ProcessBackend(_Backend):
    def __init__(self, start_method: str | None) -> None:
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        self.context = mp.get_context(start_method)
        self.remotes: dict[int, Connection] = {}
        self.processes: dict[int, Any] = {}

    def start(self, index: int, envs: WorkerEnvs, torch_seed: int | None) -> None:
        remote, work_remote = self.context.Pipe()
        process = self.context.Process(  # type: ignore[attr-defined]
            target=_process_main, args=(work_remote, remote, index, envs, torch_seed), daemon=True
        )
        process.start()
        work_remote.close()
        self.remotes[index], self.processes[index] = remote, process
        self.result(index, None)  # the worker's envs are built (or its error is raised)

    def submit(self, index: int, method: str, *args: Any) -> Any:
        try:
            self.remotes[index].send((method, args))
        except (ConnectionError, EOFError) as error:
            raise _WorkerDied(death_cause(self.processes[index])) from error
        return None

    def result(self, index: int, handle: Any) -> Any:
        try:
            ok, value = self.remotes[index].recv()
        except (ConnectionError, EOFError) as error:
            raise _WorkerDied(death_cause(self.processes[index])) from error
        if not ok:
            raise RemoteTraceback(value)
        return value

    def stop(self, index: int) -> None:
        remote, process = self.remotes.pop(index, None), self.processes.pop(index, None)
        if remote is not None:
            with contextlib.suppress(ConnectionError, EOFError, OSError):
                remote.send(("stop", ()))
            remote.close()
        if process is not None:
            process.join(timeout=5)
            if process.is_alive():
                process.kill()
                process.join()


class RemoteTraceback(Exception):
    """An exception raised inside a worker; its message is the worker's traceback."""


class _RayBackend(_Backend):
    def __init__(self, cpus_per_worker: float, placement_timeout: float) -> None:
        import ray

        self.ray = ray
        self.cpus_per_worker = cpus_per_worker
        self.placement_timeout = placement_timeout
        self.actor_class = ray.remote(RolloutWorker)
        self.actors: dict[int, Any] = {}

    def start(self, index: int, envs: WorkerEnvs, torch_seed: int | None) -> None:
        actor = self.actor_class.options(
            num_cpus=self.cpus_per_worker, scheduling_strategy="SPREAD", max_restarts=0, max_task_retries=0
        ).remote(index, envs, torch_seed)
        self.actors[index] = actor
        ready = actor.describe.remote()  # type: ignore[attr-defined]
        done, _ = self.ray.wait([ready], timeout=self.placement_timeout)
        if not done:
            with contextlib.suppress(Exception):
                self.ray.kill(self.actors.pop(index))  # never placed: nothing to close
            raise RolloutWorkerError(
                f"RayRollouts worker {index} ({envs.n_envs} x {envs.env_id}) was not placed within "
                f"{self.placement_timeout:.0f} s: no node of the cluster has {self.cpus_per_worker} CPU free "
                f"(cluster resources: {self.ray.available_resources()})"
            )
        self.result(index, ready)

    def submit(self, index: int, method: str, *args: Any) -> Any:
        return getattr(self.actors[index], method).remote(*args)

    def share(self, value: Any) -> Any:
        return self.ray.put(value)

    def result(self, index: int, handle: Any) -> Any:
        from ray import exceptions

        try:
            return self.ray.get(handle)
        except exceptions.RayTaskError as error:
            raise RemoteTraceback(_plain(str(error))) from None
        except (exceptions.RayActorError, exceptions.NodeDiedError, exceptions.ObjectLostError) as error:
            message = _plain(str(error))
            if getattr(error, "actor_init_failed", False):  # its __init__ raised: an error to report, not a death
                raise RemoteTraceback(message) from None
            raise _WorkerDied(f"{type(error).__name__}: {message.splitlines()[0] if message else ''}") from error

    def stop(self, index: int) -> None:
        actor = self.actors.pop(index, None)
        if actor is not None:
            with contextlib.suppress(Exception):
                self.ray.get(actor.close.remote(), timeout=10)
            with contextlib.suppress(Exception):
                self.ray.kill(actor)


def _plain(text: str) -> str:
    """``text`` without terminal colour codes (Ray colours its tracebacks)."""
    return re.sub(r"\x1b\[[0-9;]*m", "", text)
