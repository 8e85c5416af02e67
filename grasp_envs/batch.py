"""The batched simulation engine: every registered task as one SB3 ``VecEnv`` over ``mujoco.batch.Batch``.

``make_batch_env("Grasper3D-v7", n_envs=64, seed=0, n_threads=2)`` steps 64 simulations of the task's model on a
thread pool (MuJoCo's GIL-free batch, bit-identical to a loop of ``mj_step``) and computes actions' controls,
observations, rewards, success, termination and resets for all of them at once, with the task's one batch-first
definition (``grasp_envs.base.ArmTask``) and the one step sequence (``grasp_envs.base.Physics``, here over a
``BatchPhysics``) that the Gymnasium env runs as a batch of one; its scripted starts are the wrapper's
(``grasp_envs.wrappers.scripted_starts``). Its transitions equal SB3's ``DummyVecEnv`` over ``gymnasium.make(env_id)``
with the same seeds and actions (tested to 1e-9 for every id).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import mujoco
import mujoco.batch
import numpy as np
from gymnasium.envs.registration import load_env_creator
from gymnasium.spaces import Box
from gymnasium.utils import seeding
from numpy.typing import NDArray
from stable_baselines3.common.monitor import Monitor, ResultsWriter
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from grasp_envs.base import RENDER_ARGUMENTS, SIM_FIELDS, ArmEnv, ArmTask, Physics, SimArrays, Start, info_of, infos_of
from grasp_envs.grasper3d import Grasper3DTask
from grasp_envs.options import Rule, check_arguments, flag, integer, is_keywords, is_names
from grasp_envs.proximity import ContactScreen
from grasp_envs.wrappers import ScriptedStartOptions, ScriptedStarts, scripted_starts

# MjData fields that are state (bound as live views); the others are derived, refreshed by each call on the
# simulations it ran
_STATE_FIELDS = ("qpos", "qvel", "ctrl", "mocap_pos")

# What each argument of BatchVecEnv and make_batch_env accepts, and that requirement in words. Booleans are bool only,
# integers never bool or float, info keys a list or tuple of str (one str would be a sequence of characters).
ARGUMENT_RULES: dict[str, Rule] = {
    "env_id": Rule(lambda value: isinstance(value, str), "a registered id of grasp_envs (str)"),
    "n_envs": integer(1),
    "n_threads": integer(0),
    "seed": integer(0, optional=True),
    "scripted_starts": Rule(lambda value: value is None or is_keywords(value), "None or a dict of ScriptedStarts' arguments"),
    "wrapper_class": Rule(
        lambda value: value is None or value is ScriptedStarts,
        "None or grasp_envs.wrappers.ScriptedStarts (the batched engine runs no per-env Gymnasium wrappers; "
        "wrap the VecEnv with VecEnv wrappers instead)",
    ),
    "wrapper_kwargs": Rule(lambda value: value is None or is_keywords(value), "None or a dict of the wrapper's arguments"),
    "monitor": flag(),
    "monitor_file": Rule(lambda value: value is None or isinstance(value, str | os.PathLike), "None or a file path"),
    "info_keywords": Rule(is_names, "a list or tuple of str (not one str)"),
}


class BatchPhysics(Physics):
    """``n`` simulations of a task's model in one ``mujoco.batch.Batch``, stepped on ``n_threads`` threads.

    ``sim`` binds the batch's fields as live views: its state fields, and its derived fields, which each call
    refreshes for the simulations it ran only, so that every simulation's show it as ``MjData`` after its last
    ``mj_step`` or ``mj_forward``. The contact list has no batched binding: each simulation's is read from its
    ``MjData``, for the tasks that count contacts, only where ``ContactScreen`` finds that a counted pair may touch.
    """

    def __init__(self, task: ArmTask, n: int, n_threads: int):
        model = task.build_model()
        super().__init__(task, model, n)
        self.batch = mujoco.batch.Batch(model, n, n_threads, persistent=True)
        self._state = {name: self.batch.bind(name) for name in _STATE_FIELDS}
        self._derived = {name: self.batch.bind(name) for name in SIM_FIELDS if name not in _STATE_FIELDS}
        self._contacts = np.zeros((n, len(task.contact_pairs)))
        self._contact_data = mujoco.MjData(model)
        self._screen = ContactScreen(model, [(task.geom_id(a), task.geom_id(b)) for a, b in task.contact_pairs])
        self.sim = SimArrays(model, {**self._state, **self._derived}, self.batch.warning[..., 1], contacts=self._contacts)

    def _run(self, ids: NDArray[np.int64] | None) -> None:
        self.batch.step(ids, nstep=self.task.frame_skip)

    def _restore(self, ids: NDArray[np.int64]) -> None:
        self.batch.reset(ids)

    def _settle(self, ids: NDArray[np.int64] | None) -> None:
        """Count the contacts of ``ids`` (all: ``None``) as MjData shows them now."""
        if self.task.contact_pairs:  # the contact list has no batched binding: read each simulation's MjData
            xpos, xmat = self._derived["geom_xpos"], self._derived["geom_xmat"]
            if ids is None:  # every simulation: the bound arrays as they are, no row copies
                rows = np.arange(self.n)
            else:
                rows = np.asarray(ids)
                xpos, xmat = xpos[rows], xmat[rows]
            self._contacts[rows] = 0.0
            # only where a counted pair may touch: the others' lists hold no counted contact
            rows = rows[self._screen.may_touch(xpos, xmat)]
            if len(rows):
                data, geoms = self._contact_data, []
                for i in rows:
                    self.batch.get_data(int(i), data)
                    geoms.append(data.contact.geom[: data.ncon].copy())
                self._contacts[rows] = self.task.count_contact_lists(geoms)

    def _write_starts(self, ids: NDArray[np.int64], starts: Sequence[Start]) -> None:
        self.batch.reset(ids, stage=mujoco.mjtStage.mjSTAGE_NONE)
        for i, (qpos, qvel, mocap_pos) in zip(ids, starts, strict=True):
            self._state["qpos"][i] = qpos
            self._state["qvel"][i] = qvel
            if mocap_pos is not None:
                self._state["mocap_pos"][i] = mocap_pos
        self.batch.forward(ids)
        self._settle(ids)


class BatchVecEnv(VecEnv):
    """``n_envs`` simulations of one registered arm task, stepped together (an SB3 ``VecEnv``).

    Episodes end as with ``gymnasium.make(env_id)`` (the task's termination, and truncation after the id's
    ``max_episode_steps``), and the env resets itself as SB3's vectorised envs do: the step's info holds
    ``terminal_observation`` and ``TimeLimit.truncated``, the returned observation is the next episode's first, and
    ``reset_infos`` the reset's info. Seeding follows SB3: ``seed(s)`` makes env ``i``'s next reset use seed
    ``s + i`` (its own generator, as ``gymnasium.make(env_id).reset(seed=s + i)``).

    ``scripted_starts``: ``grasp_envs.wrappers.ScriptedStarts``' arguments (``probability``, ``steps``,
    ``hold_height``), run batched on the Grasper: a training aid, never for evaluation envs.

    ``monitor``: record each episode as SB3's ``Monitor`` does inside the envs of ``make_vec_env`` (``info["episode"]``
    with the return, the length, the time and ``info_keywords``; rows in ``monitor_file`` when given), so that the
    VecEnv wrappers above it are the same as above a ``DummyVecEnv`` of monitored envs (``sync_envs_normalization``
    between a training and an evaluation env needs that) and ``env_is_wrapped(Monitor)`` is true.

    Every argument is checked before the simulations are built: a value of the wrong type or out of range raises
    ``ValueError`` naming the argument and the value (``ARGUMENT_RULES``; the task's options by its options
    dataclass, the scripted starts' by ``ScriptedStartOptions``), and an unknown option ``TypeError`` naming it.

    :param env_id: a registered id of ``grasp_envs`` (``grasp_envs.ENV_IDS``)
    :param n_envs: number of simulations
    :param n_threads: threads stepping the physics (``mujoco.batch``); 0 uses every CPU
    :param scripted_starts: ``None``, or ``ScriptedStarts``' keyword arguments
    :param monitor: record episodes as ``Monitor`` does
    :param monitor_file: ``None``, or the CSV (``.monitor.csv`` is appended) the episodes are written to
    :param info_keywords: info keys recorded with each episode
    :param options: the id's options to override (the fields of the task's options dataclass, e.g.
        ``Grasper3DOptions``), and Gymnasium's rendering arguments (``render_mode``, ``width``, ``height``,
        ``camera_id``, ``camera_name``, ``default_camera_config``)
    """

    action_space: Box
    observation_space: Box
    env_id: str
    spec: Any  # gymnasium's EnvSpec
    task: ArmTask
    physics: BatchPhysics
    batch: Any  # mujoco.batch.Batch
    model: mujoco.MjModel
    sim: SimArrays
    max_episode_steps: int | None
    _scripted: ScriptedStartOptions | None
    _render_kwargs: dict[str, Any]
    _monitor: bool
    _info_keywords: tuple[str, ...]
    _episode_steps: NDArray[np.int64]
    _episode_returns: NDArray[np.float64]
    _observations: NDArray[np.float64]
    _t_start: float

    def __init__(
        self,
        env_id: str,
        n_envs: int,
        n_threads: int = 1,
        scripted_starts: dict[str, Any] | None = None,
        monitor: bool = False,
        monitor_file: str | os.PathLike[str] | None = None,
        info_keywords: Sequence[str] = (),
        **options: Any,
    ):
        check_arguments(
            "BatchVecEnv",
            ARGUMENT_RULES,
            {
                "env_id": env_id,
                "n_envs": n_envs,
                "n_threads": n_threads,
                "scripted_starts": scripted_starts,
                "monitor": monitor,
                "monitor_file": monitor_file,
                "info_keywords": info_keywords,
            },
        )
        n_envs, n_threads = int(n_envs), int(n_threads)
        spec = gym.spec(env_id)
        env_class = load_env_creator(spec.entry_point) if isinstance(spec.entry_point, str) else spec.entry_point
        if not (isinstance(env_class, type) and issubclass(env_class, ArmEnv)):
            raise ValueError(f"make_batch_env runs the tasks of grasp_envs (grasp_envs.ENV_IDS), got {env_id!r}")
        task_options, rendering = env_class.options_class.from_keywords({**spec.kwargs, **options}, env_id, RENDER_ARGUMENTS)
        rendering.setdefault("default_camera_config", env_class.default_camera)
        self.env_id = env_id
        self.spec = spec
        self.task = task = env_class.task_class(task_options)
        self._render_kwargs = rendering
        self.render_mode: str | None = rendering.get("render_mode")
        self.max_episode_steps = spec.max_episode_steps
        self.physics = physics = BatchPhysics(task, n_envs, n_threads)
        self.model, self.batch, self.sim = physics.model, physics.batch, physics.sim
        self.dt = float(physics.model.opt.timestep) * task.frame_skip
        self._scripted = self._scripted_start_options(scripted_starts)
        observation_space = Box(low=-np.inf, high=np.inf, shape=(task.observation_dim,), dtype=np.float64)
        self._env_attributes: list[dict[str, Any]] = [{} for _ in range(n_envs)]  # set_attr's new per-env attributes
        super().__init__(n_envs, observation_space, physics.action_space)
        self._rngs: list[np.random.Generator | None] = [None] * n_envs
        self._episode_steps = np.zeros(n_envs, dtype=np.int64)
        self._observations = np.zeros((n_envs, task.observation_dim))
        self._actions: NDArray[np.float64] | None = None
        self._monitor = monitor
        self._info_keywords = tuple(info_keywords)
        self._episode_returns = np.zeros(n_envs)
        self._t_start = time.time()
        self._results_writer: ResultsWriter | None = None
        if monitor_file is not None:
            if not monitor:
                raise ValueError("monitor_file needs monitor=True")
            header = {"t_start": self._t_start, "env_id": env_id}
            self._results_writer = ResultsWriter(os.fspath(monitor_file), header=header, extra_keys=self._info_keywords)
        self._renderers: dict[int, Any] = {}  # one per simulation, as each Gymnasium env has its own camera state
        self._render_data: mujoco.MjData | None = None

    def _scripted_start_options(self, arguments: dict[str, Any] | None) -> ScriptedStartOptions | None:
        """The scripted starts' options (``None``: none, or ``probability`` 0), checked."""
        if arguments is None:
            return None
        if not isinstance(self.task, Grasper3DTask):
            raise TypeError(f"scripted_starts runs the Grasper's scripted grasp, {self.env_id} is another task")
        options, _ = ScriptedStartOptions.from_keywords(arguments, "scripted_starts")
        return options if options.probability > 0 else None

    def _rng(self, i: int) -> np.random.Generator:
        if self._rngs[i] is None:
            self._rngs[i], _ = seeding.np_random(None)
        return self._rngs[i]  # type: ignore[return-value]

    def _reset_envs(self, ids: NDArray[np.int64]) -> tuple[NDArray[np.float64], list[dict[str, Any]]]:
        """Start the simulations ``ids`` afresh (with scripted starts, where asked for), each with its generator."""
        rngs = [self._rng(int(i)) for i in ids]
        self.physics.start(ids, rngs)
        if self._scripted is not None:
            scripted_starts(self.physics, ids, rngs, self._scripted)
        self._episode_steps[ids] = 0
        observation = self.task.observe(self.sim)
        info = self.task.reset_info(self.sim)
        return observation[ids], [info_of(info, int(i)) for i in ids]

    # ------------------------------------------------------------------ VecEnv
    def reset(self) -> VecEnvObs:
        if any(self._options):
            raise ValueError(f"{type(self).__name__}.reset takes no options (the tasks have none), got {self._options}")
        for i, seed in enumerate(self._seeds):
            if seed is not None:
                self._rngs[i], _ = seeding.np_random(seed)
        observations, infos = self._reset_envs(np.arange(self.num_envs))
        self._observations[:] = observations
        self.reset_infos = infos
        self._reset_seeds()
        self._reset_options()
        return self._observations.copy()

    def step_async(self, actions: NDArray[Any]) -> None:
        self._actions = actions

    def _checked_actions(self, actions: Any) -> NDArray[np.float64]:
        actions = np.asarray(actions, dtype=np.float64)
        if actions.shape != (self.num_envs, *self.action_space.shape):
            raise ValueError(
                f"{type(self).__name__}.step expects actions of shape {(self.num_envs, *self.action_space.shape)}, "
                f"got {actions.shape}"
            )
        finite = np.isfinite(actions).all(axis=1)
        if not finite.all():
            i = int(np.flatnonzero(~finite)[0])
            raise ValueError(f"{type(self).__name__}.step got a non-finite action for env {i}: {actions[i]}")
        return np.clip(actions, self.action_space.low, self.action_space.high)

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("step_wait called without step_async")
        actions = self._checked_actions(self._actions)
        self._actions = None
        observation, reward, terminated, info = self.physics.step(actions)
        self._episode_steps += 1
        limit = self.max_episode_steps
        truncated = self._episode_steps >= limit if limit is not None else np.zeros(self.num_envs, dtype=bool)
        done = terminated | truncated
        info["TimeLimit.truncated"] = truncated & ~terminated  # as SB3's DummyVecEnv: on every step
        infos = infos_of(info, self.num_envs)
        ids = np.flatnonzero(done)
        if self._monitor:
            self._record_episodes(reward, ids, infos)
        for index in ids:
            infos[index]["terminal_observation"] = observation[index].copy()
        if len(ids):
            observation[ids], reset_infos = self._reset_envs(ids)
            for index, reset_info in zip(ids, reset_infos, strict=True):
                self.reset_infos[index] = reset_info
        self._observations[:] = observation
        return self._observations.copy(), reward.astype(np.float32), done, infos

    def _record_episodes(self, reward: NDArray[np.float64], ended: NDArray[np.int64], infos: list[dict[str, Any]]) -> None:
        """``Monitor``'s bookkeeping for every env: the returns summed in float64, each ended episode in its info."""
        self._episode_returns += reward
        for index in ended:
            episode = {
                "r": round(float(self._episode_returns[index]), 6),
                "l": int(self._episode_steps[index]),
                "t": round(time.time() - self._t_start, 6),
            }
            for key in self._info_keywords:
                episode[key] = infos[index][key]
            if self._results_writer is not None:
                self._results_writer.write_row(episode)
            infos[index]["episode"] = episode
            self._episode_returns[index] = 0.0

    def close(self) -> None:
        if self._results_writer is not None:
            self._results_writer.close()
            self._results_writer = None
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()

    def get_images(self) -> Sequence[NDArray[np.uint8] | None]:
        if self.render_mode != "rgb_array":
            raise ValueError(f"rendering images needs render_mode='rgb_array', this env has {self.render_mode!r}")
        return [self.render_env(i) for i in range(self.num_envs)]

    def render_env(self, i: int) -> NDArray[np.uint8]:
        """An ``rgb_array`` image of simulation ``i``, as ``gymnasium.make(env_id, render_mode="rgb_array")`` renders."""
        from gymnasium.envs.mujoco.mujoco_rendering import MujocoRenderer

        if i not in self._renderers:
            model = self.model
            width, height = self._render_kwargs.get("width", 480), self._render_kwargs.get("height", 480)
            model.vis.global_.offwidth = max(model.vis.global_.offwidth, width)
            model.vis.global_.offheight = max(model.vis.global_.offheight, height)
            if self._render_data is None:
                self._render_data = mujoco.MjData(model)
            self._renderers[i] = MujocoRenderer(
                model,
                self._render_data,
                self._render_kwargs.get("default_camera_config"),
                width,
                height,
                self._render_kwargs.get("max_geom", 1000),
                self._render_kwargs.get("camera_id"),
                self._render_kwargs.get("camera_name"),
                self._render_kwargs.get("visual_options", {}),
            )
        self.batch.get_data(i, self._render_data)  # with the derived fields of the last step, as MjData after mj_step
        return self._renderers[i].render("rgb_array")

    def _indices(self, indices: VecEnvIndices) -> list[int]:
        return list(self._get_indices(indices))

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Per env: an attribute set for it with ``set_attr``, else the task's (``self.task``; a per-simulation array
        gives env ``i`` its row), else the batch's (``dt``, ``spec``, ``render_mode``, ...)."""
        values = []
        for i in self._indices(indices):
            if attr_name in self._env_attributes[i]:
                values.append(self._env_attributes[i][attr_name])
                continue
            target = self.task if hasattr(self.task, attr_name) else self
            if not hasattr(target, attr_name):
                raise AttributeError(f"{self.env_id} has no attribute {attr_name!r}")
            value = getattr(target, attr_name)
            per_env = target is self.task and isinstance(value, np.ndarray) and value.shape[:1] == (self.num_envs,)
            values.append(value[i] if per_env else value)
        return values

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set a per-simulation task array's rows for ``indices``; an option of the task only for all envs at once
        (the simulations share it); any other name as an attribute of each env in ``indices``."""
        rows = self._indices(indices)
        current = getattr(self.task, attr_name, None)
        if isinstance(current, np.ndarray) and current.shape[:1] == (self.num_envs,):
            current[rows] = value
        elif hasattr(self.task, attr_name):
            if sorted(rows) != list(range(self.num_envs)):
                raise ValueError(
                    f"{attr_name!r} is an option of all {self.num_envs} simulations of the batch: set it for all envs"
                )
            if attr_name in self.task.options.names():  # checked as when the options were made
                self.task.options = dataclasses.replace(self.task.options, **{attr_name: value})
            else:
                setattr(self.task, attr_name, value)
        else:
            for i in rows:
                self._env_attributes[i][attr_name] = value

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method of the task over the batch (``task.method(sim, *args)``), and give env ``i`` its row."""
        method = getattr(self.task, method_name, None)
        if not callable(method):
            raise AttributeError(f"{type(self.task).__name__} has no method {method_name!r}")
        result = method(self.sim, *method_args, **method_kwargs)
        return [result[i] for i in self._indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper[Any, Any, Any, Any]], indices: VecEnvIndices = None
    ) -> list[bool]:
        wrapped = (self._scripted is not None and issubclass(ScriptedStarts, wrapper_class)) or (
            self._monitor and issubclass(Monitor, wrapper_class)
        )
        return [wrapped for _ in self._indices(indices)]


def make_batch_env(
    env_id: str,
    n_envs: int = 1,
    seed: int | None = None,
    n_threads: int = 1,
    wrapper_class: Any = None,
    wrapper_kwargs: dict[str, Any] | None = None,
    monitor: bool = True,
    info_keywords: Sequence[str] = ("is_success",),
    monitor_file: str | os.PathLike[str] | None = None,
    **options: Any,
) -> BatchVecEnv:
    """``n_envs`` simulations of ``env_id`` in one batched SB3 ``VecEnv`` (``BatchVecEnv``), as SB3's
    ``make_vec_env`` would make them: seeded with ``seed`` (env ``i``: ``seed + i``) and, with ``monitor``, recording
    episodes as ``Monitor`` (returns, lengths and ``info_keywords`` in ``info["episode"]``; rows in ``monitor_file``).

    ``wrapper_class``: ``None`` or ``grasp_envs.wrappers.ScriptedStarts`` (run batched, with ``wrapper_kwargs``);
    the batch has no per-env Gymnasium envs to wrap, so any other wrapper is refused.

    Every argument is checked before the simulations are built: a value of the wrong type or out of range raises
    ``ValueError`` naming the argument and the value.
    """
    check_arguments(
        "make_batch_env",
        ARGUMENT_RULES,
        {
            "env_id": env_id,
            "n_envs": n_envs,
            "seed": seed,
            "n_threads": n_threads,
            "wrapper_class": wrapper_class,
            "wrapper_kwargs": wrapper_kwargs,
            "monitor": monitor,
            "info_keywords": info_keywords,
            "monitor_file": monitor_file,
        },
    )
    scripted = None
    if wrapper_class is not None:
        scripted = dict(wrapper_kwargs or {})
    elif wrapper_kwargs:
        raise TypeError("wrapper_kwargs given without wrapper_class")
    env = BatchVecEnv(
        env_id,
        n_envs,
        n_threads,
        scripted_starts=scripted,
        monitor=monitor,
        monitor_file=monitor_file,
        info_keywords=info_keywords,
        **options,
    )
    if seed is not None:
        env.seed(seed)
    return env
