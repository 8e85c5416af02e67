"""``trpo-plus``: train / enjoy / record-video / plot / main, on top of rl-zoo3.

Every rl-zoo3 flag passes through ``train`` and ``enjoy`` unchanged; we register TRPOPlus in rl-zoo3,
import ``grasp_envs`` and default ``-conf`` to our validated YAML for the chosen algorithm.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from sb3_trpo_plus.arguments import ArgumentError, CommandLineParser
from sb3_trpo_plus.run_folders import RunNotFoundError, default_folder, load_trained, validated_run_folders

ALGO_CHOICES = ("trpo_plus", "trpo", "ppo")
ALGO_HELP = "trpo_plus (TRPOPlus), trpo (sb3-contrib's TRPO) or ppo (SB3's PPO); default: trpo_plus"


def _headless() -> None:
    """Render off-screen when there is no display (MuJoCo reads MUJOCO_GL when it first renders)."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("MUJOCO_GL", "egl")


def _zoo_argv(algo: str, env: str, conf_path: str | None, rest: Sequence[str]) -> list[str]:
    """rl-zoo3's train flags: ``conf_path`` (default: our YAML of ``algo``) checked and handed over as a module."""
    from sb3_trpo_plus.zoo import config_module, register_in_rl_zoo

    register_in_rl_zoo()
    module = config_module(algo, conf_path)
    packages = [] if "--gym-packages" in rest else ["--gym-packages", "grasp_envs"]
    return ["--algo", algo, "--env", env, "-conf", module, *packages, *rest]


def _workers_option(value: str) -> tuple[str, int]:
    """``--workers BACKEND:N`` as ``(backend, N)``."""
    from sb3_trpo_plus.zoo import parse_workers

    try:
        return parse_workers(value)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def train(argv: Sequence[str]) -> None:
    """``trpo-plus train --env ID [--algo trpo_plus|trpo|ppo] [--vec-env dummy|subproc|batch] [--sim-threads N]
    [--workers inprocess|process|ray:N] [rl_zoo3 train flags]``.

    ``--vec-env batch``, the default for the tasks of ``grasp_envs``, steps the training envs with the batched engine
    (``grasp_envs.make_batch_env``, physics on ``--sim-threads`` threads): the same transitions as ``dummy``, faster.
    Ctrl-C stops at the next env step and saves the run (model, replay memory, VecNormalize statistics), from which
    ``-i <run>/<ENV>.zip`` resumes.
    ``--workers ray:8`` collects with 8 Ray workers (``sb3_trpo_plus.rollouts.RayRollouts``; the cluster at
    ``RAY_ADDRESS``, else Ray on this machine), each stepping ``n_envs / 8`` of the recipe's envs; a cluster that
    refuses this process' token stops the command at once with one line naming ``RAY_AUTH_MODE=token`` and the
    token's file. A recipe with ``rollout_workers: BACKEND:N`` (Grasper3D-v7's) collects so without ``--workers``;
    ``--workers`` replaces it, and ``--vec-env`` beside it stops the command naming the conflict.
    ``--help`` prints our flags and the common rl-zoo3 ones that pass through, without running rl-zoo3. A bad flag
    or value (ours or rl-zoo3's), an unknown env id, a recipe file that cannot be used and hyperparameters that the
    constructor refuses stop the command with one line, ``trpo-plus train: error: ...``, exit status 2.
    """
    parser = _train_parser()
    known, rest = parser.parse_known_args(argv)  # --help: our flags and the pass-through, rl-zoo3 never runs
    from sb3_trpo_plus.engines import batch_engine_ids, has_batch_engine
    from sb3_trpo_plus.experiment import zoo_train

    if known.sim_threads < 0:
        parser.error(f"--sim-threads must be >= 0 (0: every CPU), got {known.sim_threads}")
    make: Callable[..., Any] | None = None
    chosen_vec_env = known.vec_env
    if known.workers is not None:
        if known.vec_env is not None:
            parser.error(f"--workers collects with its own workers' envs; --vec-env {known.vec_env} does not apply")
        if known.algo != "trpo_plus":
            parser.error(f"--workers collects whole segments for trpo_plus only, got --algo {known.algo}")
        backend, count = known.workers
        origin = f"--workers {backend}:{count}"
        make = _workers_factory(backend, count, known.sim_threads, origin, _torch_threads_given(rest))
        known.vec_env = "dummy"
    else:
        if known.vec_env is None:  # the same transitions as dummy, faster from a few envs on
            known.vec_env = "batch" if has_batch_engine(known.env) else "dummy"
        if known.vec_env == "batch":
            if not has_batch_engine(known.env):
                ids = ", ".join(batch_engine_ids())
                parser.error(f"--vec-env batch runs the tasks of grasp_envs ({ids}), got {known.env}")
            from sb3_trpo_plus.zoo import batch_training_env

            make = functools.partial(batch_training_env, n_threads=known.sim_threads)
        elif known.sim_threads != 1:
            parser.error("--sim-threads sets the physics threads of --vec-env batch or --workers")

    def recipe_workers(value: str) -> Callable[..., Any]:
        """The training envs of a recipe's ``rollout_workers`` on this command line."""
        if make is not None and known.workers is not None:
            return make  # --workers replaces the recipe's
        if chosen_vec_env is not None:
            _fail(
                parser,
                f"the recipe of {known.env} collects with rollout workers (rollout_workers: {value});"
                f" --vec-env {chosen_vec_env} does not apply: leave it out, or add"
                " --hyperparams rollout_workers:None overlap_collection:False",
            )
        if known.algo != "trpo_plus":
            _fail(parser, f"rollout_workers collect whole segments for trpo_plus, not {known.algo}")
        from sb3_trpo_plus.zoo import parse_workers

        try:
            backend, count = parse_workers(value)
        except ValueError as error:
            _fail(parser, f"rollout_workers: {error}")
        origin = f"(the recipe's rollout_workers: {value})"
        return _workers_factory(backend, count, known.sim_threads, origin, _torch_threads_given(rest))

    _check_env_id(parser, known.env, rest)
    vec_env = "dummy" if known.vec_env == "batch" else known.vec_env
    conf_path, rest = _conf_file(parser, rest)
    try:
        zoo_train(_zoo_argv(known.algo, known.env, conf_path, [*rest, "--vec-env", vec_env]), make, recipe_workers)
    except ArgumentError as error:  # a YAML file or an override that cannot work (HyperparameterError names its file)
        from sb3_trpo_plus.zoo import ALGO_FILES, ZOO_DIR, HyperparameterError

        if isinstance(error, HyperparameterError):
            _fail(parser, str(error))
        source = f"{conf_path or ZOO_DIR / ALGO_FILES[known.algo]}: {known.env}"
        overrides = [flag for flag in ("-params", "--hyperparams") if flag in rest]
        _fail(parser, f"{source}{f' with {overrides[0]}' if overrides else ''}: {error}")


TRAIN_EPILOG = """\
every other rl-zoo3 train flag passes through unchanged, for example:
  -n N, --n-timesteps N          training budget (default: the recipe's n_timesteps)
  --seed SEED                    random seed
  -f DIR, --log-folder DIR       where the run is saved (default: logs)
  -tb DIR, --tensorboard-log DIR TensorBoard log folder
  --eval-freq N                  evaluate every N steps (-1: never)
  -conf FILE, --conf-file FILE   hyperparameter YAML, checked before rl-zoo3 reads it
                                 (default: the recipes of --algo, zoo_hyperparams/<algo>.yml)
  -params KEY:VALUE [KEY:VALUE ...], --hyperparams KEY:VALUE [KEY:VALUE ...]
                                 override keys of the recipe (VALUE: Python, e.g. n_envs:8)
  -optimize, --optimize-hyperparameters
                                 tune the hyperparameters with Optuna
  -i ZIP, --trained-agent ZIP    continue a run from <run>/<ENV>.zip
  --num-threads N                PyTorch threads of the learner (default: 1 with rollout worker
                                 processes, as Grasper3D-v7's recipe collects; else PyTorch's)
list them all with: python -m rl_zoo3.train --help
"""


def _train_parser() -> CommandLineParser:
    parser = CommandLineParser(
        prog="trpo-plus train",
        description=textwrap.fill(
            "Train an agent with rl-zoo3's train and the YAML recipe of --env for --algo. Ctrl-C stops at the next env "
            "step and saves the run (model, replay memory, VecNormalize statistics); -i <run>/<ENV>.zip resumes it.",
            width=79,
        ),
        epilog=TRAIN_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES, help=ALGO_HELP)
    parser.add_argument("--env", required=True, help="environment id (the tasks of grasp_envs, or any Gymnasium id)")
    parser.add_argument(
        "--vec-env",
        default=None,
        choices=("dummy", "subproc", "batch"),
        help="how the training envs are stepped; default: batch (the batched engine: the transitions of dummy, "
        "faster) for the tasks of grasp_envs, dummy for any other env",
    )
    parser.add_argument(
        "--sim-threads",
        type=int,
        default=1,
        metavar="N",
        help="physics threads of --vec-env batch or of each --workers worker (0: every CPU; default: 1)",
    )
    parser.add_argument(
        "--workers",
        type=_workers_option,
        default=None,
        metavar="BACKEND:N",
        help="collect with N rollout workers (inprocess, process or ray), the recipe's n_envs split over them; "
        "replaces a recipe's rollout_workers",
    )
    return parser


def _fail(parser: argparse.ArgumentParser, message: str) -> NoReturn:
    """Stop the command with one line, ``<prog>: error: <message>``, exit status 2 (as argparse's errors)."""
    parser.exit(2, f"{parser.prog}: error: {message}\n")


def _check_env_id(parser: argparse.ArgumentParser, env_id: str, rest: Sequence[str]) -> None:
    """``--env`` names a registered env once rl-zoo3's envs, grasp_envs and the ``--gym-packages`` are imported (as
    rl-zoo3 checks, but in one line)."""
    import difflib
    import importlib

    import gymnasium as gym
    import rl_zoo3.import_envs  # noqa: F401  (the envs rl-zoo3 registers)

    packages = argparse.ArgumentParser(add_help=False)
    packages.add_argument("--gym-packages", nargs="+", default=[])
    for package in ["grasp_envs", *packages.parse_known_args(rest)[0].gym_packages]:
        try:
            importlib.import_module(package)
        except ImportError as error:
            _fail(parser, f"argument --gym-packages: cannot import {package}: {error}")
    if env_id not in gym.registry:
        close = difflib.get_close_matches(env_id, list(gym.registry), n=1)
        _fail(parser, f"argument --env: no env {env_id!r} is registered{f' (did you mean {close[0]}?)' if close else ''}")


def _conf_file(parser: argparse.ArgumentParser, rest: Sequence[str]) -> tuple[str | None, list[str]]:
    """``-conf FILE`` / ``--conf-file FILE`` (the last one given), and the other flags."""
    rest = list(rest)
    conf_path = None
    for flag in ("-conf", "--conf-file"):
        while flag in rest:
            index = rest.index(flag)
            if index + 1 >= len(rest) or rest[index + 1].startswith("-"):
                parser.error("argument -conf/--conf-file: expected one argument")
            conf_path = rest[index + 1]
            del rest[index : index + 2]
    for item in list(rest):
        flag, equals, value = item.partition("=")
        if equals and flag in ("-conf", "--conf-file"):
            conf_path = value
            rest.remove(item)
    return conf_path, rest


WORKER_LAYOUT_TORCH_THREADS = 1
"""The learner's PyTorch threads where rollout worker processes (``process``, ``ray``) collect and no
``--num-threads`` is given: the learner's update then shares the cores with the workers' physics, and one thread
trained Grasper3D-v7's recipe 1.43 x as fast as two on 2 cores (``python -m benchmarks.torch_threads``,
docs/benchmarks.md). Where the learner's own process collects (batched engine, ``DummyVecEnv``), PyTorch's default
(every core) was level or faster, and stays."""


def _torch_threads_given(rest: Sequence[str]) -> bool:
    """Whether rl-zoo3's ``--num-threads`` is on the command line."""
    return any(arg == "--num-threads" or arg.startswith("--num-threads=") for arg in rest)


def _workers_factory(
    backend: str, count: int, sim_threads: int, origin: str, torch_threads_given: bool = False
) -> Callable[..., Any]:
    """The training envs of ``BACKEND:N`` workers (:func:`sb3_trpo_plus.zoo.workers_training_env`); a Ray cluster
    that refuses this process' token stops the command with one line naming ``origin`` (the flag or the key). With
    worker processes, the learner takes ``WORKER_LAYOUT_TORCH_THREADS`` unless ``--num-threads`` was given."""
    from sb3_trpo_plus.zoo import workers_training_env

    if backend in ("process", "ray") and not torch_threads_given:
        import torch as th

        th.set_num_threads(WORKER_LAYOUT_TORCH_THREADS)

    if backend == "ray":
        from sb3_trpo_plus.ray_cluster import RayAuthenticationError, check_cluster_token

        try:
            check_cluster_token()  # before rl-zoo3 builds anything: one line, not Ray's 20 s of retries
        except RayAuthenticationError as error:
            raise SystemExit(f"trpo-plus train {origin}: {error}") from None
    return functools.partial(workers_training_env, backend=backend, num_workers=count, n_threads=sim_threads)


def _enjoy_parser() -> CommandLineParser:
    parser = CommandLineParser(
        prog="trpo-plus enjoy",
        description="Run a trained agent; print every episode's return and length and the success rate. Reads the "
        "run as data only (weights-only load); --trust-pickle hands the run to rl-zoo3's enjoy, which unpickles the "
        "model and statistics (for runs you trust). Without a display nothing is rendered (trpo-plus record-video "
        "films the agent).",
        epilog="With --trust-pickle every other rl-zoo3 enjoy flag passes through unchanged; list them with: "
        "python -m rl_zoo3.enjoy --help",
    )
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES, help=ALGO_HELP)
    parser.add_argument("--env", required=True, help="environment id of the run")
    parser.add_argument("-f", "--folder", default=None, help="rl-zoo log folder (default: logs, else trained_agents)")
    parser.add_argument("--exp-id", type=int, default=0, help="run number, <folder>/<algo>/<env>_<N> (0: latest run)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=1000, help="steps to run (default: 1000)")
    parser.add_argument("--n-envs", type=int, default=1, help="envs stepped at once (default: 1)")
    parser.add_argument("--no-render", action="store_true", help="do not show the env")
    parser.add_argument("--deterministic", action="store_true", help="the policy's mean action (the default)")
    parser.add_argument("--stochastic", action="store_true", help="sample the policy's actions")
    parser.add_argument("--load-best", action="store_true", help="the run's best_model.zip (saved by evaluations)")
    parser.add_argument("--load-checkpoint", type=int, default=None, metavar="N", help="rl_model_<N>_steps.zip")
    parser.add_argument("--load-last-checkpoint", action="store_true", help="the run's latest rl_model_<N>_steps.zip")
    parser.add_argument("--norm-reward", action="store_true", help="show normalised rewards")
    parser.add_argument("--seed", type=int, default=0, help="seed of the envs (default: 0)")
    parser.add_argument("--device", default="cpu", help="torch device of the policy (default: cpu)")
    parser.add_argument("--num-threads", type=int, default=-1, help="PyTorch threads (-1: PyTorch's default)")
    parser.add_argument("--verbose", type=int, default=1, help="0: print nothing per episode")
    parser.add_argument(
        "--env-kwargs",
        nargs="+",
        type=_literal_pair,
        default=None,
        metavar="KEY:VALUE",
        help="keyword arguments of the env, VALUE a Python literal (else a string)",
    )
    parser.add_argument("--gym-packages", nargs="+", default=[], help="modules to import (they register envs)")
    parser.add_argument("--trust-pickle", action="store_true", help="unpickle the run with rl-zoo3's enjoy")
    return parser


def _literal_pair(pair: str) -> tuple[str, Any]:
    """A ``KEY:VALUE`` command-line pair, VALUE read as a Python literal (rl-zoo3 evaluates it), else a string."""
    import ast

    key, sep, text = pair.partition(":")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY:VALUE, got {pair!r}")
    try:
        return key, ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return key, text  # a bare word: a string


def enjoy(argv: Sequence[str]) -> dict[str, Any]:
    """``trpo-plus enjoy --env ID [--algo ...] [-f folder] [-n steps] [--no-render] [--trust-pickle] ...``.

    Reads the run through the weights-only path (nothing unpickled or evaluated); ``--trust-pickle`` runs
    rl-zoo3's enjoy instead. Renders nothing without a display. Prints every episode's return and length
    and the success rate; returns them.
    """
    argv = list(argv)
    parser = _enjoy_parser()
    if "-h" in argv or "--help" in argv:
        parser.parse_args(["--help"])  # both paths: this help, and exit
    _headless()
    if "--trust-pickle" in argv:
        return _zoo_enjoy([a for a in argv if a != "--trust-pickle"])
    args = parser.parse_args(argv)
    import importlib

    import torch as th

    for package in args.gym_packages:
        importlib.import_module(package)
    if args.num_threads > 0:
        th.set_num_threads(args.num_threads)
    if not args.no_render and os.environ.get("MUJOCO_GL") == "egl" and not os.environ.get("DISPLAY"):
        print("trpo-plus enjoy: no display, running with --no-render (trpo-plus record-video films the agent)")
        args.no_render = True
    folder = args.folder or default_folder(args.algo, args.env)
    print(f"trpo-plus enjoy: loading from {folder}")
    checkpoint = None if args.load_checkpoint is None else str(args.load_checkpoint)
    try:
        agent, env, _ = load_trained(
            args.algo,
            args.env,
            folder,
            args.exp_id,
            args.load_best,
            args.seed,
            render=False,
            n_envs=args.n_envs,
            render_mode=None if args.no_render else "human",
            env_kwargs=dict(args.env_kwargs or ()),
            load_checkpoint=checkpoint,
            load_last_checkpoint=args.load_last_checkpoint,
            norm_reward=args.norm_reward,
            device=args.device,
        )
    except RunNotFoundError as error:
        _fail(parser, str(error))
    returns: list[float] = []
    lengths: list[int] = []
    successes: list[bool] = []
    episode_return, episode_length = 0.0, 0
    obs = env.reset()
    try:
        for _ in range(args.n_timesteps):
            action, _ = agent.predict(obs, deterministic=not args.stochastic)
            obs, reward, done, infos = env.step(action)
            if not args.no_render:
                env.render()
            episode_return += float(reward[0])
            episode_length += 1
            if done[0]:
                returns.append(episode_return)
                lengths.append(episode_length)
                if infos[0].get("is_success") is not None:
                    successes.append(bool(infos[0]["is_success"]))
                if args.verbose > 0:
                    print(f"Episode Reward: {episode_return:.2f}")
                    print("Episode Length", episode_length)
                episode_return, episode_length = 0.0, 0
    except KeyboardInterrupt:
        pass
    finally:
        env.close()
    summary: dict[str, Any] = {"episodes": len(returns), "returns": returns, "lengths": lengths}
    if args.verbose > 0 and returns:
        print(f"{len(returns)} Episodes")
        print(f"Mean reward: {np.mean(returns):.2f} +/- {np.std(returns):.2f}")
    if successes:
        summary["success_rate"] = float(np.mean(successes))
        if args.verbose > 0:
            print(f"Success rate: {100 * summary['success_rate']:.2f}%")
    return summary


def _zoo_enjoy(argv: Sequence[str]) -> dict[str, Any]:
    """rl-zoo3's enjoy (unpickles the model and statistics), after the run's YAML files were checked to be data."""
    parser = CommandLineParser(prog="trpo-plus enjoy", add_help=False)
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("--env", required=True)
    parser.add_argument("-f", "--folder", default=None)
    parser.add_argument("--exp-id", type=int, default=0)
    known, rest = parser.parse_known_args(argv)
    import rl_zoo3.enjoy

    from sb3_trpo_plus.experiment import zoo_command_line, zoo_parser
    from sb3_trpo_plus.zoo import register_in_rl_zoo

    register_in_rl_zoo()
    packages = [] if "--gym-packages" in rest else ["--gym-packages", "grasp_envs"]
    if os.environ.get("MUJOCO_GL") == "egl" and not os.environ.get("DISPLAY") and "--no-render" not in rest:
        print("trpo-plus enjoy: no display, running with --no-render (trpo-plus record-video films the agent)")
        rest = [*rest, "--no-render"]
    folder = known.folder or default_folder(known.algo, known.env)
    print(f"trpo-plus enjoy: loading from {folder} (--trust-pickle: rl-zoo3 unpickles the run)")
    zoo_argv = ["--algo", known.algo, "--env", known.env, "-f", folder, "--exp-id", str(known.exp_id), *packages, *rest]
    try:
        with zoo_command_line(zoo_argv), zoo_parser(rl_zoo3.enjoy, parser.prog), validated_run_folders(known.env):
            rl_zoo3.enjoy.enjoy()
    except RunNotFoundError as error:
        _fail(parser, str(error))
    return {}


def record_video(argv: Sequence[str]) -> list[Path]:
    """``trpo-plus record-video --env ID [--algo] [-f logs] [--exp-id 0] [-n steps] [-o out.mp4|DIR] [--gif]
    [--trust-pickle]``.

    Loads the run through the weights-only path; ``--trust-pickle`` unpickles it with SB3 (trusted runs only).
    ``-o`` is an MP4 file, or a folder (one that exists, or a path ending with a separator or without a suffix) to
    write ``<env>.mp4`` into.
    """
    parser = CommandLineParser(
        prog="trpo-plus record-video",
        description="Film a trained agent (rendered off-screen) to an MP4, and a GIF beside it with --gif. Reads the "
        "run as data only (weights-only load) unless --trust-pickle.",
    )
    parser.add_argument("--env", required=True, help="environment id of the run")
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES, help=ALGO_HELP)
    parser.add_argument("-f", "--folder", default=None, help="rl-zoo log folder (default: logs, else trained_agents)")
    parser.add_argument("--exp-id", type=int, default=0, help="run number, <folder>/<algo>/<env>_<N> (0: latest run)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="steps to film (default: two episodes)")
    parser.add_argument(
        "-o",
        "--output",
        default=None,
        metavar="OUT.mp4|DIR",
        help="the MP4 file, or a folder for <env>.mp4 (default: <run>/videos/<env>.mp4)",
    )
    parser.add_argument("--gif", action="store_true", help="also write a GIF beside the MP4")
    parser.add_argument("--load-best", action="store_true", help="the run's best_model.zip (saved by evaluations)")
    parser.add_argument("--stochastic", action="store_true", help="sample the policy's actions (default: its mean)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the env (default: 0)")
    parser.add_argument("--trust-pickle", action="store_true", help="load with SB3 (unpickles the run: trusted runs only)")
    args = parser.parse_args(argv)
    output = None if args.output is None else _video_path(parser, args.output, args.env)
    _headless()
    args.folder = args.folder or default_folder(args.algo, args.env)
    try:
        model, env, log_path = load_trained(
            args.algo, args.env, args.folder, args.exp_id, args.load_best, args.seed, True, trust_pickle=args.trust_pickle
        )
    except RunNotFoundError as error:
        _fail(parser, str(error))
    spec_steps = env.get_attr("spec")[0].max_episode_steps or 200
    steps = args.n_timesteps or 2 * spec_steps
    frames = []
    obs = env.reset()
    for _ in range(steps):
        frames.append(env.env_method("render")[0])
        action, _ = model.predict(obs, deterministic=not args.stochastic)
        obs, _, _, _ = env.step(action)
    env.close()
    output = output or Path(log_path) / "videos" / f"{args.env}.mp4"
    paths = write_video(frames, output, fps=round(1.0 / env.get_attr("dt")[0]), gif=args.gif)
    print(f"wrote {', '.join(map(str, paths))}")
    return paths


def _video_path(parser: argparse.ArgumentParser, output: str, env_id: str) -> Path:
    """``-o``: an ``.mp4`` file, or a folder (rl-zoo3's ``-o`` is one) for ``<env>.mp4``: a folder that exists, or a
    path that ends with a separator or has no suffix. Any other suffix stops the command with one line."""
    path = Path(output)
    if path.is_dir() or output.endswith(("/", os.sep)) or not path.suffix:
        return path / f"{env_id}.mp4"
    if path.suffix.lower() != ".mp4":
        parser.error(f"argument -o/--output: writes an MP4 (OUT.mp4) or into a folder, got {output!r}")
    return path


def write_video(frames: list[np.ndarray], output: Path, fps: int, gif: bool = False) -> list[Path]:
    """Write RGB frames to an MP4 (H.264) and optionally a GIF beside it; return the paths."""
    from moviepy import ImageSequenceClip

    output.parent.mkdir(parents=True, exist_ok=True)
    clip = ImageSequenceClip([np.asarray(f) for f in frames], fps=fps)
    clip.write_videofile(str(output), codec="libx264", audio=False, logger=None)
    paths = [output]
    if gif:
        clip.write_gif(str(output.with_suffix(".gif")), logger=None)
        paths.append(output.with_suffix(".gif"))
    return paths


def plot(argv: Sequence[str]) -> Path:
    """``trpo-plus plot --env ID [--algos trpo_plus trpo ppo] [-f logs] [--runs DIR ...] [-o curve.png]``.

    Episode reward and success rate against timesteps, mean ± std over the runs (seeds) of each
    algorithm, from the runs' monitor CSVs.
    """
    from matplotlib.backend_bases import FigureCanvasBase
    from stable_baselines3.common.monitor import LoadMonitorResultsError

    from sb3_trpo_plus.plotting import learning_curve_figure

    parser = CommandLineParser(
        prog="trpo-plus plot",
        description="Plot the learning curves of runs: episode reward and success rate against timesteps, mean and "
        "std over the runs (seeds) of each algorithm, from the runs' monitor CSVs.",
    )
    parser.add_argument("--env", required=True, help="environment id of the runs (the plot's title)")
    parser.add_argument(
        "--algos",
        nargs="+",
        default=list(ALGO_CHOICES),
        metavar="ALGO",
        help=f"algorithms whose runs <folder>/<algo>/<env>_<N> are plotted (default: {' '.join(ALGO_CHOICES)})",
    )
    parser.add_argument("-f", "--folder", default="logs", help="rl-zoo log folder (default: logs)")
    parser.add_argument(
        "--runs",
        nargs="*",
        default=None,
        metavar="[LABEL=]DIR",
        help="run folders to plot instead, each labelled LABEL (default: the name of its parent folder)",
    )
    parser.add_argument(
        "-o",
        "--output",
        default=None,
        metavar="FILE",
        help="the figure; its suffix picks the format (default: <folder>/<env>_learning_curve.png)",
    )
    args = parser.parse_args(argv)
    output = Path(args.output or Path(args.folder) / f"{args.env}_learning_curve.png")
    formats = FigureCanvasBase.get_supported_filetypes()
    if output.is_dir() or output.suffix[1:].lower() not in formats:
        parser.error(f"argument -o/--output: a figure file ({', '.join(f'.{f}' for f in formats)}), got {str(output)!r}")
    groups: dict[str, list[Path]] = {}
    if args.runs:
        for run in args.runs:
            label, _, folder = run.rpartition("=")
            if not Path(folder).is_dir():
                _fail(parser, f"--runs {run}: {folder} is no folder")
            groups.setdefault(label or Path(folder).parent.name, []).append(Path(folder))
    else:
        for algo in args.algos:
            runs = sorted(Path(args.folder, algo).glob(f"{args.env}_*"))
            if runs:
                groups[algo] = runs
    if not groups:
        _fail(parser, f"no runs of {args.env} found under {args.folder}/{{{','.join(args.algos)}}}")
    try:
        learning_curve_figure(groups, args.env, output)
    except LoadMonitorResultsError as error:
        _fail(parser, f"{error} (a run folder holds them)")
    print(f"wrote {output}")
    return output


MAIN_ENV = "Grasper3D-v7"
MAIN_STEPS = {"Grasper3D-v7": 1_000_000}
"""``trpo-plus main``'s budgets where they differ from the recipe's ``n_timesteps``: Grasper3D-v7's recipe reached 90 %
held-out lifts within 0.72M env steps on each of twenty seeds (docs/results.md, a grasp in minutes), so 1M steps
(about two minutes on 2 cores) make the headline job; the recipe's 2M is the budget of the shipped agent."""
MAIN_EVALUATIONS = 10
"""Evaluations during training (rl-zoo3's EvalCallback, 10 episodes each): the run's best model and its curve."""


def main_job(argv: Sequence[str]) -> dict[str, Any]:
    """``trpo-plus main``: train with the recipe, then evaluate on held-out episodes, plot the learning curve and film
    the trained agent; prints where each file is."""
    _headless()
    parser = CommandLineParser(
        prog="trpo-plus main",
        description="Train an env's recipe (zoo_hyperparams/), then evaluate the policy on held-out episodes, plot its "
        "learning curve and film it; TensorBoard logs under OUT/tensorboard.",
    )
    parser.add_argument("--env", default=MAIN_ENV, help=f"the task (default: {MAIN_ENV})")
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument(
        "--steps",
        type=int,
        default=None,
        help=f"training budget in env steps (default: {MAIN_STEPS[MAIN_ENV]:,} for {MAIN_ENV}, else the recipe's n_timesteps)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sim-threads", type=int, default=0, help="physics threads of the batched engine (0: every CPU)")
    parser.add_argument("--out", default="results", help="output folder (default: results)")
    parser.add_argument("--eval-episodes", type=int, default=50, help="held-out episodes of the final evaluation")
    args = parser.parse_args(argv)
    from sb3_trpo_plus.engines import has_batch_engine
    from sb3_trpo_plus.recipes import recipe

    for name in ("steps", "eval_episodes"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    try:
        budget = args.steps or MAIN_STEPS.get(args.env) or int(recipe(args.env, args.algo)["n_timesteps"])
    except ValueError as error:
        parser.error(str(error))
    out = Path(args.out)
    logs = out / "logs"
    zoo_args = ["--seed", str(args.seed), "-f", str(logs), "-tb", str(out / "tensorboard"), "-n", str(budget)]
    zoo_args += ["--eval-episodes", "10", "--eval-freq", str(max(budget // MAIN_EVALUATIONS, 1)), "--progress"]
    if has_batch_engine(args.env):
        zoo_args += ["--sim-threads", str(args.sim_threads)]
    train(["--algo", args.algo, "--env", args.env, *zoo_args])

    model, env, log_path = load_trained(args.algo, args.env, str(logs), 0, False, 10_000 + args.seed, False)
    summary = {"env": args.env, "algo": args.algo, "seed": args.seed, "model": str(Path(log_path) / f"{args.env}.zip")}
    from sb3_trpo_plus.evaluation import evaluate_agent

    # the env was made with this seed; one seeded stream of episodes, as the command always evaluated
    result = evaluate_agent(model, env, args.eval_episodes, seed=10_000 + args.seed, seed_every_episode=False)
    summary.update(
        {
            "episodes": result.episodes,
            "mean_reward": result.mean_return,
            "std_reward": result.std_return,
            "success_rate": result.success_rate,
        }
    )
    env.close()
    summary_path = Path(log_path) / "evaluation.json"
    summary_path.write_text(json.dumps(summary, indent=2))
    curve = plot(["--env", args.env, "--runs", f"{args.algo}={log_path}", "-o", str(Path(log_path) / "learning_curve.png")])
    video = record_video(["--env", args.env, "--algo", args.algo, "-f", str(logs), "-o", str(Path(log_path) / "trained.mp4")])
    summary.update(
        {
            "evaluation": str(summary_path),
            "learning_curve": str(curve),
            "video": str(video[0]),
            "tensorboard": str(out / "tensorboard"),
        }
    )
    print("\n== trpo-plus main: result ==")
    for key, value in summary.items():
        print(f"{key:>15}: {value}")
    print(f"TensorBoard: tensorboard --logdir {out / 'tensorboard'}")
    return summary


COMMANDS = {"train": train, "enjoy": enjoy, "record-video": record_video, "plot": plot, "main": main_job}
SUMMARIES = {
    "train": "train an agent with rl-zoo3 and the YAML recipe of its env (rl-zoo3's train flags pass through)",
    "enjoy": "run a trained agent; print its episodes' returns and success rate",
    "record-video": "film a trained agent to an MP4 (and a GIF)",
    "plot": "plot the learning curves of runs (reward, success rate against timesteps)",
    "main": "train, evaluate, plot and film in one go (Grasper3D-v7 by default, about 3 minutes on 2 cores)",
}


def usage() -> str:
    """``trpo-plus --help``: the commands, one line each, and how to get a command's help."""
    width = max(map(len, COMMANDS))
    lines = [
        f"usage: trpo-plus {{{','.join(COMMANDS)}}} [options]",
        "",
        "TRPOPlus (TRPO with a replay memory and a warm-started conjugate gradient) on rl-zoo3.",
        "",
        "commands:",
        *(f"  {name:<{width}}  {SUMMARIES[name]}" for name in COMMANDS),
        "",
        "trpo-plus COMMAND --help shows the options of COMMAND.",
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> None:
    """``trpo-plus COMMAND [options]``; ``trpo-plus``, ``-h`` or ``--help`` print :func:`usage`; an unknown command is
    one line on stderr, exit status 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"}:
        print(usage())
        raise SystemExit(0)
    if argv[0] not in COMMANDS:
        print(
            f"trpo-plus: error: unknown command {argv[0]!r} (choose from {', '.join(COMMANDS)}; trpo-plus --help)",
            file=sys.stderr,
        )
        raise SystemExit(2)
    COMMANDS[argv[0]](argv[1:])


if __name__ == "__main__":
    main()
