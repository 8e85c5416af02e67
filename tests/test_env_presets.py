"""Every registered id is a preset of one class per task, and reproduces its recorded trajectories exactly."""

from __future__ import annotations

import inspect
import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.wrappers import FlattenObservation, FrameStackObservation, NormalizeObservation, RecordEpisodeStatistics
from stable_baselines3.common.monitor import Monitor

import grasp_envs
from grasp_envs.registration import PRESETS, RECOMMENDED_GRASPER
from grasp_envs.wrappers import ScriptedStarts

TRAJECTORIES = Path(__file__).resolve().parent / "data" / "trajectories"
# recorded option sets beyond the presets: name -> (id, env kwargs, wrapper kwargs)
OPTION_SETS: dict[str, tuple[str, dict[str, Any], dict[str, Any] | None]] = {
    "Grasper3D-v6_ready": ("Grasper3D-v6", {"start_pose": "ready"}, None),
    "Grasper3D-v0_thesis": ("Grasper3D-v0", {"reward_mode": "thesis"}, None),
    # the scripted starts (ScriptedStarts) over the env: 50-99 steps along the grasp, and 0-99 with the cube held 7 cm up
    "Grasper3D-v6_ready_scripted_late": ("Grasper3D-v6", {"start_pose": "ready"}, {"probability": 0.5, "steps": (50, 100)}),
    "Grasper3D-v4_scripted_hold": ("Grasper3D-v4", {}, {"probability": 0.6, "steps": (0, 100), "hold_height": 0.07}),
}
CASES = {env_id: (env_id, {}, None) for env_id in grasp_envs.ENV_IDS if (TRAJECTORIES / f"{env_id}.npz").exists()}
CASES |= OPTION_SETS | {"Grasper3D-v7": ("Grasper3D-v7", {}, None)}


# The recordings were made on an Intel Xeon; MuJoCo's arithmetic differs across CPUs in the last bits (its SIMD code
# paths), and contacts amplify that: on an AMD EPYC the 600-row grasps with scripted starts drift by up to 3e-8
# (relative), the 300-row ones by 2e-10 at most. A changed task moves observations, rewards and infos far more.
TOLERANCE = {"rtol": 1e-6, "atol": 1e-6}


def _replay(env_id: str, env_kwargs: dict[str, Any], wrapper_kwargs: dict[str, Any] | None, recorded: Any) -> None:
    env = gym.make(env_id, **env_kwargs)
    if wrapper_kwargs is not None:
        env = ScriptedStarts(env, **wrapper_kwargs)
    keys = [str(k) for k in recorded["info_keys"]]
    first = True
    for t, action in enumerate(recorded["actions"]):
        if np.isnan(recorded["rewards"][t]):  # an episode's first row: reset
            observation, info = env.reset(seed=int(recorded["seed"]) if first else None)
            first = False
            reward, terminated, truncated = np.nan, False, False
        else:
            observation, reward, terminated, truncated, info = env.step(action)
        np.testing.assert_allclose(observation, recorded["observations"][t], **TOLERANCE, err_msg=f"row {t}")
        np.testing.assert_allclose(reward, recorded["rewards"][t], **TOLERANCE, err_msg=f"row {t}")
        assert (terminated, truncated) == (recorded["terminated"][t], recorded["truncated"][t]), f"row {t}"
        values = np.array([float(info.get(k, np.nan)) for k in keys])
        np.testing.assert_allclose(values, recorded["infos"][t], **TOLERANCE, err_msg=f"row {t}: {keys}")


@pytest.mark.parametrize("name", sorted(CASES))
def test_preset_replays_its_recorded_trajectory(name: str) -> None:
    env_id, env_kwargs, wrapper_kwargs = CASES[name]
    recording = "Grasper3D-v6_ready" if name == "Grasper3D-v7" else name  # v7 is v6 with the ready pose
    _replay(env_id, env_kwargs, wrapper_kwargs, np.load(TRAJECTORIES / f"{recording}.npz"))


def test_every_id_is_a_preset_of_one_class_per_task() -> None:
    classes = {gym.spec(env_id).entry_point for env_id in grasp_envs.ENV_IDS}
    assert classes == {preset.entry_point for preset in PRESETS.values()}
    assert len(classes) == 4  # Reacher2D, Reacher3D, WallReacher3D, Grasper3D
    for env_id, preset in PRESETS.items():
        spec = gym.spec(env_id)
        assert spec.kwargs == preset.kwargs and spec.max_episode_steps == preset.max_episode_steps
        env_class = type(gym.make(env_id).unwrapped)
        assert set(preset.kwargs) <= set(inspect.signature(env_class).parameters), env_id


def test_no_env_class_inherits_another_version_of_its_task() -> None:
    for env_class in (grasp_envs.Grasper3DEnv, grasp_envs.Reacher2DEnv, grasp_envs.Reacher3DEnv, grasp_envs.WallReacher3DEnv):
        bases = [base.__module__ for base in env_class.__mro__[1:]]
        assert not any(module.startswith("grasp_envs.") and module != "grasp_envs.base" for module in bases), env_class


def test_recommended_grasper_is_the_class_defaults() -> None:
    """The recommended id and ``Grasper3DEnv()`` make the same env: each preset option is the class default, or a
    ``None`` default that the claw resolves to it (``observe_claw_torque``, ``reward_squeeze_weight``); same spaces,
    same observations and rewards for the same seed and actions."""
    preset = gym.make(RECOMMENDED_GRASPER)
    assert preset.unwrapped.spec.kwargs == PRESETS[RECOMMENDED_GRASPER].kwargs
    signature = inspect.signature(grasp_envs.Grasper3DEnv).parameters
    for option, value in PRESETS[RECOMMENDED_GRASPER].kwargs.items():
        assert signature[option].default in (value, None), option
    default = grasp_envs.Grasper3DEnv()
    assert default.observation_space == preset.observation_space and default.action_space == preset.action_space
    np.testing.assert_array_equal(preset.reset(seed=3)[0], default.reset(seed=3)[0])
    for action in np.random.default_rng(0).uniform(-1.0, 1.0, size=(20, 4)).astype(np.float32):
        observation, reward, terminated, _, _ = preset.step(action)
        default_observation, default_reward, default_terminated, _, _ = default.step(action)
        np.testing.assert_array_equal(default_observation, observation)
        assert (default_reward, default_terminated) == (reward, terminated)


def test_torque_claw_leaves_the_servo_terms_out_by_default() -> None:
    env = grasp_envs.Grasper3DEnv(claw="torque")
    assert env.observation_space.shape == (31,)  # the recommended 32 rows less the claw servo's torque
    env.reset(seed=0)
    *_, info = env.step(env.action_space.sample())
    assert info["reward_squeeze"] == 0.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"claw": "magnet"}, "claw must be one of"),
        ({"control": "torque"}, "control must be one of"),
        ({"observation": "pixels"}, "observation must be one of"),
        ({"cube_rotation": "roll"}, "cube_rotation must be one of"),
        ({"observe_claw_torque": "yes"}, "observe_claw_torque must be a bool or None, got 'yes'"),
        ({"claw": "torque", "observe_claw_torque": True}, "need claw='servo'"),
        ({"claw": "torque", "control": "joint_torque", "reward_squeeze_weight": 2.0}, "need claw='servo'"),
        ({"claw_rate": 0.1, "control": "joint_torque"}, "claw_rate"),
        ({"lift_height": 0.0}, "lift_height must be a positive number, got 0.0"),
        ({"lift_height": -0.05}, "lift_height must be a positive number, got -0.05"),
        ({"lift_height": True}, "lift_height must be a positive number, got True"),
        ({"reset_noise_scale": -0.1}, "reset_noise_scale must be a non-negative number, got -0.1"),
        ({"reset_noise_scale": float("nan")}, "reset_noise_scale must be a non-negative number, got nan"),
        ({"squeeze_torque": 0.0}, "squeeze_torque must be a positive number, got 0.0"),
        ({"max_grip_speed": True}, "max_grip_speed must be a positive number, got True"),
        ({"frame_skip": True}, "frame_skip must be an integer >= 1, got True"),
        ({"frame_skip": 2.0}, "frame_skip must be an integer >= 1, got 2.0"),
        ({"frame_skip": 0}, "frame_skip must be an integer >= 1, got 0"),
    ],
)
def test_grasper_options_are_checked(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        grasp_envs.Grasper3DEnv(**kwargs)


def test_grasper_accepts_a_noise_free_reset() -> None:
    env = grasp_envs.Grasper3DEnv(reset_noise_scale=0)
    env.reset(seed=0)
    assert env.data.qpos[env.task.claw_qpos] == 0.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"probability": 1.5}, "probability"),
        ({"probability": True}, "probability"),
        ({"steps": (5, 5)}, "steps"),
        ({"steps": (0.5, 10)}, "steps"),
        ({"hold_height": -0.1}, "hold_height"),
    ],
)
def test_scripted_starts_arguments_are_checked(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ScriptedStarts(gym.make("Grasper3D-v7"), **kwargs)
    with pytest.raises(TypeError, match="Grasper3D"):
        ScriptedStarts(gym.make("Reacher2D-v1"))


def test_scripted_starts_off_changes_nothing() -> None:
    plain, wrapped = gym.make("Grasper3D-v7"), ScriptedStarts(gym.make("Grasper3D-v7"), probability=0.0)
    for seed in range(3):
        np.testing.assert_array_equal(plain.reset(seed=seed)[0], wrapped.reset(seed=seed)[0])


@pytest.mark.parametrize(
    "wrap",
    [FlattenObservation, NormalizeObservation, lambda env: FrameStackObservation(env, 2)],
    ids=["flatten", "normalize", "stack"],
)
def test_scripted_starts_refuses_wrappers_that_change_observations(wrap: Any) -> None:
    """A scripted start returns the Grasper's own observation: a wrapper inside that may change it is refused."""
    inner = wrap(gym.make("Grasper3D-v7"))
    with pytest.raises(TypeError, match=type(inner).__name__):
        ScriptedStarts(inner)
    wrap(ScriptedStarts(gym.make("Grasper3D-v7"), probability=1.0, steps=(50, 51))).reset(seed=0)  # outside: fine


def test_scripted_starts_accepts_observation_preserving_wrappers_and_keeps_their_reset_info() -> None:
    inner = RecordEpisodeStatistics(Monitor(gym.make("Grasper3D-v7")))  # inside: gym.make's wrappers too
    original_reset = inner.reset

    def reset_with_info(**kwargs: Any) -> Any:
        observation, info = original_reset(**kwargs)
        return observation, {**info, "inner_note": 7}

    inner.reset = reset_with_info  # type: ignore[method-assign]
    env = ScriptedStarts(inner, probability=1.0, steps=(70, 71))
    observation, info = env.reset(seed=0)
    grasper = env.unwrapped
    np.testing.assert_array_equal(observation, grasper._get_obs())
    assert info == {"inner_note": 7, "is_success": grasper._is_success(), "unstable": False}


def test_scripted_starts_records_its_arguments_in_the_spec() -> None:
    env = ScriptedStarts(gym.make("Grasper3D-v7"), probability=0.5, steps=[50, 100], hold_height=0.07)
    recorded = env.spec.additional_wrappers[-1]
    assert recorded.entry_point == "grasp_envs.wrappers:ScriptedStarts"
    assert recorded.kwargs == {"probability": 0.5, "steps": (50, 100), "hold_height": 0.07}
    remade = gym.make(env.spec)
    assert isinstance(remade, ScriptedStarts)
    assert (remade.probability, remade.steps, remade.hold_height) == (0.5, (50, 100), 0.07)
    np.testing.assert_array_equal(remade.reset(seed=1)[0], env.reset(seed=1)[0])


ENV_CLASSES = (grasp_envs.Reacher2DEnv, grasp_envs.Reacher3DEnv, grasp_envs.WallReacher3DEnv, grasp_envs.Grasper3DEnv)
# options every env class takes from Gymnasium's MujocoEnv (checked there or by MuJoCo's renderer)
RENDER_OPTIONS = {"render_mode", "width", "height", "camera_id", "camera_name", "default_camera_config"}


def _wrong_values(name: str, default: Any) -> list[Any]:
    """Values of the wrong type for an option with this default."""
    if name == "xml_file":
        return [3, None if default is not None else 3.5]
    if isinstance(default, bool) or name in ("observe_claw_torque", "terminate_on_success"):
        return ["yes", 1]
    if isinstance(default, int):  # frame_skip
        return [True, 2.0, "2"]
    if isinstance(default, float) or default is None:
        return ["1", True, float("nan"), [1.0]]
    return [3, True]  # a choice among strings


@pytest.mark.parametrize("env_class", ENV_CLASSES, ids=lambda c: c.__name__)
def test_every_option_of_every_env_refuses_a_wrong_type(env_class: type) -> None:
    """Table-driven over the constructor's signature: each task option, given a value of the wrong type, raises
    ValueError naming the option (and nothing is coerced)."""
    options = {
        name: p.default
        for name, p in inspect.signature(env_class).parameters.items()
        if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and name not in RENDER_OPTIONS
    }
    assert len(options) >= 8, options
    for name, default in options.items():
        for value in _wrong_values(name, default):
            with pytest.raises(ValueError, match=re.escape(name)):
                env_class(**{name: value})
