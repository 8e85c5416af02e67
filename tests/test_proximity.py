"""The distance bounds that let the batched engine skip contact-list reads: hand-computed values, and no counted
contact ever skipped on the tasks' own trajectories."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import grasp_envs  # noqa: F401  (registers the ids)
from grasp_envs.proximity import (
    CLEARANCE,
    ContactScreen,
    never_collide,
    segment_box_separation,
    segment_plane_distance,
    segment_segment_distance,
)
from grasp_envs.scripted import grasper3d_policy, wall_reacher3d_policy


def _v(*values: float) -> np.ndarray:
    return np.array(values, dtype=np.float64)


@pytest.mark.parametrize(
    ("p1", "q1", "p2", "q2", "expected"),
    [
        (_v(0, 0, 0), _v(1, 0, 0), _v(0, 1, 0), _v(1, 1, 0), 1.0),  # parallel, side by side
        (_v(0, 0, 0), _v(1, 0, 0), _v(2, 0, 0), _v(3, 0, 0), 1.0),  # on one line, end to end
        (_v(-1, 0, 0), _v(1, 0, 0), _v(0, -1, 2), _v(0, 1, 2), 2.0),  # crossing at right angles, 2 apart
        (_v(0, 0, 0), _v(1, 0, 0), _v(2, 1, 0), _v(2, 3, 0), np.sqrt(2.0)),  # closest: end points (1,0,0), (2,1,0)
        (_v(0, 0, 0), _v(0, 0, 0), _v(3, 4, 0), _v(3, 4, 0), 5.0),  # two points
        (_v(0, 0, 0), _v(0, 0, 0), _v(-1, 2, 0), _v(1, 2, 0), 2.0),  # a point and a segment
        (_v(0, 0, 0), _v(2, 0, 0), _v(1, -1, 0), _v(1, 1, 0), 0.0),  # intersecting
    ],
)
def test_segment_segment_distance(p1, q1, p2, q2, expected) -> None:
    assert segment_segment_distance(p1, q1, p2, q2) == pytest.approx(expected, abs=1e-12)
    assert segment_segment_distance(p2, q2, p1, q1) == pytest.approx(expected, abs=1e-12)


def test_segment_segment_distance_is_the_minimum_over_sampled_points() -> None:
    rng = np.random.default_rng(0)
    p1, q1, p2, q2 = rng.normal(size=(4, 200, 3))
    t = np.linspace(0.0, 1.0, 201)
    a = p1[:, None] + (q1 - p1)[:, None] * t[None, :, None]
    b = p2[:, None] + (q2 - p2)[:, None] * t[None, :, None]
    sampled = np.linalg.norm(a[:, :, None] - b[:, None], axis=-1).min(axis=(1, 2))
    exact = segment_segment_distance(p1, q1, p2, q2)
    assert np.all(exact <= sampled + 1e-12)
    assert np.all(sampled - exact < 0.05)


def test_segment_box_separation() -> None:
    identity, half = np.eye(3), _v(1, 2, 3)
    # above the box's top face by 1, along z
    assert segment_box_separation(_v(0, 0, 4), _v(0.5, 1, 4), _v(0, 0, 0), identity, half) == pytest.approx(1.0)
    # through the box
    assert segment_box_separation(_v(-5, 0, 0), _v(5, 0, 0), _v(0, 0, 0), identity, half) == 0.0
    # off a corner by (1, 1, 1): the bound is the largest gap on one axis, 1, below the distance sqrt(3)
    assert segment_box_separation(_v(2, 3, 4), _v(2, 3, 4), _v(0, 0, 0), identity, half) == pytest.approx(1.0)
    # a box turned by 90 degrees about z: its long y axis lies along world x
    turned = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert segment_box_separation(_v(3, 0, 0), _v(3, 0, 0), _v(0, 0, 0), turned, half) == pytest.approx(1.0)
    assert segment_box_separation(_v(0, 3, 0), _v(0, 3, 0), _v(0, 0, 0), turned, half) == pytest.approx(2.0)


def test_segment_plane_distance() -> None:
    up, origin = _v(0, 0, 1), _v(0, 0, 0)
    assert segment_plane_distance(_v(0, 0, 2), _v(1, 0, 3), origin, up) == pytest.approx(2.0)
    assert segment_plane_distance(_v(0, 0, 2), _v(1, 0, -1), origin, up) == pytest.approx(-1.0)


def test_the_filter_leaves_out_what_mujoco_never_collides() -> None:
    xml = """
    <mujoco>
      <worldbody>
        <geom name="floor" type="plane" size="1 1 .1"/>
        <body name="a"><freejoint/><geom name="a1" size=".1"/><geom name="a2" size=".1" pos=".3 0 0"/>
          <body name="b"><joint type="hinge"/><geom name="b" size=".1" contype="2" conaffinity="2"/></body>
        </body>
        <body name="c"><freejoint/><geom name="c" size=".1" contype="2" conaffinity="1"/></body>
        <body name="d"><freejoint/><geom name="d" size=".1"/></body>
      </worldbody>
      <contact><exclude body1="c" body2="d"/></contact>
    </mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)

    def geom(name: str) -> int:
        return int(model.geom(name).id)

    assert never_collide(model, geom("a1"), geom("a2"))  # one body
    assert never_collide(model, geom("a1"), geom("b"))  # contype 1 / conaffinity 2 and back
    assert never_collide(model, geom("c"), geom("d"))  # excluded bodies
    assert not never_collide(model, geom("c"), geom("a1"))  # c's contype 2 misses, a1's contype 1 meets c's 1
    assert not never_collide(model, geom("floor"), geom("d"))


GEOMETRY_IDS = ["Grasper3D-v0", "Grasper3D-v3", "Grasper3D-v7", "WallReacher3D-v0"]


@pytest.mark.parametrize("env_id", GEOMETRY_IDS)
def test_no_counted_contact_is_ever_screened_out(env_id: str) -> None:
    """Along scripted grasps / reaches with noise and along random actions: every step with a counted contact is one
    the screen lets through, and (but on Grasper3D-v0, whose claw halves touch at the hinge) it skips most others."""
    env = gym.make(env_id).unwrapped
    task, model = env.task, env.model
    screen = ContactScreen(model, [(task.geom_id(a), task.geom_id(b)) for a, b in task.contact_pairs])
    policy = grasper3d_policy if env_id.startswith("Grasper") else wall_reacher3d_policy
    env.reset(seed=0)
    env.action_space.seed(0)
    rng = np.random.default_rng(0)
    touching = skipped = 0
    steps = 1500
    for t in range(steps):
        if (t // 150) % 2 == 0:
            noisy = policy(env) + rng.normal(0.0, 0.2, env.action_space.shape)
            action = np.clip(noisy, env.action_space.low, env.action_space.high)
        else:
            action = env.action_space.sample()
        _, _, terminated, truncated, _ = env.step(action)
        counted = task.count_contacts(env.data).any()
        possible = screen.may_touch(env.data.geom_xpos[None], env.data.geom_xmat[None])[0]
        assert possible or not counted, f"step {t}: a counted contact was screened out"
        touching += counted
        skipped += not possible
        if terminated or truncated:
            env.reset()
    assert touching > 0
    if env_id != "Grasper3D-v0":
        assert skipped > steps // 2


def test_a_screened_out_pair_is_beyond_reach() -> None:
    """A capsule held CLEARANCE + 1 mm above a plane is screened out, one held at CLEARANCE / 2 is not."""
    xml = """
    <mujoco>
      <worldbody>
        <geom name="floor" type="plane" size="1 1 .1"/>
        <body name="rod" pos="0 0 1"><freejoint/><geom name="rod" type="capsule" size=".05 .2" euler="0 90 0"/></body>
      </worldbody>
    </mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    screen = ContactScreen(model, [(int(model.geom("rod").id), int(model.geom("floor").id))])
    for height, expected in ((0.05 + CLEARANCE + 1e-3, False), (0.05 + CLEARANCE / 2, True), (0.04, True)):
        data.qpos[2] = height
        mujoco.mj_forward(model, data)
        assert screen.may_touch(data.geom_xpos[None], data.geom_xmat[None])[0] == expected
        assert (data.ncon > 0) <= expected


def test_the_screens_shared_geom_path_is_its_pairwise_path() -> None:
    """Where every pair of a group has the same second geom (the Grasper's claw capsules with the floor and with the
    cube), the screen bounds them broadcast over that geom's pose; along random motion its answer is the one of
    bounding each pair with ``segment_plane_distance`` and ``segment_box_separation``."""
    env = gym.make("Grasper3D-v7").unwrapped
    task, model = env.task, env.model
    pairs = [(task.geom_id(a), task.geom_id(b)) for a, b in task.contact_pairs]
    screen, pairwise = ContactScreen(model, pairs), ContactScreen(model, pairs)
    assert {kind: group[2] is not None for kind, group in screen._groups.items()} == {"plane": True, "box": True}
    pairwise._groups = {kind: (rows, second, None, reach) for kind, (rows, second, _, reach) in screen._groups.items()}
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    xpos, xmat = [], []
    for t in range(600):
        noisy = grasper3d_policy(env) + rng.normal(0.0, 0.3, env.action_space.shape)
        env.step(np.clip(noisy, env.action_space.low, env.action_space.high) if t % 200 < 150 else env.action_space.sample())
        xpos.append(env.data.geom_xpos.copy())
        xmat.append(env.data.geom_xmat.copy())
    xpos_all, xmat_all = np.array(xpos), np.array(xmat)
    possible = screen.may_touch(xpos_all, xmat_all)
    np.testing.assert_array_equal(possible, pairwise.may_touch(xpos_all, xmat_all))
    assert 0 < possible.sum() < len(possible)
