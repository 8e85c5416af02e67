"""Shared machinery of the arm tasks, written once over a leading simulation axis.

A task (``ArmTask``) computes controls, observations, rewards, success, termination and reset states for ``n``
simulations at once from ``SimArrays``: views with a leading simulation axis, either of one ``MjData`` (the Gymnasium
env, a batch of one) or of a ``mujoco.batch.Batch`` (``grasp_envs.make_batch_env``). ``ArmEnv`` is the Gymnasium face
of a task; ``grasp_envs.batch.BatchVecEnv`` its SB3 VecEnv face.
"""

from __future__ import annotations

import os
from os import path
from typing import Any, ClassVar

import mujoco
import numpy as np
from gymnasium import utils
from gymnasium.envs.mujoco import MujocoEnv
from gymnasium.spaces import Box
from numpy.typing import NDArray

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
    "qpos", "qvel", "ctrl", "mocap_pos", "xpos", "xmat", "site_xpos", "geom_xpos", "geom_xmat", "actuator_force",
    "qfrc_bias", "cdof", "subtree_com",
)  # fmt: skip

Array = NDArray[np.float64]


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
        self.chains: dict[int, NDArray[np.int64]] = {}  # body -> the dofs that move it (grasp_envs.control)
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
        return SimArrays(self.model, arrays, self._warnings[ids], contacts=contacts)

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


def check_near_bonus(weight: float, scale: float) -> None:
    check_amount("near_scale", scale, "positive number")
    check_amount("reward_near_weight", weight)


def check_amount(name: str, value: Any, kind: str = "non-negative number") -> None:
    """Raise ``ValueError`` naming the option and the value unless it is a finite real number (a bool is not one) that
    is > 0 (``kind="positive number"``) or >= 0 (``"non-negative number"``); ``None`` passes where ``kind`` ends in
    ``" or None"``."""
    if value is None and kind.endswith(" or None"):
        return
    number = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)
    positive = kind.startswith("positive")
    if not (number and np.isfinite(value) and (value > 0 or (value == 0 and not positive))):
        raise ValueError(f"{name} must be a {kind}, got {value!r}")


def check_frame_skip(frame_skip: Any) -> None:
    if isinstance(frame_skip, bool) or not isinstance(frame_skip, int | np.integer) or frame_skip < 1:
        raise ValueError(f"frame_skip must be an integer >= 1, got {frame_skip!r}")


def asset_path(xml_file: str) -> str:
    """Absolute path of a model: an existing path is used as given, a bare name is looked up in our assets."""
    if path.isabs(xml_file) or path.exists(xml_file):
        return path.abspath(xml_file)
    return path.join(ASSETS, xml_file)


class ArmTask:
    """One arm task over ``n`` simulations: everything but the physics stepping, batch-first.

    Subclasses set ``observation_dim`` and ``contact_pairs`` (geom name pairs whose contacts the task counts, read
    through MuJoCo contact sensors added to the model), and implement ``observe``, ``reward`` (``(reward, info)``
    with ``info`` arrays, one ``reward_<term>`` per term), ``success`` and ``sample_start``. Per-simulation task
    state (e.g. whether the wall was touched) lives in arrays of length ``n`` set up by ``setup``.
    """

    contact_pairs: ClassVar[tuple[tuple[str, str], ...]] = ()

    def __init__(self, xml_file: str, frame_skip: int, observation_dim: int):
        if not isinstance(xml_file, str | os.PathLike):
            raise ValueError(f"xml_file must be a path (str), got {xml_file!r}")
        check_frame_skip(frame_skip)
        self.xml_file = xml_file
        self.frame_skip = int(frame_skip)
        self.observation_dim = observation_dim
        self.n = 0

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
    def sample_start(self, rng: np.random.Generator) -> tuple[Array, Array, Array | None]:  # pragma: no cover
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
    columns = {key: value.tolist() for key, value in info.items()}
    return [{key: column[i] for key, column in columns.items()} for i in range(n)]


class ArmEnv(MujocoEnv, utils.EzPickle):
    """The Gymnasium face of an ``ArmTask``: one simulation, a batch of one (not registered itself).

    ``step`` validates and clips the action, simulates ``frame_skip`` physics steps, and ends the episode with
    ``info["unstable"] = True`` if MuJoCo had to reset a diverging simulation.
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array", "depth_array", "rgbd_tuple"]}
    action_space: Box  # every arm task has continuous actions
    task: ArmTask

    def __init__(self, task: ArmTask, default_camera_config: dict[str, Any] | None, **kwargs: Any):
        self.task = task
        observation_space = Box(low=-np.inf, high=np.inf, shape=(task.observation_dim,), dtype=np.float64)
        MujocoEnv.__init__(
            self,
            asset_path(task.xml_file),
            task.frame_skip,
            observation_space=observation_space,
            default_camera_config=default_camera_config,
            **kwargs,
        )
        self.metadata = {**ArmEnv.metadata, "render_fps": int(np.round(1.0 / self.dt))}
        task.setup(self.model, 1)
        self.init_qpos, self.init_qvel = task.init_qpos, task.init_qvel
        self.sim = SimArrays.of_data(self.model, self.data)

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

    def _simulate(self, action: Array) -> bool:
        """Run ``frame_skip`` physics steps with the controls of ``action``; return whether the simulation became
        unstable (MuJoCo resets ``mjData`` and counts a warning when positions, velocities, accelerations or
        controls become non-finite or huge). An unstable simulation is put back into its default state."""
        ctrl = self.task.controls(self.sim, action[None])
        warnings_before = int(self.sim.instability_warnings()[0])
        self.data.ctrl[:] = ctrl[0]
        mujoco.mj_step(self.model, self.data, nstep=self.frame_skip)
        unstable = int(self.sim.instability_warnings()[0]) > warnings_before or not np.isfinite(self.data.qvel).all()
        if unstable:
            mujoco.mj_resetData(self.model, self.data)
            mujoco.mj_forward(self.model, self.data)
        return unstable

    def step(self, action: Any) -> tuple[Array, float, bool, bool, dict[str, Any]]:  # type: ignore[override]
        action = self._checked_action(action)
        unstable = self._simulate(action)
        observation, reward, terminated, info = self.task.transition(self.sim, action[None], np.array([unstable]))
        if self.render_mode == "human":
            self.render()
        # truncation is left to the TimeLimit wrapper added by `gymnasium.make`
        return observation[0], float(reward[0]), bool(terminated[0]), False, info_of(info, 0)

    # ------------------------------------------------------------------ reset
    def reset_model(self) -> Array:
        qpos, qvel, mocap_pos = self.task.sample_start(self.np_random)
        if mocap_pos is not None:
            self.data.mocap_pos[:] = mocap_pos
        self.set_state(qpos, qvel)
        self.task.started(self.sim, np.zeros(1, dtype=np.int64))
        return self.task.observe(self.sim)[0]

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
