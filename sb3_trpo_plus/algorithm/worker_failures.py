"""Worker processes that die, named: which worker, which process, which envs, and how it ended.

A rollout worker that dies (killed, out of memory, a crash in native code) raises :class:`RolloutWorkerError`
naming the worker, its process and the envs it stepped, instead of a bare ``EOFError`` / ``BrokenPipeError``: the
pools of :mod:`sb3_trpo_plus.rollouts` raise it themselves, and :func:`worker_failure` gives SB3's
``SubprocVecEnv`` the same message (``TRPOPlus.learn`` translates its pipe errors).
"""

from __future__ import annotations

import signal
import time
from typing import Any

from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnv, VecEnvWrapper


class RolloutWorkerError(RuntimeError):
    """A rollout worker process died; the message names the worker, its process and its envs."""


def death_cause(process: Any) -> str:
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
        f"worker {i} (pid {inner.processes[i].pid}) stepping env {i} ({names[i]}) died: {death_cause(inner.processes[i])}"
        for i in dead
    )
    return RolloutWorkerError(f"SubprocVecEnv {described} [{type(error).__name__}]")
