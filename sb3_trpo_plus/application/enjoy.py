"""``trpo-plus enjoy`` and ``trpo-plus record-video``: a trained agent on screen, or on film, read through the
weights-only path (or unpickled with SB3 under ``--trust-pickle``)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_trpo_plus.application.command_line import ALGO_CHOICES, ALGO_HELP, fail, headless
from sb3_trpo_plus.application.rl_zoo import RunNotFoundError
from sb3_trpo_plus.application.run_folders import default_folder, load_trained
from sb3_trpo_plus.common.arguments import CommandLineParser


def enjoy_parser() -> CommandLineParser:
    parser = CommandLineParser(
        prog="trpo-plus enjoy",
        description="Run a trained agent; print every episode's return and length and the success rate. Reads the "
        "run as data only (weights-only load); --trust-pickle unpickles the model and statistics with SB3 (for runs "
        "you trust). A run not found under a folder named rl-trained-agents is downloaded from the SB3 organisation "
        "on the Hugging Face hub, as rl-zoo3's enjoy does. Without a display nothing is rendered (trpo-plus "
        "record-video films the agent).",
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
    parser.add_argument("--trust-pickle", action="store_true", help="unpickle the model and statistics with SB3")
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

    Reads the run through the weights-only path (nothing unpickled or evaluated); ``--trust-pickle`` unpickles the
    model and statistics with SB3 (the run's YAML is still read as data). Renders nothing without a display. Prints
    every episode's return and length and the success rate; returns them.
    """
    parser = enjoy_parser()
    args = parser.parse_args(list(argv))
    headless()
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
    trusted = " (--trust-pickle: SB3 unpickles the run)" if args.trust_pickle else ""
    print(f"trpo-plus enjoy: loading from {folder}{trusted}")
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
            trust_pickle=args.trust_pickle,
            n_envs=args.n_envs,
            render_mode=None if args.no_render else "human",
            env_kwargs=dict(args.env_kwargs or ()),
            load_checkpoint=checkpoint,
            load_last_checkpoint=args.load_last_checkpoint,
            norm_reward=args.norm_reward,
            device=args.device,
        )
    except RunNotFoundError as error:
        fail(parser, str(error))
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
    headless()
    args.folder = args.folder or default_folder(args.algo, args.env)
    try:
        model, env, log_path = load_trained(
            args.algo, args.env, args.folder, args.exp_id, args.load_best, args.seed, True, trust_pickle=args.trust_pickle
        )
    except RunNotFoundError as error:
        fail(parser, str(error))
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
