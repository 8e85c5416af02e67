"""python -m benchmarks.grasper_probe: how an episode is classified and counted (--failures), how a loss is named
(--losses), and the turning cube of --what-if."""

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import grasp_envs  # noqa: F401  (registers the envs)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/ is a package beside the installed ones
from benchmarks.grasper_probe import (
    LOSS_PARTS,
    Episode,
    failure_table,
    outcome,
    success_parts,
    trace,
    turning_cube_xml,
)

CHECKS = {100: False, 150: False, 200: False}


def episode(bearing: float, grasp: int | None, lift: int | None, **lifted: bool) -> Episode:
    return Episode(bearing, grasp, lift, {**CHECKS, **{int(k[1:]): v for k, v in lifted.items()}})


def test_outcome_names_how_a_registered_episode_ended() -> None:
    assert outcome(episode(0.0, 40, 50, t100=True), 100) == "lifted"
    assert outcome(episode(0.0, 40, 50), 100) == "lifted and lost"
    assert outcome(episode(0.0, 40, 120, t150=True), 100) == "grasped, not lifted"  # the lift came too late
    assert outcome(episode(0.0, 130, 140, t150=True), 100) == "never grasped"  # so did the grasp
    assert outcome(episode(0.0, None, None), 100) == "never grasped"


def test_failure_table_groups_by_bearing_and_counts() -> None:
    episodes = [
        episode(10.0, 40, 50, t100=True, t150=True, t200=True),
        episode(-50.0, 60, 90),  # lifted and lost
        episode(90.0, 80, 120, t150=True, t200=True),  # too late at 100 steps
        episode(-170.0, None, None),
        episode(175.0, 70, 85, t100=True, t200=True),
    ]
    rows = failure_table(episodes, 100)
    assert rows == [
        "| in front (bearing within ±60°) | 2 | 0.50 / 0.50 / 0.50 | 50 "
        "| never grasped 0, grasped, not lifted 0, lifted and lost 1 |",
        "| to the side (60-120°) | 1 | 0.00 / 1.00 / 1.00 | 80 | never grasped 0, grasped, not lifted 1, lifted and lost 0 |",
        "| behind (beyond ±120°) | 2 | 0.50 / 0.00 / 0.50 | 70 | never grasped 1, grasped, not lifted 0, lifted and lost 0 |",
        "| all | 5 | 0.40 / 0.40 / 0.60 | 65 | never grasped 1, grasped, not lifted 1, lifted and lost 1 |",
    ]


def test_trace_follows_the_scripted_grasp_past_the_registered_length() -> None:
    from grasp_envs.scripted import grasper3d_policy

    env = gym.make("Grasper3D-v4", max_episode_steps=200)
    env.reset(seed=10_005)
    arm = env.unwrapped
    cube = arm.data.geom("cube").xpos.copy()  # type: ignore[attr-defined]

    def step(action: np.ndarray) -> tuple[None, bool]:
        return None, bool(env.step(action)[4]["is_success"])

    result = trace(None, lambda _: grasper3d_policy(arm), step, arm, 200, (100, 150, 200))  # type: ignore[arg-type]
    assert result.bearing == np.degrees(np.arctan2(cube[1], cube[0]))
    assert set(result.lifted_at) == {100, 150, 200}
    assert result.first_grasp is not None and result.first_lift is not None  # the scripted grasp lifts this cube
    assert result.first_grasp < result.first_lift


def test_success_parts_decompose_the_success_test() -> None:
    """--losses names the part of the success test that failed: the parts together are the env's test."""
    from grasp_envs.scripted import grasper3d_policy

    env = gym.make("Grasper3D-v5")
    env.reset(seed=10_000)  # the scripted grasp lifts this cube and loses it (tests/test_envs.py)
    arm = env.unwrapped
    seen = set()
    for _ in range(100):
        info = env.step(grasper3d_policy(arm))[4]  # type: ignore[arg-type]
        parts = success_parts(arm)
        assert list(parts) == list(LOSS_PARTS)
        assert info["is_success"] == all(parts.values())
        seen.add(info["is_success"])
    assert seen == {False, True}


def test_turning_cube_model_is_v6s_cube_under_the_saved_observation(tmp_path: Path) -> None:
    """--what-if's turning cube: v5's observation and model with v6's hinge, so v5's losses go as on v6."""
    from grasp_envs.scripted import grasper3d_policy

    env = gym.make("Grasper3D-v5", xml_file=turning_cube_xml("Grasper3D-v5", tmp_path))
    arm = env.unwrapped
    obs, _ = env.reset(seed=10_000)
    assert obs.shape == (26,)
    assert arm.model.joint("cube_rotation").type == 3  # type: ignore[attr-defined]  # mjJNT_HINGE
    for _ in range(100):
        info = env.step(grasper3d_policy(arm))[4]  # type: ignore[arg-type]
    assert info["is_success"]  # v5's model loses this cube after the lift
