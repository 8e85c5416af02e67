"""Why does a Grasper run stop at the grasp? Probe a saved run of the convergence study (`python -m benchmarks.convergence`).

    python -m benchmarks.grasper_probe --env Grasper3D-v4 --variant warm --seed 3 [--episodes 30]
    python -m benchmarks.grasper_probe --env Grasper3D-v4 --variant plain_scripted25 --seed 2 --failures [--episodes 40]
    python -m benchmarks.grasper_probe --env Grasper3D-v5 --variant plain_scripted25_late --seed 8 --losses [--episodes 40]
    python -m benchmarks.grasper_probe --env Grasper3D-v5 --variant plain_scripted25_late --seed 8 --what-if [--episodes 40]

``--failures``: where and how the held-out episodes fail. Runs the deterministic policy on held-out resets
seeded 10,000 + episode (the study's evaluation seeds only its first reset with 10,000 and lets the env's generator
draw the others, so these are its first episode and then others of the same kind) in episodes twice the registered length
(the policy has no clock, so its first steps are those of a registered episode) and the scripted grasp on the
same resets. Prints, per bearing of the cube from the shoulder's axis (the arm starts stretched along +x, so a
cube behind it is farther from the grip): how many episodes end lifted at the registered length, at 1.5 and 2
times it, the median step of the first grasp, and how the others failed (never grasped, grasped but never
lifted, lifted and lost).

``--losses``: how the lifted cubes are lost. On the same held-out resets, in episodes of the registered length,
for every episode whose success (cube up and grasped) ends after having begun, prints the step of the loss, which
part of the success test failed first (height, the right or left half's contact, the cube's centre between the
halves along the segment, along the forearm or along the hinge axis), the state just before it (the cube's height
and vertical speed, the policy's vertical grip and claw commands, the claw's torque and angle, the forearm's tilt
from pointing down) and whether the episode ends lifted all the same.

``--what-if``: are the losses the simulation's? The saved policy, unchanged, and the scripted grasp on the same
held-out resets in registered-length episodes, with the model as trained and with one change at a time: MuJoCo's
settings against slip in grasping (elliptic friction cones with ``impratio`` 10, the noslip solver, twice the
friction, half the time step at the same control period) and a cube that can turn (Grasper3D-v6's joint, about the
vertical or about every axis; the observation stays the saved policy's). Prints how many episodes end lifted and
how many lifted the cube and lost it.

Without ``--failures``, ``--losses`` or ``--what-if``:
Runs the saved policy (with its VecNormalize statistics) on seeded episodes (reset seed 30,000, not the
study's held-out 10,000) three ways: as it is, and with the vertical grip command replaced by a constant
(0.3, 0.6) from the first grasp until the cube is 7 cm up; every other action component stays the policy's.
Each way runs deterministically (the policy's mean) and stochastically (its exploration noise). Prints a
Markdown table of mean return and final success, and the deterministic policy's mean vertical command
while grasped. If forcing the lift pays more, even under the policy's own noise, then the lift is not too
risky for the policy's grip; the policy has simply not found it.
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import mujoco
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import grasp_envs  # noqa: F401
from benchmarks.builders import add_run_arguments, algorithm_class, model_settings
from benchmarks.protocol import EVAL_SEED
from benchmarks.runs import OUT, job_folder
from grasp_envs import grasper3d
from grasp_envs.scripted import grasper3d_policy

PROBE_SEED = 30_000
HELD_OUT_SEED = EVAL_SEED  # the study's held-out reset seed: far from the training envs' seeds
SECTORS = (  # |bearing| ranges in degrees
    (0.0, 60.0, "in front (bearing within ±60°)"),
    (60.0, 120.0, "to the side (60-120°)"),
    (120.0, 180.1, "behind (beyond ±120°)"),
)
RELEASE_HEIGHT = 0.07  # m: the forced command stops once the cube is this high


def saved_env(folder: Path, env_id: str, **make_kwargs: Any) -> VecNormalize:
    """One ``env_id`` env with the run's frozen VecNormalize statistics (observations normalised, rewards raw)."""
    env = VecNormalize.load(str(folder / "vecnormalize.pkl"), DummyVecEnv([lambda: gym.make(env_id, **make_kwargs)]))
    env.training, env.norm_reward = False, False
    return env


def probe(
    model: Any, env: VecNormalize, episodes: int, deterministic: bool, forced_up: float | None
) -> tuple[float, float, float]:
    """Mean return, final success and (deterministic, unforced) mean vertical action while grasped."""
    arm = env.venv.envs[0].unwrapped  # type: ignore[attr-defined]
    returns, successes, vertical = [], [], []
    for episode in range(episodes):
        env.seed(PROBE_SEED + episode)
        obs: Any = env.reset()
        total, grasped_once, done = 0.0, False, np.array([False])
        while not done[0]:  # the TimeLimit ends it (the VecEnv then resets; infos[0] is the last step's)
            action, _ = model.predict(obs, deterministic=deterministic)
            grasped = arm.is_grasped()
            grasped_once = grasped_once or grasped
            if grasped:
                vertical.append(float(np.clip(action[0, 2], -1.0, 1.0)))
            if forced_up is not None and grasped_once and arm.cube_height() < RELEASE_HEIGHT:
                action = action.copy()
                action[0, 2] = forced_up
            obs, reward, done, infos = env.step(action)
            total += float(reward[0])
        returns.append(total)
        successes.append(float(infos[0].get("is_success", False)))
    return float(np.mean(returns)), float(np.mean(successes)), float(np.mean(vertical)) if vertical else float("nan")


class Episode(NamedTuple):
    bearing: float  # degrees of the cube from +x (the stretched start pose) about the shoulder's vertical axis
    first_grasp: int | None  # step (1-based) of the first grasp
    first_lift: int | None  # step of the first success
    lifted_at: dict[int, bool]  # success at each checked step


def trace(
    obs: Any,
    policy: Callable[[Any], Any],
    step: Callable[[Any], tuple[Any, bool]],
    arm: Any,
    steps: int,
    checks: Sequence[int],
) -> Episode:
    """Run ``steps`` steps from the reset that gave ``obs``; ``step(action)`` returns the next obs and success."""
    cube = arm.data.geom("cube").xpos
    bearing = float(np.degrees(np.arctan2(cube[1], cube[0])))
    first_grasp = first_lift = None
    lifted_at = {}
    for t in range(1, steps + 1):
        obs, success = step(policy(obs))
        if first_grasp is None and arm.is_grasped():
            first_grasp = t
        if first_lift is None and success:
            first_lift = t
        if t in checks:
            lifted_at[t] = success
    return Episode(bearing, first_grasp, first_lift, lifted_at)


def outcome(episode: Episode, limit: int) -> str:
    """How an episode of the registered length ``limit`` ended."""
    if episode.lifted_at[limit]:
        return "lifted"
    if episode.first_lift is not None and episode.first_lift <= limit:
        return "lifted and lost"
    if episode.first_grasp is not None and episode.first_grasp <= limit:
        return "grasped, not lifted"
    return "never grasped"


def failure_table(episodes: Sequence[Episode], limit: int) -> list[str]:
    """Markdown rows: per bearing sector, success at 1, 1.5 and 2 times ``limit``, first grasp, failure kinds."""
    rows = []
    for low, high, name in (*SECTORS, (0.0, 180.1, "all")):
        group = [e for e in episodes if low <= abs(e.bearing) < high]
        if not group:
            continue
        rates = " / ".join(f"{np.mean([e.lifted_at[t] for e in group]):.2f}" for t in sorted(group[0].lifted_at))
        grasps = [e.first_grasp for e in group if e.first_grasp is not None]
        kinds = [outcome(e, limit) for e in group]
        failures = ", ".join(
            f"{kind} {kinds.count(kind)}" for kind in ("never grasped", "grasped, not lifted", "lifted and lost")
        )
        median = f"{np.median(grasps):.0f}" if grasps else "-"
        rows.append(f"| {name} | {len(group)} | {rates} | {median} | {failures} |")
    return rows


def held_out_episodes(
    model: Any, env: VecNormalize, scripted_env: gym.Env, episodes: int, steps: int, checks: Sequence[int]
) -> tuple[list[Episode], list[Episode]]:
    """The saved policy (deterministic, in ``env``) and the scripted grasp (in ``scripted_env``) on the same held-out
    resets, ``steps`` steps each: one ``Episode`` per reset for each."""
    arm, scripted_arm = env.venv.envs[0].unwrapped, scripted_env.unwrapped  # type: ignore[attr-defined]

    def learned_step(action: Any) -> tuple[Any, bool]:
        obs, _, _, infos = env.step(action)
        return obs, bool(infos[0]["is_success"])

    def scripted_step(action: Any) -> tuple[Any, bool]:
        return None, bool(scripted_env.step(action)[4]["is_success"])

    def learned_policy(obs: Any) -> Any:
        return model.predict(obs, deterministic=True)[0]

    def scripted_policy(_: Any) -> Any:
        return grasper3d_policy(scripted_arm)  # type: ignore[arg-type]

    learned, scripted = [], []
    for episode in range(episodes):
        env.seed(HELD_OUT_SEED + episode)
        learned.append(trace(env.reset(), learned_policy, learned_step, arm, steps, checks))
        scripted_env.reset(seed=HELD_OUT_SEED + episode)
        scripted.append(trace(None, scripted_policy, scripted_step, scripted_arm, steps, checks))
    return learned, scripted


def failures(model: Any, env_id: str, folder: Path, episodes: int, env_kwargs: dict[str, Any]) -> None:
    """Print the ``--failures`` tables for the saved policy and for the scripted grasp (both on ``env_id`` made with
    ``env_kwargs``, the run's evaluation kwargs)."""
    registered = gym.spec(env_id).max_episode_steps
    assert registered is not None
    steps, checks = 2 * registered, (registered, registered * 3 // 2, 2 * registered)
    kwargs = {**env_kwargs, "max_episode_steps": steps}
    env, scripted_env = saved_env(folder, env_id, **kwargs), gym.make(env_id, **kwargs)
    learned, scripted = held_out_episodes(model, env, scripted_env, episodes, steps, checks)
    header = " / ".join(str(t) for t in checks)
    for name, group in (("the saved policy (deterministic)", learned), ("the scripted grasp", scripted)):
        print(f"\n{name}, {episodes} held-out resets from seed {HELD_OUT_SEED}\n")
        print(f"| cube | episodes | lifted at step {header} | median first grasp | failures at step {registered} |")
        print("|---|---|---|---|---|")
        print("\n".join(failure_table(group, registered)))


LOSS_PARTS = ("height", "right contact", "left contact", "along the segment", "along the forearm", "along the hinge")


def success_parts(arm: Any) -> dict[str, bool]:
    """Each part of v4/v5's success test (``_is_success``): all true exactly when the task counts as solved."""
    contacts = arm.claw_cube_contacts()
    t, offset = arm.cube_off_claw_segment_in_forearm_frame()
    tolerance = grasper3d.BETWEEN_TOLERANCE
    return dict(
        zip(
            LOSS_PARTS,
            (
                arm.cube_height() >= arm.task.lift_height,
                contacts["right"] > 0,
                contacts["left"] > 0,
                0.0 < t < 1.0,
                abs(offset[0]) <= tolerance,
                abs(offset[2]) <= tolerance,
            ),
            strict=True,
        )
    )


def losses(model: Any, env_id: str, folder: Path, episodes: int, env_kwargs: dict[str, Any]) -> None:
    """Print the ``--losses`` table: one row per held-out episode that lifts the cube and loses it."""
    registered = gym.spec(env_id).max_episode_steps
    assert registered is not None
    env = saved_env(folder, env_id, **{**env_kwargs, "max_episode_steps": registered})
    arm = env.venv.envs[0].unwrapped  # type: ignore[attr-defined]
    print(f"\nthe saved policy (deterministic), {episodes} held-out resets from seed {HELD_OUT_SEED}\n")
    print(
        "| reset | lifted at step | lost at step | failed first | height (cm) | cube's vertical speed (cm/s) "
        "| vertical command | claw command | claw torque (N m) | claw angle (rad) | forearm tilt from down (°) "
        f"| lifted again at step {registered} |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    lost = 0
    for episode in range(episodes):
        env.seed(HELD_OUT_SEED + episode)
        obs: Any = env.reset()
        first_lift, row = None, ""
        before: tuple[float, ...] = ()
        for t in range(1, registered + 1):
            action, _ = model.predict(obs, deterministic=True)
            command = np.clip(action[0], -1.0, 1.0)
            forearm = arm.data.body("forearm").xmat.reshape(3, 3)[:, 0]
            before = (
                100 * arm.cube_height(),
                100 * float(arm.data.qvel[arm.model.joint("cube_z").dofadr[0]]),
                float(command[2]),
                float(command[3]),
                arm.claw_torque(),
                float(arm.data.joint("claw_right").qpos[0]),
                float(np.degrees(np.arccos(np.clip(-forearm[2], -1.0, 1.0)))),
            )
            obs, _, _, infos = env.step(action)
            success = bool(infos[0]["is_success"])
            if first_lift is None and success:
                first_lift = t
            elif first_lift is not None and not success and not row:
                parts = success_parts(arm)
                failed = ", ".join(part for part in LOSS_PARTS if not parts[part])
                height, speed, vertical, claw, torque, angle, tilt = before
                row = (
                    f"| {HELD_OUT_SEED + episode} | {first_lift} | {t} | {failed} | {height:.1f} | {speed:+.1f} "
                    f"| {vertical:+.2f} | {claw:+.2f} | {torque:.2f} | {angle:+.3f} | {tilt:.0f} |"
                )
        if row:  # the VecEnv reset after the last step: infos[0] is that step's
            print(f"{row} {'yes' if infos[0]['is_success'] else 'no'} |")
            lost += 1
    print(f"\n{lost} of {episodes} episodes lost a lifted cube within {registered} steps")


def _elliptic_cones(model: mujoco.MjModel) -> None:
    model.opt.cone, model.opt.impratio = mujoco.mjtCone.mjCONE_ELLIPTIC, 10.0


def _noslip(model: mujoco.MjModel) -> None:
    model.opt.noslip_iterations = 20


def _double_friction(model: mujoco.MjModel) -> None:
    model.geom_friction[:, 0] *= 2.0


# change -> (edit of the compiled model, physics steps per control step as a multiple of the env's, how the cube turns
# (Grasper3D-v6's cube_rotation; None: it only slides))
WHAT_IF: dict[str, tuple[Callable[[mujoco.MjModel], None] | None, int, str | None]] = {
    "as trained": (None, 1, None),
    "elliptic cones, impratio 10": (_elliptic_cones, 1, None),
    "noslip solver, 20 iterations": (_noslip, 1, None),
    "friction 2 instead of 1": (_double_friction, 1, None),
    "time step 0.005 s, 4 per action": (None, 2, None),
    "the cube turns about the vertical (v6)": (None, 1, "yaw"),
    'the cube turns about every axis (v6, `cube_rotation="free"`)': (None, 1, "free"),
}


def turning_cube_xml(env_id: str, folder: Path, cube_rotation: str = "yaw") -> str:
    """The env's model with Grasper3D-v6's cube rotation, written to ``folder`` (for ``xml_file``)."""
    spec = mujoco.MjSpec.from_file(gym.make(env_id).unwrapped.fullpath)  # type: ignore[attr-defined]
    grasper3d.add_cube_rotation(spec, cube_rotation)
    path = folder / f"cube_{cube_rotation}.xml"
    path.write_text(spec.to_xml())
    return str(path)


def _outcomes(model: Any, env: VecNormalize, scripted_env: gym.Env, episodes: int, limit: int) -> list[int]:
    """Episodes ending lifted and lifted-and-lost, for the saved policy in ``env`` and the scripted grasp."""
    groups = held_out_episodes(model, env, scripted_env, episodes, limit, (limit,))
    kinds = [[outcome(episode, limit) for episode in group] for group in groups]
    return [group.count(kind) for group in kinds for kind in ("lifted", "lifted and lost")]


def what_if(model: Any, env_id: str, folder: Path, episodes: int, env_kwargs: dict[str, Any]) -> None:
    """Print the ``--what-if`` table: the policy and the scripted grasp under each change of WHAT_IF."""
    registered = gym.spec(env_id).max_episode_steps
    assert registered is not None
    print(f"\n{episodes} held-out resets from seed {HELD_OUT_SEED}, {registered} steps\n")
    print(
        "| model | policy: lifted at the end | policy: lifted and lost "
        "| scripted grasp: lifted at the end | scripted grasp: lifted and lost |"
    )
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for change, (edit, substeps, rotation) in WHAT_IF.items():
            kwargs: dict[str, Any] = {**env_kwargs, "max_episode_steps": registered}
            if rotation is not None:
                kwargs["xml_file"] = turning_cube_xml(env_id, Path(tmp), rotation)
            env, scripted_env = saved_env(folder, env_id, **kwargs), gym.make(env_id, **kwargs)
            arms: list[Any] = [env.venv.envs[0].unwrapped, scripted_env.unwrapped]  # type: ignore[attr-defined]
            for arm in arms:
                if edit is not None:
                    edit(arm.model)
                arm.model.opt.timestep /= substeps
                arm.frame_skip *= substeps
            counts = _outcomes(model, env, scripted_env, episodes, registered)
            print(f"| {change} | " + " | ".join(str(count) for count in counts) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_run_arguments(parser, "Grasper3D-v4", "warm")
    parser.add_argument("--episodes", type=int, default=30)
    parser.add_argument("--failures", action="store_true", help="where and how the held-out episodes fail")
    parser.add_argument("--losses", action="store_true", help="how the lifted cubes are lost")
    parser.add_argument("--what-if", action="store_true", help="the losses under other physics settings")
    parser.add_argument("--runs", type=Path, default=OUT, help="the runs' folder (python -m benchmarks.convergence's --out)")
    args = parser.parse_args()
    folder = job_folder(args.runs, args.env, args.variant, args.seed)
    if not (folder / "model.zip").exists():
        raise SystemExit(f"{folder}: no model.zip (run python -m benchmarks.convergence first; checkpoints are not committed)")
    model = algorithm_class(args.variant).load(folder / "model.zip", device="cpu")
    env_kwargs = model_settings(args.env, args.variant).env_kwargs  # e.g. a variant's max_grip_speed
    if args.failures:
        print(f"{args.env} {args.variant} seed {args.seed}")
        failures(model, args.env, folder, args.episodes, env_kwargs)
        return
    if args.losses or args.what_if:
        print(f"{args.env} {args.variant} seed {args.seed}")
        (losses if args.losses else what_if)(model, args.env, folder, args.episodes, env_kwargs)
        return
    env = saved_env(folder, args.env, **env_kwargs)
    print(f"{args.env} {args.variant} seed {args.seed}, {args.episodes} episodes from reset seed {PROBE_SEED}\n")
    print("| policy | vertical command after the grasp | return | final success |")
    print("|---|---|---|---|")
    for deterministic in (True, False):
        for forced_up in (None, 0.3, 0.6):
            mean_return, success, vertical = probe(model, env, args.episodes, deterministic, forced_up)
            label = "deterministic" if deterministic else "stochastic"
            command = f"policy's (mean {vertical:+.2f})" if forced_up is None else f"{forced_up} until 7 cm"
            print(f"| {label} | {command} | {mean_return:.0f} | {success:.2f} |")


if __name__ == "__main__":
    main()
