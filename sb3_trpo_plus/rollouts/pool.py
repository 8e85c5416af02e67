"""The pools of rollout workers as SB3 VecEnvs, and how TRPOPlus finds a pool under its env."""

from __future__ import annotations

import abc
import contextlib
import dataclasses
import importlib
import io
import os
import time
from collections.abc import Iterable, Sequence
from typing import Any

import cloudpickle
import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.monitor import ResultsWriter
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sb3_trpo_plus.algorithm.normalization import NormalizationStats
from sb3_trpo_plus.algorithm.segment import Segment
from sb3_trpo_plus.algorithm.segment_pool import SegmentPool
from sb3_trpo_plus.algorithm.worker_failures import RolloutWorkerError
from sb3_trpo_plus.common.arguments import check_arguments
from sb3_trpo_plus.rollouts.backends import (
    RemoteTraceback,
    _Backend,
    _InProcessBackend,
    _ProcessBackend,
    _RayBackend,
    _WorkerDied,
)
from sb3_trpo_plus.rollouts.ray_cluster import check_cluster_token, use_loopback_for_local_ray
from sb3_trpo_plus.rollouts.rules import POOL_ARGUMENT_RULES
from sb3_trpo_plus.rollouts.worker import SegmentOrder, WorkerEnvs


class RolloutWorkers(SegmentPool):
    """``num_workers`` workers with ``envs_per_worker`` envs of ``env_id`` each: one SB3 ``VecEnv`` of
    ``num_workers * envs_per_worker`` envs (worker ``w`` steps envs ``w * envs_per_worker`` to
    ``(w + 1) * envs_per_worker - 1``). Use a subclass: :class:`InProcessRollouts`, :class:`ProcessRollouts`,
    :class:`RayRollouts`.

    Every argument is checked before any worker starts (``POOL_ARGUMENT_RULES``): a value of the wrong type or out of
    range raises ``ValueError`` naming the argument and the value.

    :param env_id: a registered Gymnasium id
    :param num_workers: number of workers
    :param envs_per_worker: envs of each worker (one batched VecEnv per worker for the tasks of ``grasp_envs``)
    :param seed: env ``i`` is seeded ``seed + i`` at the first reset; worker ``w`` samples its actions from a torch
        generator seeded from ``(seed, w)``. None: unseeded
    :param sim_threads: threads of each worker's batched physics
    :param env_kwargs: the env's constructor options
    :param scripted_starts: ``grasp_envs.wrappers.ScriptedStarts`` options (the grasper's training resets), or None
    :param info_keywords: info keys recorded in ``info["episode"]`` (as SB3's ``Monitor``); default
        ``("is_success",)`` for the tasks of ``grasp_envs``, none for other ids
    :param monitor_file: write every finished episode there, as SB3's ``Monitor`` / ``VecMonitor`` do (learner side)
    :param max_restarts: how often each worker may be restarted after its process or node died during a segment
        (the segment is then collected again by the new worker, whose envs start new episodes); beyond that, or
        when a worker dies while stepped one step at a time, :class:`RolloutWorkerError` names it
    """

    _start_hint = ""  # what a worker that dies while starting most likely needs, for its error

    def __init__(
        self,
        env_id: str,
        num_workers: int,
        envs_per_worker: int,
        *,
        seed: int | None = None,
        sim_threads: int = 1,
        env_kwargs: dict[str, Any] | None = None,
        scripted_starts: dict[str, Any] | None = None,
        info_keywords: Sequence[str] | None = None,
        monitor_file: str | None = None,
        max_restarts: int = 0,
    ):
        check_arguments(
            type(self).__name__,
            POOL_ARGUMENT_RULES,
            {
                "env_id": env_id,
                "num_workers": num_workers,
                "envs_per_worker": envs_per_worker,
                "seed": seed,
                "sim_threads": sim_threads,
                "env_kwargs": env_kwargs,
                "scripted_starts": scripted_starts,
                "info_keywords": info_keywords,
                "monitor_file": monitor_file,
                "max_restarts": max_restarts,
            },
        )
        from sb3_trpo_plus.rollouts.engines import has_batch_engine

        if info_keywords is None:
            info_keywords = ("is_success",) if has_batch_engine(env_id) else ()

        module, _, name = env_id.rpartition(":")  # gymnasium's "module:Env-v0": import the module that registers it
        if module:
            importlib.import_module(module)
        gym.spec(name)  # an unknown id raises gymnasium's error naming it, before any worker starts
        self.env_id = env_id
        self.num_workers, self.envs_per_worker = int(num_workers), int(envs_per_worker)
        self.max_restarts = int(max_restarts)
        self.worker_envs = WorkerEnvs(
            env_id,
            self.envs_per_worker,
            int(sim_threads),
            dict(env_kwargs or {}),
            None if scripted_starts is None else dict(scripted_starts),
            tuple(info_keywords),
        )
        self._base_seed = None if seed is None else int(seed)
        self.restarts = [0] * self.num_workers
        self._fresh: set[int] = set()  # workers restarted since the last segment: their envs were reset
        self.closed = False
        self._backend = self._make_backend()
        self._blueprint: bytes | None = None
        self._blueprint_of: int | None = None
        self._actions: np.ndarray | None = None
        self._pending: _PendingSegments | None = None
        self._arrived: list[Segment] | None = None
        self.last_timings: dict[str, Any] = {}
        self._monitor = None if monitor_file is None else _MonitorWriter(os.fspath(monitor_file), env_id, tuple(info_keywords))
        started: list[int] = []
        try:
            for worker in range(self.num_workers):
                started.append(worker)  # stopped below if anything fails, itself included
                try:
                    self._backend.start(worker, self.worker_envs, self._torch_seed(worker))
                except (_WorkerDied, RemoteTraceback) as error:
                    failure = self._error(worker, error)
                    if isinstance(error, _WorkerDied) and error.cause == "exit code 1" and self._start_hint:
                        failure = RolloutWorkerError(f"{failure} while starting; {self._start_hint}")
                    raise failure from None
            descriptions = self._all("describe")
        except BaseException:
            for worker in started:
                self._backend.stop(worker)
            raise
        first = descriptions[0]
        if not isinstance(
            first["observation_space"], spaces.Box | spaces.Discrete | spaces.MultiDiscrete | spaces.MultiBinary
        ):
            for worker in started:
                self._backend.stop(worker)
            raise ValueError(
                f"{type(self).__name__}: rollout workers collect array observations; {env_id} observes "
                f"{type(first['observation_space']).__name__}"
            )
        self.render_mode = first["render_mode"]
        self.workers = [{key: d[key] for key in ("pid", "host", "node")} for d in descriptions]
        super().__init__(self.num_workers * self.envs_per_worker, first["observation_space"], first["action_space"])
        if seed is not None:
            self.seed(int(seed))

    # -- backend plumbing
    @abc.abstractmethod
    def _make_backend(self) -> _Backend:
        """The backend that runs the workers (each subclass has one)."""

    def _torch_seed(self, worker: int) -> int | None:
        if self._base_seed is None:
            return None
        return int(np.random.SeedSequence([self._base_seed, worker]).generate_state(1)[0])

    def _describe_worker(self, worker: int) -> str:
        first = worker * self.envs_per_worker
        where = ""
        if hasattr(self, "workers") and worker < len(self.workers):
            where = f" (pid {self.workers[worker]['pid']} on {self.workers[worker]['host']})"
        return (
            f"{type(self).__name__} worker {worker}{where} stepping envs {first}-{first + self.envs_per_worker - 1} "
            f"({self.env_id})"
        )

    def _error(self, worker: int, error: BaseException) -> RolloutWorkerError:
        if isinstance(error, _WorkerDied):
            return RolloutWorkerError(f"{self._describe_worker(worker)} died: {error.cause}")
        return RolloutWorkerError(f"{self._describe_worker(worker)} raised an error; its traceback:\n{error}")

    def _gather(self, worker_handles: Sequence[tuple[int, Any]]) -> list[Any]:
        """Every handle's result; the first failure raises :class:`RolloutWorkerError` once all have answered."""
        results: list[Any] = []
        failure: RolloutWorkerError | None = None
        for worker, handle in worker_handles:
            try:
                results.append(self._backend.result(worker, handle))
            except (_WorkerDied, RemoteTraceback, Exception) as error:
                results.append(None)
                if failure is None:
                    failure = error if isinstance(error, RolloutWorkerError) else self._error(worker, error)
                    failure.__cause__ = error
        if failure is not None:
            raise failure
        return results

    def _all(self, method: str, *args: Any) -> list[Any]:
        self.discard_segments()
        handles = []
        for worker in range(self.num_workers):
            try:
                handles.append((worker, self._backend.submit(worker, method, *args)))
            except _WorkerDied as error:
                raise self._error(worker, error) from error
        return self._gather(handles)

    def _each(self, method: str, args: Sequence[tuple[Any, ...]]) -> list[Any]:
        self.discard_segments()
        handles = []
        for worker, worker_args in enumerate(args):
            try:
                handles.append((worker, self._backend.submit(worker, method, *worker_args)))
            except _WorkerDied as error:
                raise self._error(worker, error) from error
        return self._gather(handles)

    def _slice(self, values: Sequence[Any] | np.ndarray, worker: int) -> Any:
        return values[worker * self.envs_per_worker : (worker + 1) * self.envs_per_worker]

    # -- segments (TRPOPlus' collection)
    def _ensure_policy(self, policy: ActorCriticPolicy) -> None:
        if self._blueprint_of == id(policy) and self._blueprint is not None:
            return
        buffer = io.BytesIO()
        blueprint = _cpu_copy(policy)
        cloudpickle.dump(blueprint, buffer)
        self._blueprint, self._blueprint_of = buffer.getvalue(), id(policy)
        self._all("set_policy", self._blueprint)

    def collect_segments(
        self, policy: ActorCriticPolicy, n_steps: int, gamma: float, normalizer: NormalizationStats | None
    ) -> list[Segment]:
        """One segment of ``n_steps`` from every worker, in worker order. A worker that died is restarted (up to
        ``max_restarts`` times) and its segment collected again."""
        self.submit_segments(policy, n_steps, gamma, normalizer)
        return self.gather_segments()

    def submit_segments(
        self, policy: ActorCriticPolicy, n_steps: int, gamma: float, normalizer: NormalizationStats | None
    ) -> None:
        """Order one segment of ``n_steps`` from every worker, collected with ``policy``'s weights as they are now, and
        return at once: the workers collect while the caller goes on (the process and Ray workers in their own
        processes; the in-process workers collect here, before this returns). :meth:`gather_segments` returns them.
        Any other use of the pool first waits for the ordered segments and drops them (:meth:`discard_segments`)."""
        if self.collecting:
            raise RuntimeError(f"{type(self).__name__}.submit_segments: the segments ordered before were not gathered")
        self._ensure_policy(policy)
        start = time.perf_counter()
        weights = {name: tensor.detach().cpu().clone() for name, tensor in policy.state_dict().items()}
        order = self._backend.share(SegmentOrder(n_steps, float(gamma), weights, normalizer))
        broadcast = time.perf_counter() - start
        handles: dict[int, Any] = {}
        failure: RolloutWorkerError | None = None
        for worker in range(self.num_workers):
            try:
                handles[worker] = self._submit_or_restart(worker, "collect", order)
            except RolloutWorkerError as error:
                failure = failure or error
        self._pending = _PendingSegments(order, handles, failure, start, broadcast)

    @property
    def collecting(self) -> bool:
        """Whether segments were ordered (:meth:`submit_segments`) and not gathered yet."""
        return self._pending is not None or self._arrived is not None

    def gather_segments(self) -> list[Segment]:
        """The segments of the last :meth:`submit_segments`, in worker order, once every worker has sent its own; a
        worker that died meanwhile is restarted (up to ``max_restarts`` times) and collects its segment again."""
        self.wait_segments()
        arrived, self._arrived = self._arrived, None
        if arrived is None:
            raise RuntimeError(f"{type(self).__name__}.gather_segments: no segments were ordered (submit_segments)")
        return arrived

    def wait_segments(self) -> None:
        """Wait until the segments ordered have arrived, and keep them for :meth:`gather_segments` (e.g. so that time
        spent collecting them is not hidden in what the caller does next). Nothing ordered: nothing to do."""
        pending, self._pending = self._pending, None
        if pending is not None:
            self._arrived = self._receive(pending)

    def _receive(self, pending: _PendingSegments) -> list[Segment]:
        waiting = time.perf_counter()
        segments: list[Segment | None] = [None] * self.num_workers
        failure = pending.failure
        for worker in pending.handles:  # every submitted segment is read, so that no reply is left in a pipe
            while segments[worker] is None:
                try:
                    segments[worker] = self._backend.result(worker, pending.handles[worker])
                except _WorkerDied as error:
                    try:
                        self._restart(worker, error)
                        pending.handles[worker] = self._submit_or_restart(worker, "collect", pending.order)
                    except RolloutWorkerError as final:
                        failure = failure or final
                        break
                except RemoteTraceback as error:
                    failure = failure or self._error(worker, error)
                    break
        if failure is not None:
            raise failure
        end = time.perf_counter()
        done = [segment for segment in segments if segment is not None]
        for worker, segment in enumerate(done):
            segment.restarted = np.full(self.envs_per_worker, worker in self._fresh)
        self._fresh.clear()
        slowest = max(segment.seconds for segment in done)
        # beyond the slowest worker's own time, counted from when the caller waited if it came later (the segments
        # ordered during an update have been collecting meanwhile): scheduling, serialisation, transfer, restarts
        transfer = max(end - max(waiting, pending.start + pending.broadcast + slowest), 0.0)
        self.last_timings = {
            "broadcast_s": pending.broadcast,
            "collect_s": slowest + transfer,
            "wait_s": end - waiting,
            "worker_s": [segment.seconds for segment in done],
            "transfer_s": transfer,
        }
        return done

    def discard_segments(self) -> None:
        """Wait for the segments ordered and not gathered, and drop them (their envs have moved on: the next segment
        starts where they ended). Nothing ordered: nothing to do."""
        self.wait_segments()
        self._arrived = None

    def _submit_or_restart(self, worker: int, method: str, *args: Any) -> Any:
        while True:
            try:
                return self._backend.submit(worker, method, *args)
            except _WorkerDied as error:
                self._restart(worker, error)

    def _restart(self, worker: int, error: _WorkerDied) -> None:
        """Replace a dead worker by a new one with the same envs and policy, its envs reset with seeds past the pool's;
        a replacement that dies too counts as another restart. Raises :class:`RolloutWorkerError` past
        ``max_restarts`` or when the new worker raises an error."""
        while True:
            if self.restarts[worker] >= self.max_restarts:
                raise RolloutWorkerError(
                    f"{self._describe_worker(worker)} died: {error.cause} (restarted {self.restarts[worker]} times of "
                    f"max_restarts={self.max_restarts})"
                ) from error
            self.restarts[worker] += 1
            self._backend.stop(worker)
            try:
                self._start_fresh(worker)
                return
            except _WorkerDied as died:
                error = died
            except RemoteTraceback as raised:
                raise self._error(worker, raised) from None

    def _start_fresh(self, worker: int) -> None:
        restarts = self.restarts[worker]
        self._backend.start(worker, self.worker_envs, self._torch_seed(worker + self.num_workers * restarts))
        description = self._backend.result(worker, self._backend.submit(worker, "describe"))
        self.workers[worker] = {key: description[key] for key in ("pid", "host", "node")}
        if self._blueprint is not None:
            self._backend.result(worker, self._backend.submit(worker, "set_policy", self._blueprint))
        seeds = None
        if self._base_seed is not None:
            first = self._base_seed + worker * self.envs_per_worker + self.num_envs * restarts
            seeds = list(range(first, first + self.envs_per_worker))
        self._backend.result(worker, self._backend.submit(worker, "reset", seeds, None))
        self._fresh.add(worker)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """As ``VecEnv.seed``; a restarted worker's envs are later seeded past ``seed + num_envs``."""
        if seed is not None:
            self._base_seed = int(seed)
        return super().seed(seed)

    def record_episodes(self, ended: Sequence[tuple[int, dict[str, Any]]]) -> None:
        """Write the episodes of one step's ``(env, info)`` to ``monitor_file`` (the segment path calls it per step)."""
        if self._monitor is not None:
            self._monitor.write(info for _, info in ended)

    # -- VecEnv
    def reset(self) -> VecEnvObs:
        seeds, options = list(self._seeds), list(self._options)
        results = self._each("reset", [(self._slice(seeds, w), self._slice(options, w)) for w in range(self.num_workers)])
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [info for _, infos in results for info in infos]
        return np.concatenate([obs for obs, _ in results])

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        actions, self._actions = self._actions, None
        if actions is None:
            raise RuntimeError("step_wait called without step_async")
        results = self._each("step", [(self._slice(actions, w),) for w in range(self.num_workers)])
        infos = [info for _, _, _, worker_infos in results for info in worker_infos]
        dones = np.concatenate([dones for _, _, dones, _ in results])
        if self._monitor is not None:
            self._monitor.write(infos[i] for i in np.flatnonzero(dones))
        return (
            np.concatenate([obs for obs, _, _, _ in results]),
            np.concatenate([rewards for _, rewards, _, _ in results]),
            dones,
            infos,
        )

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self._pending = self._arrived = None  # stopping a worker drops what it was collecting
        for worker in range(self.num_workers):
            self._backend.stop(worker)
        if self._monitor is not None:
            self._monitor.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            if not self.closed:
                self.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [image for images in self._all("call", "get_images") for image in images]

    def _route(self, indices: VecEnvIndices) -> list[tuple[int, list[int]]]:
        groups: dict[int, list[int]] = {}
        for index in self._get_indices(indices):
            groups.setdefault(index // self.envs_per_worker, []).append(index % self.envs_per_worker)
        return sorted(groups.items())

    def _ask(self, command: str, indices: VecEnvIndices, *args: Any) -> list[Any]:
        routes = self._route(indices)
        self.discard_segments()
        handles = []
        for worker, local in routes:
            handles.append((worker, self._backend.submit(worker, "call", command, (*args, local))))
        return [value for values in self._gather(handles) for value in (values or [])]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._ask("get_attr", indices, attr_name)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._ask("set_attr", indices, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        self.discard_segments()
        handles = [
            (
                worker,
                self._backend.submit(
                    worker, "call", "env_method", (method_name, *method_args), {"indices": local, **method_kwargs}
                ),
            )
            for worker, local in self._route(indices)
        ]
        return [value for values in self._gather(handles) for value in values]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._ask("env_is_wrapped", indices, wrapper_class)


class InProcessRollouts(RolloutWorkers):
    """Rollout workers in the learner's process, collecting one after the other (the reference of the others)."""

    def _make_backend(self) -> _Backend:
        return _InProcessBackend()


class ProcessRollouts(RolloutWorkers):
    """One local process per rollout worker. ``start_method``: as SB3's ``SubprocVecEnv`` (default forkserver)."""

    _start_hint = (
        "a worker process imports the script that started it: if the script makes a ProcessRollouts (or trains a "
        'recipe with rollout_workers: process:N) at import, guard its entry point with `if __name__ == "__main__":`'
    )

    def __init__(self, env_id: str, num_workers: int, envs_per_worker: int, *, start_method: str | None = None, **kwargs: Any):
        check_arguments(type(self).__name__, POOL_ARGUMENT_RULES, {"start_method": start_method})
        self._start_method = start_method
        super().__init__(env_id, num_workers, envs_per_worker, **kwargs)

    def _make_backend(self) -> _Backend:
        return _ProcessBackend(self._start_method)


class RayRollouts(RolloutWorkers):
    """One Ray actor per rollout worker, spread over the cluster's nodes (``SPREAD`` scheduling).

    Connects to the running Ray cluster (``address``, else the ``RAY_ADDRESS`` environment variable) or, when there
    is none, starts a local Ray instance that listens on 127.0.0.1 only (unless ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER``
    is set); Ray already initialised in the process (``ray.init(...)``) is used as it is. Ray is imported and started
    once every argument is checked. A cluster that requires token authentication (``RAY_AUTH_MODE=token`` on its
    nodes) and refuses this process' token raises :class:`~sb3_trpo_plus.rollouts.ray_cluster.RayAuthenticationError` at once,
    naming what to set (docs: "Securing the cluster").

    :param cpus_per_worker: CPUs each actor reserves (Ray places a worker on a node with that many free)
    :param max_restarts: restarts of each worker after its process or node died (default 3)
    :param placement_timeout: seconds to wait for a worker to be placed before raising
    """

    def __init__(
        self,
        env_id: str,
        num_workers: int,
        envs_per_worker: int,
        *,
        address: str | None = None,
        cpus_per_worker: float = 1.0,
        max_restarts: int = 3,
        placement_timeout: float = 120.0,
        **kwargs: Any,
    ):
        check_arguments(
            type(self).__name__,
            POOL_ARGUMENT_RULES,
            {"address": address, "cpus_per_worker": cpus_per_worker, "placement_timeout": placement_timeout},
        )
        self._address = address
        self._cpus_per_worker, self._placement_timeout = float(cpus_per_worker), float(placement_timeout)
        super().__init__(env_id, num_workers, envs_per_worker, max_restarts=max_restarts, **kwargs)

    def _make_backend(self) -> _Backend:
        """Ray's backend, Ray started first (after the pool checked its arguments)."""
        try:
            import ray
        except ImportError as error:  # pragma: no cover - the suite runs with the extra installed
            raise ImportError("RayRollouts needs Ray: pip install 'sb3-trpo-plus[ray]'") from error
        if not ray.is_initialized():
            if self._address is None and not os.environ.get("RAY_ADDRESS"):
                use_loopback_for_local_ray()  # a Ray of this process only: not reachable from the network
            else:
                check_cluster_token(self._address)  # one line at once, not Ray's 20 s of retries
            ray.init(address=self._address, include_dashboard=False, log_to_driver=False)
        return _RayBackend(self._cpus_per_worker, self._placement_timeout)


POOLS: dict[str, type[RolloutWorkers]] = {"inprocess": InProcessRollouts, "process": ProcessRollouts, "ray": RayRollouts}
"""The pool class of each backend name (``trpo-plus train --workers BACKEND:N``)."""


def split_pool(backend: str, env_id: str, n_envs: int, num_workers: int, **kwargs: Any) -> RolloutWorkers:
    """``n_envs`` envs of ``env_id`` split evenly over ``num_workers`` workers of ``backend`` (a key of :data:`POOLS`);
    ``kwargs`` go to the pool. ``ValueError`` names a backend that does not exist or ``n_envs`` that does not split."""
    if backend not in POOLS:
        raise ValueError(f"rollout worker backend must be one of {tuple(POOLS)}, got {backend!r}")
    if n_envs % num_workers:
        raise ValueError(f"{backend}:{num_workers}: the recipe's n_envs={n_envs} does not split over {num_workers} workers")
    return POOLS[backend](env_id, num_workers, n_envs // num_workers, **kwargs)


def _cpu_copy(policy: ActorCriticPolicy) -> ActorCriticPolicy:
    """A CPU copy of ``policy`` without its optimizer (workers only sample)."""
    import copy

    optimizer = getattr(policy, "optimizer", None)
    try:
        policy.optimizer = None  # type: ignore[assignment]
        clone = copy.deepcopy(policy)
    finally:
        policy.optimizer = optimizer  # type: ignore[assignment]
    return clone.to("cpu")


@dataclasses.dataclass
class _PendingSegments:
    """Segments ordered from the workers and not gathered yet."""

    order: Any
    handles: dict[int, Any]
    failure: RolloutWorkerError | None
    start: float
    broadcast: float


class _MonitorWriter:
    """SB3's ``Monitor`` CSV for the pool's episodes (``r``, ``l``, ``t`` and the ``info_keywords``)."""

    def __init__(self, filename: str, env_id: str, info_keywords: tuple[str, ...]):
        self.writer = ResultsWriter(filename, header={"t_start": time.time(), "env_id": env_id}, extra_keys=info_keywords)
        self.info_keywords = info_keywords

    def write(self, infos: Iterable[dict[str, Any]]) -> None:
        for info in infos:
            episode = info.get("episode")
            if episode is not None:
                row: dict[str, Any] = {"r": episode["r"], "l": episode["l"], "t": episode["t"]}
                row.update({key: info.get(key) for key in self.info_keywords})
                self.writer.write_row(row)

    def close(self) -> None:
        self.writer.close()
