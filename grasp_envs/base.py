"""Shared machinery of the arm tasks, written once over a leading simulation axis.

A task (``ArmTask``) computes controls, observations, rewards, success, termination and reset states for ``n``
simulations at once from ``SimArrays``: views with a leading simulation axis, either of one ``MjData`` (the Gymnasium
env, a batch of one) or of a ``mujoco.batch.Batch`` (``grasp_envs.make_batch_env``). Its options are one frozen
dataclass (a ``TaskOptions``). ``Physics`` runs a task's step on ``n`` simulations, whichever holds them
(``DataPhysics``: one ``MjData``; ``grasp_envs.batch.BatchPhysics``: a batch). ``ArmEnv`` is the Gymnasium face of a
task; ``grasp_envs.batch.BatchVecEnv`` its SB3 VecEnv face.
"""

from __future__ import annotations

import inspect
from collections.abc import Sequence
from dataclasses import fields
from os import path
from typing import TYPE_CHECKING, Any, ClassVar

import mujoco
import numpy as np
from gymnasium import utils
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.spaces import Box
from numpy.typing import NDArray

from grasp_envs.options import Options

ASSETS = path.join(path.dirname(__file__), "assets")

DEFAULT_CAMERA_CONFIG_3D: dict[str, Any] = {
    "distance": 0.75,
    "elevation": -30.0,
    "azimuth": 135.0,
    "lookat": np.array([0.0, 0.0, -0.12]),
}

INSTABILITY_WARNINGS = np.array(
    [
        mujoco.mjtWarning.mjWARN_BADQPOS,
        mujoco.mjtWarning.mjWARN_BADQVEL,
        mujoco.mjtWarning.mjWARN_BADQACC,
        mujoco.mjtWarning.mjWARN_BADCTRL,
    ],
    dtype=np.int64,
)
# MjData fields the tasks read, each as an (n, ...) array
SIM_FIELDS = (
    "qpos",
    "qvel",
    "ctrl",
    "mocap_pos",
    "xpos",
    "xmat",
    "site_xpos",
    "geom_xpos",
    "geom_xmat",
    "actuator_force",
    "qfrc_bias",
    "cdof",
    "subtree_com",
)

# Gymnasium MujocoEnv's arguments that only concern rendering: every env takes them besides its task's options
RENDER_ARGUMENTS = (
    "render_mode",
    "width",
    "height",
    "camera_id",
    "camera_name",
    "default_camera_config",
    "max_geom",
    "visual_options",
)

Array = NDArray[np.float64]
Start = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]  # qpos, qvel, mocap_pos (or None)


class SimArrays:
    """The state of ``n`` simulations of one model, each MjData field (``SIM_FIELDS``) an ``(n, ...)`` array.

    ``SimArrays.of_data(model, data)`` views one ``MjData`` as a batch of one; ``SimArrays.of_batch(batch)`` binds a
    ``mujoco.batch.Batch``. Either way the arrays stay live: they show the state after every physics call.
    """

    qpos: Array
    qvel: Array
    ctrl: Array
    mocap_pos: Array
    xpos: Array
    xmat: Array
    site_xpos: Array
    geom_xpos: Array
    geom_xmat: Array
    actuator_force: Array
    qfrc_bias: Array
    cdof: Array
    subtree_com: Array

    def __init__(
        self,
        model: mujoco.MjModel,
        arrays: dict[str, Array],
        warnings: NDArray[np.int32],
        data: mujoco.MjData | None = None,
        contacts: Array | None = None,
    ):
        self.model = model
        self.data = data
        self.contacts = contacts
        # (body, columns) -> the dofs among the columns that move the body, and where (grasp_envs.control)
        self.chains: dict[tuple[int, tuple[int, ...] | None], tuple[NDArray[np.int64], NDArray[np.int64], int]] = {}
        self.n = len(arrays["qpos"])
        for name in SIM_FIELDS:
            setattr(self, name, arrays[name])
        self._warnings = warnings

    @classmethod
    def of_data(cls, model: mujoco.MjModel, data: mujoco.MjData) -> SimArrays:
        return cls(model, {name: getattr(data, name)[None] for name in SIM_FIELDS}, data.warning.number[None], data)

    def take(self, ids: NDArray[np.int64]) -> SimArrays:
        """A copy of the simulations ``ids``' arrays (a smaller batch, for computing on a subset)."""
        arrays = {name: getattr(self, name)[ids] for name in SIM_FIELDS}
        contacts = None if self.contacts is None else self.contacts[ids]
        subset = SimArrays(self.model, arrays, self._warnings[ids], contacts=contacts)
        subset.chains = self.chains  # the same model: the same kinematic chains
        return subset

    def instability_warnings(self) -> NDArray[np.int64]:
        """Per simulation, how many times MuJoCo has reset a diverging state (bad qpos, qvel, qacc or ctrl)."""
        return self._warnings[:, INSTABILITY_WARNINGS].sum(axis=1, dtype=np.int64)


def near_bonus(distance: Array, weight: float, scale: float) -> Array:
    """The reachers' precision term ``weight (1 - tanh(distance / scale))``: bounded in ``[0, weight]`` and steepest at
    the target, so that the last centimetres before it pay."""
    return weight * (1.0 - np.tanh(distance / scale))


def norm(vectors: Array) -> Array:
    """Euclidean norm over the last axis (as a stack of dot products, so that each equals ``np.linalg.norm`` of the
    one vector: bit-equal results whatever the batch size)."""
    return np.sqrt((vectors[..., None, :] @ vectors[..., :, None])[..., 0, 0])


def asset_path(xml_file: str) -> str:
    """Absolute path of a model: an existing path is used as given, a bare name is looked up in our assets."""
    if path.isabs(xml_file) or path.exists(xml_file):
        return path.abspath(xml_file)
    return path.join(ASSETS, xml_file)


class TaskOptions(Options):
    """Base of each task's options dataclass (``@dataclass(frozen=True)``, every field made by ``option``).

    Every task has the options ``xml_file`` (its MuJoCo model) and ``frame_skip`` (physics steps per action); each
    dataclass defines them as fields, with its own defaults, and they are declared here for the code that reads them.
    """

    xml_file: str | None
    frame_skip: int


class ArmTask:
    """One arm task over ``n`` simulations: everything but the physics stepping, batch-first.

    Made from the task's options (``options``, a ``TaskOptions`` dataclass, checked when it was made); the options
    also read as the task's attributes (``task.reset_noise_scale``), as a VecEnv's ``get_attr`` asks for them.
    Subclasses set ``observation_dim`` and ``contact_pairs`` (geom name pairs whose contacts the task counts in
    MuJoCo's contact list, ``contact_counts``), and implement ``observe``, ``reward`` (``(reward, info)``
    with ``info`` arrays, one ``reward_<term>`` per term), ``success`` and ``sample_start``. Per-simulation task
    state (e.g. whether the wall was touched) lives in arrays of length ``n`` set up by ``setup``.
    """

    contact_pairs: ClassVar[tuple[tuple[str, str], ...]] = ()
    observation_dim: int
    options: TaskOptions

    def __init__(self, options: TaskOptions):
        self.options = options
        self.n = 0

    if not TYPE_CHECKING:  # at run time only, so that the type checker still checks the tasks' own attributes

        def __getattr__(self, name: str) -> Any:
            options = self.__dict__.get("options")
            if options is None or name not in options.names():
                raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")
            return getattr(options, name)

    @property
    def xml_file(self) -> str:
        """The model's XML file: the ``xml_file`` option."""
        xml_file = self.options.xml_file
        assert xml_file is not None, f"{type(self).__name__} must choose its model where xml_file is None"
        return xml_file

    @property
    def frame_skip(self) -> int:
        """Physics steps per action: the ``frame_skip`` option."""
        return int(self.options.frame_skip)

    # ------------------------------------------------------------------ the model
    def build_model(self) -> mujoco.MjModel:
        """The task's model: its XML, edited by ``edit_spec``."""
        spec = mujoco.MjSpec.from_file(asset_path(self.xml_file))
        self.edit_spec(spec)
        return spec.compile()

    def edit_spec(self, spec: mujoco.MjSpec) -> None:
        """Change the model before it is compiled (the Grasper adds the cube's turning joint)."""

    def setup(self, model: mujoco.MjModel, n: int) -> None:
        """Look the model's names up once and make the per-simulation task state for ``n`` simulations."""
        self.model = model
        self.n = n
        self.init_qpos = model.qpos0.copy()
        self.init_qvel = np.zeros(model.nv)
        self.ctrl_low = model.actuator_ctrlrange[:, 0].copy()
        self.ctrl_high = model.actuator_ctrlrange[:, 1].copy()
        self.default_mocap_pos = mujoco.MjData(model).mocap_pos.copy()
        # geom id pair (either order) -> index in contact_pairs, or -1
        self._pair_of_geoms = np.full((model.ngeom, model.ngeom), -1, dtype=np.int64)
        for index, (first, second) in enumerate(self.contact_pairs):
            a, b = model.geom(first).id, model.geom(second).id
            self._pair_of_geoms[a, b] = self._pair_of_geoms[b, a] = index

    def action_space(self, model: mujoco.MjModel) -> Box:
        """The actuators' control ranges, as Gymnasium's ``MujocoEnv`` makes them."""
        low, high = model.actuator_ctrlrange.copy().astype(np.float32).T
        return Box(low=low, high=high, dtype=np.float32)

    def geom_id(self, name: str) -> int:
        return int(self.model.geom(name).id)

    def site_id(self, name: str) -> int:
        return int(self.model.site(name).id)

    def count_contacts(self, data: mujoco.MjData) -> NDArray[np.float64]:
        """Contacts between each ``contact_pairs`` pair in ``data``'s contact list, ``(len(contact_pairs),)``."""
        return self.count_contact_lists([data.contact.geom[: data.ncon]])[0]

    def count_contact_lists(self, geoms: list[NDArray[np.int32]]) -> NDArray[np.float64]:
        """``count_contacts`` of several simulations' contact lists (geom id pairs, ``(ncon, 2)`` each) in one go,
        ``(len(geoms), len(contact_pairs))``."""
        n_pairs = len(self.contact_pairs)
        sims = np.repeat(np.arange(len(geoms)), [len(g) for g in geoms])
        stacked = np.concatenate(geoms) if geoms else np.zeros((0, 2), dtype=np.int32)
        pairs = self._pair_of_geoms[stacked[:, 0], stacked[:, 1]]
        found = pairs >= 0
        counts = np.bincount(sims[found] * n_pairs + pairs[found], minlength=len(geoms) * n_pairs)
        return counts.reshape(len(geoms), n_pairs).astype(np.float64)

    def contact_counts(self, sim: SimArrays) -> NDArray[np.float64]:
        """Contacts between each ``contact_pairs`` pair, ``(n, len(contact_pairs))``: those of the last collision
        detection (``MjData.contact`` after ``mj_step`` or ``mj_forward``; a batch keeps them in ``sim.contacts``)."""
        if sim.data is not None:
            return self.count_contacts(sim.data)[None]
        assert sim.contacts is not None
        return sim.contacts

    # ------------------------------------------------------------------ the step
    def controls(self, sim: SimArrays, action: Array, ids: NDArray[np.int64] | None = None) -> Array:
        """The actuator controls ``(n, nu)`` of the (checked, clipped) actions ``(n, action_dim)``; ``ids``: the rows
        of the task state that ``sim`` holds, when it holds a subset (``SimArrays.take``)."""
        return action

    def transition(
        self, sim: SimArrays, action: Array, unstable: NDArray[np.bool_]
    ) -> tuple[Array, Array, NDArray[np.bool_], dict[str, NDArray[Any]]]:
        """Observation, reward, termination and info arrays after a physics step of every simulation.

        A simulation that became unstable (MuJoCo reset it), or whose reward or observation is not finite, ends its
        episode with reward 0, every ``reward_<term>`` 0, non-finite observation entries 0 and ``unstable`` true.
        """
        observation = self.observe(sim)
        reward, info = self.reward(sim, action)
        terminated = self.terminal(sim)
        info["is_success"] = self.success(sim)
        bad = unstable | ~np.isfinite(reward) | ~np.isfinite(observation).all(axis=1)
        if bad.any():
            reward = np.where(bad, 0.0, reward)
            for key in info:
                if key.startswith("reward_"):
                    info[key] = np.where(bad, 0.0, info[key])
            observation[bad] = np.nan_to_num(observation[bad], nan=0.0, posinf=0.0, neginf=0.0)
            terminated = terminated | bad
        info["unstable"] = bad
        return observation, reward, terminated, info

    def observe(self, sim: SimArrays) -> Array:  # pragma: no cover - abstract
        raise NotImplementedError

    def reward(self, sim: SimArrays, action: Array) -> tuple[Array, dict[str, NDArray[Any]]]:  # pragma: no cover
        raise NotImplementedError

    def success(self, sim: SimArrays) -> NDArray[np.bool_]:  # pragma: no cover - abstract
        raise NotImplementedError

    def terminal(self, sim: SimArrays) -> NDArray[np.bool_]:
        return np.zeros(sim.n, dtype=bool)

    # ------------------------------------------------------------------ the reset
    def sample_start(self, rng: np.random.Generator) -> Start:  # pragma: no cover
        """One simulation's start state drawn with its generator: ``qpos``, ``qvel`` and the mocap positions (or
        ``None`` to keep the model's)."""
        raise NotImplementedError

    def started(self, sim: SimArrays, ids: NDArray[np.int64]) -> None:
        """Set the task state of the simulations ``ids`` after their start state was written and forwarded."""

    def reset_info(self, sim: SimArrays) -> dict[str, NDArray[Any]]:
        return {"is_success": self.success(sim), "unstable": np.zeros(sim.n, dtype=bool)}


def info_of(info: dict[str, NDArray[Any]], i: int) -> dict[str, Any]:
    """Simulation ``i``'s info dict, with Python scalars."""
    return {key: value[i].item() for key, value in info.items()}


def infos_of(info: dict[str, NDArray[Any]], n: int) -> list[dict[str, Any]]:
    """Every simulation's info dict, with Python scalars (``info_of`` for each, in one conversion per key)."""
    keys = list(info)
    rows = zip(*(value.tolist() for value in info.values()), strict=True) if keys else ((),) * n
    return [dict(zip(keys, row, strict=True)) for row in rows]


class Physics:
    """The physics of ``n`` simulations of one task, and the task's step on them, written once for every face.

    ``step`` is the sequence of an env step: the task's controls of the actions, ``frame_skip`` physics steps,
    MuJoCo's instability check, the task's transition. ``simulate`` is that step without the transition, for any
    subset of the simulations (the scripted starts step some while others wait); ``start`` draws and writes start
    states. Where the simulations live is a subclass's: ``DataPhysics`` one ``MjData`` (the Gymnasium env),
    ``grasp_envs.batch.BatchPhysics`` a ``mujoco.batch.Batch`` (the batched VecEnv). ``sim`` views their state.
    """

    sim: SimArrays

    def __init__(self, task: ArmTask, model: mujoco.MjModel, n: int):
        self.task = task
        self.model = model
        self.n = n
        self.action_space = task.action_space(model)
        task.setup(model, n)

    # ------------------------------------------------------------------ where the simulations live
    def _run(self, ids: NDArray[np.int64] | None) -> None:  # pragma: no cover - abstract
        """Step the simulations ``ids`` (all: ``None``) ``frame_skip`` times with the controls in ``sim.ctrl``."""
        raise NotImplementedError

    def _restore(self, ids: NDArray[np.int64]) -> None:  # pragma: no cover - abstract
        """Put the simulations ``ids`` back into the model's default state (forwarded)."""
        raise NotImplementedError

    def _settle(self, ids: NDArray[np.int64] | None) -> None:
        """After a physics call on ``ids`` (all: ``None``): make ``sim`` show its results, where it needs to."""

    def _write_starts(self, ids: NDArray[np.int64], starts: Sequence[Start]) -> None:  # pragma: no cover - abstract
        """Write the start states of ``ids`` (one each) and forward them."""
        raise NotImplementedError

    # ------------------------------------------------------------------ the step
    def simulate(
        self, actions: Array, ids: NDArray[np.int64] | None = None, sim: SimArrays | None = None
    ) -> NDArray[np.bool_]:
        """Step the simulations ``ids`` (all: ``None``) with the task's controls of ``actions`` (checked, clipped,
        one row each); return which became unstable (MuJoCo resets a simulation and counts a warning when its
        positions, velocities, accelerations or controls become non-finite or huge), each put back into its default
        state. ``sim``: the arrays of ``ids`` the controls are computed from, where the caller holds them already
        (``SimArrays.take``)."""
        rows = slice(None) if ids is None else ids
        view = self.sim if ids is None else (sim if sim is not None else self.sim.take(ids))
        ctrl = self.task.controls(view, actions, ids)
        before = self.sim.instability_warnings()[rows].copy()
        self.sim.ctrl[rows] = ctrl
        self._run(ids)
        unstable = (self.sim.instability_warnings()[rows] > before) | ~np.isfinite(self.sim.qvel[rows]).all(axis=1)
        diverged = (np.arange(self.n) if ids is None else ids)[unstable]
        if len(diverged):
            self._restore(diverged)
        self._settle(ids)
        return unstable

    def step(self, actions: Array) -> tuple[Array, Array, NDArray[np.bool_], dict[str, NDArray[Any]]]:
        """Every simulation's step with ``actions`` (checked, clipped): observation, reward, termination and info
        arrays (``ArmTask.transition``)."""
        unstable = self.simulate(actions)
        return self.task.transition(self.sim, actions, unstable)

    # ------------------------------------------------------------------ the reset
    def start(self, ids: NDArray[np.int64], rngs: Sequence[np.random.Generator]) -> None:
        """Draw the start states of the simulations ``ids``, each with its own generator, and start them there."""
        starts = [self.task.sample_start(rng) for rng in rngs]
        self._write_starts(ids, starts)
        self.task.started(self.sim, ids)


class DataPhysics(Physics):
    """One simulation in one ``MjData``: a batch of one. Its start states are written into a reset ``MjData`` (the
    Gymnasium env's reset resets it first; an unstable step leaves it reset)."""

    def __init__(self, task: ArmTask, model: mujoco.MjModel, data: mujoco.MjData):
        super().__init__(task, model, 1)
        self.data = data
        self.sim = SimArrays.of_data(model, data)

    def _run(self, ids: NDArray[np.int64] | None) -> None:
        mujoco.mj_step(self.model, self.data, nstep=self.task.frame_skip)

    def _restore(self, ids: NDArray[np.int64]) -> None:
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_forward(self.model, self.data)

    def _write_starts(self, ids: NDArray[np.int64], starts: Sequence[Start]) -> None:
        [(qpos, qvel, mocap_pos)] = starts
        if mocap_pos is not None:
            self.data.mocap_pos[:] = mocap_pos
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)


class ArmEnv(MujocoEnv, utils.EzPickle):
    """The Gymnasium face of an ``ArmTask``: one simulation, a batch of one (not registered itself).

    A task's env class names its options (``options_class``, a ``TaskOptions`` dataclass), its task (``task_class``)
    and the camera of ``render()`` (``default_camera``). Its constructor takes the options and Gymnasium's rendering
    arguments (``RENDER_ARGUMENTS``) as keywords, and refuses any other with ``TypeError``; its signature lists the
    options with their defaults (made from the dataclass). ``step`` validates and clips the action and runs the
    task's step (``Physics.step``), which ends the episode with ``info["unstable"] = True`` if MuJoCo had to reset a
    diverging simulation.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}
    options_class: ClassVar[type[TaskOptions]]
    task_class: ClassVar[type[ArmTask]]
    default_camera: ClassVar[dict[str, Any] | None] = None
    __signature__: ClassVar[inspect.Signature]
    action_space: Box  # every arm task has continuous actions
    task: ArmTask

    def __init_subclass__(cls, **kwargs: Any):
        super().__init_subclass__(**kwargs)
        if "options_class" in vars(cls):
            cls.__signature__ = constructor_signature(cls.options_class, cls.default_camera)

    def __init__(self, **kwargs: Any):
        options, rendering = self.options_class.from_keywords(kwargs, type(self).__name__, RENDER_ARGUMENTS)
        rendering.setdefault("default_camera_config", self.default_camera)
        utils.EzPickle.__init__(self, **options.keywords(), **rendering)
        self.task = task = self.task_class(options)
        observation_space = Box(low=-np.inf, high=np.inf, shape=(task.observation_dim,), dtype=np.float64)
        MujocoEnv.__init__(self, asset_path(task.xml_file), task.frame_skip, observation_space=observation_space, **rendering)
        self.metadata = {**ArmEnv.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        self.physics = DataPhysics(task, self.model, self.data)
        self.init_qpos, self.init_qvel = task.init_qpos, task.init_qvel
        self.sim = self.physics.sim

    @property
    def options(self) -> TaskOptions:
        """The task's options."""
        return self.task.options

    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        model = self.task.build_model()
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        return model, mujoco.MjData(model)

    def _set_action_space(self) -> Box:
        self.action_space = self.task.action_space(self.model)
        return self.action_space

    # ------------------------------------------------------------------ stepping
    def _checked_action(self, action: Any) -> Array:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != self.action_space.shape:
            raise ValueError(
                f"{type(self).__name__}.step expects an action of shape {self.action_space.shape}, got {action.shape}"
            )
        if not np.all(np.isfinite(action)):
            raise ValueError(f"{type(self).__name__}.step got a non-finite action: {action}")
        return np.clip(action, self.action_space.low, self.action_space.high)

    def step(self, action: Any) -> tuple[Array, float, bool, bool, dict[str, Any]]:  # type: ignore[override]
        observation, reward, terminated, info = self.physics.step(self._checked_action(action)[None])
        if self.render_mode == "human":
            self.render()
        # truncation is left to the TimeLimit wrapper added by `gymnasium.make`
        return observation[0], float(reward[0]), bool(terminated[0]), False, info_of(info, 0)

    # ------------------------------------------------------------------ reset
    def reset_model(self) -> Array:
        self.physics.start(np.zeros(1, dtype=np.int64), [self.np_random])
        return self._get_obs()

    def _get_obs(self) -> Array:
        return self.task.observe(self.sim)[0]

    def _get_reset_info(self) -> dict[str, Any]:
        return info_of(self.task.reset_info(self.sim), 0)

    def _is_success(self) -> bool:
        return bool(self.task.success(self.sim)[0])

    def _get_rew(self, action: Any) -> tuple[float, dict[str, Any]]:
        reward, info = self.task.reward(self.sim, np.asarray(action, dtype=np.float64)[None])
        return float(reward[0]), info_of(info, 0)

    def site_pos(self, name: str) -> Array:
        return self.data.site(name).xpos


def constructor_signature(options_class: type[TaskOptions], default_camera: dict[str, Any] | None) -> inspect.Signature:
    """An env class's constructor signature: its task's options with their defaults, ``default_camera_config`` and
    the other rendering arguments (``**kwargs``), all keywords."""
    keyword = inspect.Parameter.KEYWORD_ONLY
    parameters = [
        inspect.Parameter(spec.name, keyword, default=spec.default, annotation=spec.type) for spec in fields(options_class)
    ]
    parameters.append(inspect.Parameter("default_camera_config", keyword, default=default_camera, annotation="dict[str, Any]"))
    parameters.append(inspect.Parameter("kwargs", inspect.Parameter.VAR_KEYWORD, annotation="Any"))
    return inspect.Signature(parameters)
