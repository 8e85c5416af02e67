"""Each task's options are one frozen dataclass: its defaults are the documented ones, a bad value names itself, an
unknown option is refused; the env classes, the batched engine and the scripted starts all take their options from it.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import pickle
import re
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import grasp_envs
from grasp_envs import Grasper3DOptions, Reacher2DOptions, Reacher3DOptions, ScriptedStartOptions, WallReacher3DOptions
from grasp_envs.base import ArmEnv
from grasp_envs.options import Options
from grasp_envs.registration import PRESETS

ENV_OPTIONS: dict[type[ArmEnv], type[Options]] = {
    grasp_envs.Reacher2DEnv: Reacher2DOptions,
    grasp_envs.Reacher3DEnv: Reacher3DOptions,
    grasp_envs.WallReacher3DEnv: WallReacher3DOptions,
    grasp_envs.Grasper3DEnv: Grasper3DOptions,
}
ENV_IDS = {
    env_class: next(i for i, p in PRESETS.items() if p.entry_point.endswith(env_class.__name__)) for env_class in ENV_OPTIONS
}
NOT_AN_OPTION_VALUE = object()  # no rule accepts it


def documented_defaults(env_class: type) -> dict[str, Any]:
    """The Arguments table of the class docstring: each option whose default is written as a Python literal."""
    arguments = (env_class.__doc__ or "").split("## Arguments")[1].split("## Version History")[0]
    rows = re.findall(r"^\s*\| `(\w+)` \| `([^`]*)` \|", arguments, flags=re.MULTILINE)
    return {name: ast.literal_eval(default) for name, default in rows}


@pytest.mark.parametrize("env_class", ENV_OPTIONS, ids=lambda c: c.__name__)
def test_option_defaults_are_the_documented_ones(env_class: type[ArmEnv]) -> None:
    options_class = ENV_OPTIONS[env_class]
    assert env_class.options_class is options_class
    assert options_class().keywords() == options_class.defaults() == documented_defaults(env_class)


@pytest.mark.parametrize("env_class", ENV_OPTIONS, ids=lambda c: c.__name__)
def test_the_constructor_signature_lists_the_options(env_class: type[ArmEnv]) -> None:
    parameters = inspect.signature(env_class).parameters
    assert list(parameters) == [*ENV_OPTIONS[env_class].names(), "default_camera_config", "kwargs"]
    assert {name: p.default for name, p in parameters.items() if name in ENV_OPTIONS[env_class].names()} == (
        ENV_OPTIONS[env_class].defaults()
    )
    assert parameters["default_camera_config"].default is env_class.default_camera


@pytest.mark.parametrize("options_class", [*ENV_OPTIONS.values(), ScriptedStartOptions], ids=lambda c: c.__name__)
def test_a_bad_value_names_itself(options_class: type[Options]) -> None:
    for name in options_class.names():
        with pytest.raises(ValueError) as error:
            options_class(**{name: NOT_AN_OPTION_VALUE})
        message = str(error.value)
        assert message.startswith(f"{name} must be ") and message.endswith(f"got {NOT_AN_OPTION_VALUE!r}"), message


@pytest.mark.parametrize("env_class", ENV_OPTIONS, ids=lambda c: c.__name__)
def test_an_unknown_option_is_refused_everywhere(env_class: type[ArmEnv]) -> None:
    env_id = ENV_IDS[env_class]
    with pytest.raises(TypeError, match="gripper"):
        ENV_OPTIONS[env_class](gripper=1)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match=f"{env_class.__name__} has no option 'gripper', 'magnet'"):
        env_class(magnet=0, gripper=1)
    with pytest.raises(TypeError, match="has no option 'gripper'"):
        gym.make(env_id, gripper=1)
    with pytest.raises(TypeError, match=f"{env_id} has no option 'gripper'"):
        grasp_envs.make_batch_env(env_id, 1, gripper=1)


def test_options_are_frozen_and_replaced_with_checks() -> None:
    options = Grasper3DOptions(lift_height=0.07)
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.lift_height = 0.1  # type: ignore[misc]
    assert dataclasses.replace(options, claw="torque", control="joint_torque").lift_height == 0.07
    with pytest.raises(ValueError, match="lift_height must be a positive number, got 0"):
        dataclasses.replace(options, lift_height=0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"claw_rate": 0.1, "claw": "torque"}, "claw_rate moves the servo claw's target"),
        ({"claw": "torque", "observe_claw_torque": True}, "need claw='servo'"),
        ({"claw": "torque", "reward_squeeze_weight": 1.0}, "need claw='servo'"),
    ],
)
def test_grasper_options_that_need_the_servo_claw(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=re.escape(message)):
        Grasper3DOptions(**kwargs)
    Grasper3DOptions(**{**kwargs, "claw": "servo", "control": "grip_velocity"})  # with the servo claw: fine


def test_the_task_reads_its_options_and_decides_the_grasper_nones() -> None:
    servo, torque = grasp_envs.Grasper3DEnv().task, grasp_envs.Grasper3DEnv(claw="torque", reward_mode="thesis").task
    assert servo.options == Grasper3DOptions() and servo.lift_height == 0.05 and servo.claw == "servo"
    assert (servo.observe_claw_torque, servo.reward_squeeze_weight, servo.reward_control_weight) == (True, 2.0, 0.1)
    assert (torque.observe_claw_torque, torque.reward_squeeze_weight, torque.reward_control_weight) == (False, 0.0, 1.0)
    assert (servo.terminate_on_success, torque.terminate_on_success) == (False, True)
    assert (servo.xml_file, torque.xml_file) == ("grasper3d_v1.xml", "grasper3d.xml")
    with pytest.raises(AttributeError, match="no attribute 'gripper'"):
        _ = servo.gripper


def test_the_env_pickles_with_every_option() -> None:
    env = gym.make("Reacher3D-v1", near_scale=0.04).unwrapped
    assert env._ezpickle_kwargs == {
        **Reacher3DOptions(near_scale=0.04, reward_near_weight=0.5).keywords(),
        "default_camera_config": grasp_envs.Reacher3DEnv.default_camera,
    }
    assert pickle.loads(pickle.dumps(env)).options == env.options


def test_batch_set_attr_of_an_option_replaces_the_checked_options() -> None:
    env = grasp_envs.make_batch_env("Reacher2D-v1", 2, seed=0)
    env.reset()
    env.set_attr("reward_near_weight", 0.25)
    assert env.get_attr("reward_near_weight") == [0.25, 0.25] and env.task.options.reward_near_weight == 0.25
    *_, infos = env.step(np.zeros((2, 2)))
    assert infos[0]["reward_near"] == pytest.approx(0.25 * (1.0 - np.tanh(infos[0]["distance"] / 0.05)))
    with pytest.raises(ValueError, match=re.escape("reward_near_weight must be a non-negative number, got -1.0")):
        env.set_attr("reward_near_weight", -1.0)
    with pytest.raises(ValueError, match="set it for all envs"):
        env.set_attr("reward_near_weight", 0.5, indices=[0])


def test_scripted_start_options() -> None:
    options = ScriptedStartOptions(probability=1, steps=[50, np.int64(100)])  # type: ignore[arg-type]
    assert (options.probability, options.steps, options.hold_height) == (1.0, (50, 100), None)
    assert type(options.probability) is float and all(type(n) is int for n in options.steps)
    assert ScriptedStartOptions() == ScriptedStartOptions(0.25, (0, 100), None)
    with pytest.raises(TypeError, match="scripted_starts has no option 'probabilty'"):
        ScriptedStartOptions.from_keywords({"probabilty": 0.5}, "scripted_starts")
    with pytest.raises(TypeError, match="scripted_starts has no option 'probabilty'"):
        grasp_envs.make_batch_env("Grasper3D-v7", 1, wrapper_class=grasp_envs.ScriptedStarts, wrapper_kwargs={"probabilty": 1})
