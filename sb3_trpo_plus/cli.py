"""``trpo-plus``: train / enjoy / record-video / plot / main, on top of rl-zoo3.

Every rl-zoo3 flag passes through ``train`` and ``enjoy`` unchanged; we register TRPOPlus in rl-zoo3,
import ``grasp_envs`` and default ``-conf`` to our validated YAML for the chosen algorithm.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

ALGO_CHOICES = ("trpo_plus", "trpo", "ppo")
# Shipped agents: the source checkout's folder; a wheel carries none, so then ./trained_agents (a clone or a download)
_CHECKOUT_AGENTS = Path(__file__).resolve().parents[1] / "trained_agents"
TRAINED_AGENTS = _CHECKOUT_AGENTS if _CHECKOUT_AGENTS.is_dir() else Path("trained_agents")


def _default_folder(algo: str, env: str) -> str:
    """``logs`` when it holds a run of (algo, env), else the shipped ``trained_agents`` when that does."""
    for folder in (Path("logs"), TRAINED_AGENTS):
        if any((folder / algo).glob(f"{env}_[0-9]*")):
            return str(folder)
    return "logs"


def _headless() -> None:
    """Render off-screen when there is no display (MuJoCo reads MUJOCO_GL when it first renders)."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("MUJOCO_GL", "egl")


def _zoo_argv(algo: str, env: str, rest: Sequence[str]) -> list[str]:
    from sb3_trpo_plus.zoo import config_module, register_in_rl_zoo

    register_in_rl_zoo()
    rest = list(rest)
    conf_path = None
    for flag in ("-conf", "--conf-file"):
        if flag in rest:
            index = rest.index(flag)
            conf_path = rest[index + 1]
            del rest[index : index + 2]
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
    """
    parser = argparse.ArgumentParser(prog="trpo-plus train", add_help=False)
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("--env", required=True)
    parser.add_argument(
        "--vec-env", default=None, choices=("dummy", "subproc", "batch"),
        help="default: batch for the tasks of grasp_envs, dummy for any other env",
    )  # fmt: skip
    parser.add_argument("--sim-threads", type=int, default=1, help="threads of the batched engine's physics")
    parser.add_argument(
        "--workers", type=_workers_option, default=None, metavar="BACKEND:N",
        help="collect with N rollout workers (inprocess, process or ray), the recipe's n_envs split over them",
    )  # fmt: skip
    known, rest = parser.parse_known_args(argv)
    if "-h" in rest or "--help" in rest:
        parser.print_help()
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
        make = _workers_factory(backend, count, known.sim_threads, f"--workers {backend}:{count}")
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
            raise SystemExit(
                f"trpo-plus train: the recipe of {known.env} collects with rollout workers (rollout_workers: {value});"
                f" --vec-env {chosen_vec_env} does not apply: leave it out, or add"
                " --hyperparams rollout_workers:None overlap_collection:False"
            )
        if known.algo != "trpo_plus":
            raise SystemExit(f"trpo-plus train: rollout_workers collect whole segments for trpo_plus, not {known.algo}")
        from sb3_trpo_plus.zoo import parse_workers

        try:
            backend, count = parse_workers(value)
            return _workers_factory(backend, count, known.sim_threads, f"(the recipe's rollout_workers: {value})")
        except ValueError as error:
            raise SystemExit(f"trpo-plus train: rollout_workers: {error}") from None

    vec_env = "dummy" if known.vec_env == "batch" else known.vec_env
    zoo_train(_zoo_argv(known.algo, known.env, [*rest, "--vec-env", vec_env]), make, recipe_workers)


def _workers_factory(backend: str, count: int, sim_threads: int, origin: str) -> Callable[..., Any]:
    """The training envs of ``BACKEND:N`` workers (:func:`sb3_trpo_plus.zoo.workers_training_env`); a Ray cluster
    that refuses this process' token stops the command with one line naming ``origin`` (the flag or the key)."""
    from sb3_trpo_plus.zoo import workers_training_env

    if backend == "ray":
        from sb3_trpo_plus.ray_cluster import RayAuthenticationError, check_cluster_token

        try:
            check_cluster_token()  # before rl-zoo3 builds anything: one line, not Ray's 20 s of retries
        except RayAuthenticationError as error:
            raise SystemExit(f"trpo-plus train {origin}: {error}") from None
    return functools.partial(workers_training_env, backend=backend, num_workers=count, n_threads=sim_threads)


def _enjoy_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="trpo-plus enjoy",
        description="Run a trained agent. Reads the run as data only (weights-only load); --trust-pickle hands "
        "the run to rl-zoo3's enjoy, which unpickles the model and statistics (for runs you trust).",
    )
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("--env", required=True)
    parser.add_argument("-f", "--folder", default=None, help="rl-zoo log folder (default: logs, else trained_agents)")
    parser.add_argument("--exp-id", type=int, default=0, help="0: latest run")
    parser.add_argument("-n", "--n-timesteps", type=int, default=1000)
    parser.add_argument("--n-envs", type=int, default=1)
    parser.add_argument("--no-render", action="store_true")
    parser.add_argument("--deterministic", action="store_true", help="(the default)")
    parser.add_argument("--stochastic", action="store_true")
    parser.add_argument("--load-best", action="store_true")
    parser.add_argument("--load-checkpoint", type=int, default=None, help="rl_model_<N>_steps.zip")
    parser.add_argument("--load-last-checkpoint", action="store_true")
    parser.add_argument("--norm-reward", action="store_true", help="show normalised rewards")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--num-threads", type=int, default=-1)
    parser.add_argument("--verbose", type=int, default=1)
    parser.add_argument("--env-kwargs", nargs="+", default=None, metavar="KEY:VALUE", help="VALUE a Python literal")
    parser.add_argument("--gym-packages", nargs="+", default=[], help="modules to import (they register envs)")
    parser.add_argument("--trust-pickle", action="store_true", help="unpickle the run with rl-zoo3's enjoy")
    return parser


def _literal_kwargs(pairs: Sequence[str] | None) -> dict[str, Any]:
    """``KEY:VALUE`` command-line pairs, VALUE read as a Python literal (rl-zoo3 evaluates it)."""
    import ast

    result: dict[str, Any] = {}
    for pair in pairs or ():
        key, sep, text = pair.partition(":")
        if not sep:
            raise SystemExit(f"--env-kwargs: expected KEY:VALUE, got {pair!r}")
        try:
            result[key] = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            result[key] = text  # a bare word: a string
    return result


def enjoy(argv: Sequence[str]) -> dict[str, Any]:
    """``trpo-plus enjoy --env ID [--algo ...] [-f folder] [-n steps] [--no-render] [--trust-pickle] ...``.

    Reads the run through the weights-only path (nothing unpickled or evaluated); ``--trust-pickle`` runs
    rl-zoo3's enjoy instead. Renders nothing without a display. Prints every episode's return and length
    and the success rate; returns them.
    """
    _headless()
    argv = list(argv)
    if "--trust-pickle" in argv:
        return _zoo_enjoy([a for a in argv if a != "--trust-pickle"])
    args = _enjoy_parser().parse_args(argv)
    import importlib

    import torch as th

    for package in args.gym_packages:
        importlib.import_module(package)
    if args.num_threads > 0:
        th.set_num_threads(args.num_threads)
    if not args.no_render and os.environ.get("MUJOCO_GL") == "egl" and not os.environ.get("DISPLAY"):
        print("trpo-plus enjoy: no display, running with --no-render (trpo-plus record-video films the agent)")
        args.no_render = True
    folder = args.folder or _default_folder(args.algo, args.env)
    print(f"trpo-plus enjoy: loading from {folder}")
    checkpoint = None if args.load_checkpoint is None else str(args.load_checkpoint)
    agent, env, _ = _load_trained(
        args.algo, args.env, folder, args.exp_id, args.load_best, args.seed, render=False, n_envs=args.n_envs,
        render_mode=None if args.no_render else "human", env_kwargs=_literal_kwargs(args.env_kwargs),
        load_checkpoint=checkpoint, load_last_checkpoint=args.load_last_checkpoint, norm_reward=args.norm_reward,
        device=args.device,
    )  # fmt: skip
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
    parser = argparse.ArgumentParser(prog="trpo-plus enjoy", add_help=False)
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("--env", required=True)
    parser.add_argument("-f", "--folder", default=None)
    parser.add_argument("--exp-id", type=int, default=0)
    known, rest = parser.parse_known_args(argv)
    from rl_zoo3.enjoy import enjoy as zoo_enjoy

    from sb3_trpo_plus.experiment import zoo_command_line
    from sb3_trpo_plus.zoo import register_in_rl_zoo

    register_in_rl_zoo()
    packages = [] if "--gym-packages" in rest else ["--gym-packages", "grasp_envs"]
    if os.environ.get("MUJOCO_GL") == "egl" and not os.environ.get("DISPLAY") and "--no-render" not in rest:
        print("trpo-plus enjoy: no display, running with --no-render (trpo-plus record-video films the agent)")
        rest = [*rest, "--no-render"]
    folder = known.folder or _default_folder(known.algo, known.env)
    print(f"trpo-plus enjoy: loading from {folder} (--trust-pickle: rl-zoo3 unpickles the run)")
    zoo_argv = ["--algo", known.algo, "--env", known.env, "-f", folder, "--exp-id", str(known.exp_id), *packages, *rest]
    with zoo_command_line(zoo_argv), _validated_run_folders(known.env):
        zoo_enjoy()
    return {}


@contextlib.contextmanager
def _validated_run_folders(env_id: str) -> Iterator[None]:
    """While open, each run folder rl-zoo3's enjoy picks (``get_model_path``: a local run, or one it has just
    downloaded from the Hugging Face hub) is checked by :func:`sb3_trpo_plus.agents.validate_run_files` before
    rl-zoo3 reads its ``config.yml`` / ``args.yml`` with ``yaml.UnsafeLoader`` and evaluates ``normalize``; a damaged
    ``vecnormalize.pkl`` raises :class:`~sb3_trpo_plus.agents.RunFileError` naming it; the test env gets the run's
    ``env_wrapper`` without its training aids (:func:`sb3_trpo_plus.zoo.evaluation_wrappers`). rl-zoo3's ``enjoy``
    has no hooks for these: its module's names are replaced for the call and restored after it."""
    import rl_zoo3.enjoy as enjoy_module
    import rl_zoo3.utils as zoo_utils
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus.agents import load_trusted_file, validate_run_files
    from sb3_trpo_plus.zoo import evaluation_wrappers

    original = enjoy_module.get_model_path

    @functools.wraps(original)
    def get_model_path(*args: Any, **kwargs: Any) -> tuple[str, str, str]:
        name_prefix, model_path, log_path = original(*args, **kwargs)
        validate_run_files(log_path, env_id)
        return name_prefix, model_path, log_path

    class NamingVecNormalize(VecNormalize):
        """What rl-zoo3's ``create_test_env`` calls to unpickle the run's statistics."""

        @staticmethod
        def load(load_path: str, venv: Any) -> VecNormalize:
            return load_trusted_file(lambda: VecNormalize.load(load_path, venv), Path(load_path))

    create_test_env = enjoy_module.create_test_env

    @functools.wraps(create_test_env)
    def evaluation_test_env(*args: Any, **kwargs: Any) -> Any:
        hyperparams = kwargs.get("hyperparams")
        if hyperparams is not None and "env_wrapper" in hyperparams:
            kwargs["hyperparams"] = {**hyperparams, "env_wrapper": evaluation_wrappers(hyperparams["env_wrapper"])}
        return create_test_env(*args, **kwargs)

    enjoy_module.get_model_path = get_model_path
    enjoy_module.create_test_env = evaluation_test_env
    zoo_utils.VecNormalize = NamingVecNormalize  # type: ignore[misc]
    try:
        yield
    finally:
        enjoy_module.get_model_path = original
        enjoy_module.create_test_env = create_test_env
        zoo_utils.VecNormalize = VecNormalize  # type: ignore[misc]


def _load_trained(
    algo: str,
    env_id: str,
    folder: str,
    exp_id: int,
    load_best: bool,
    seed: int,
    render: bool,
    *,
    trust_pickle: bool = False,
    n_envs: int = 1,
    render_mode: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    load_checkpoint: str | None = None,
    load_last_checkpoint: bool = False,
    norm_reward: bool = False,
    device: str = "cpu",
) -> tuple[Any, Any, str]:
    """Agent and test env of an rl-zoo3 run (VecNormalize statistics and env kwargs restored), and the run folder.

    The weights-only path by default (:mod:`sb3_trpo_plus.agents`: nothing in the run is unpickled or evaluated);
    ``trust_pickle`` loads the full model with SB3. ``render`` makes the env render RGB frames.
    The env is seeded with ``seed`` (SB3's ``load(path, env=env)`` would reseed it with the model's training seed).
    """
    from huggingface_sb3 import EnvironmentName
    from rl_zoo3.utils import get_model_path

    from sb3_trpo_plus.agents import load_eval_agent

    env_name = EnvironmentName(env_id)
    _, model_path, log_path = get_model_path(
        exp_id, folder, algo, env_name, load_best, load_checkpoint=load_checkpoint, load_last_checkpoint=load_last_checkpoint
    )
    agent, env = load_eval_agent(
        log_path, env_id, model_path=model_path, trust_pickle=trust_pickle, seed=seed, n_envs=n_envs,
        render_mode="rgb_array" if render else render_mode, env_kwargs=env_kwargs, norm_reward=norm_reward,
        device=device,
    )  # fmt: skip
    return agent, env, log_path


def record_video(argv: Sequence[str]) -> list[Path]:
    """``trpo-plus record-video --env ID [--algo] [-f logs] [--exp-id 0] [-n steps] [-o out.mp4] [--gif] [--trust-pickle]``.

    Loads the run through the weights-only path; ``--trust-pickle`` unpickles it with SB3 (trusted runs only).
    """
    _headless()
    parser = argparse.ArgumentParser(prog="trpo-plus record-video")
    parser.add_argument("--env", required=True)
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("-f", "--folder", default=None, help="rl-zoo log folder (default: logs, else trained_agents)")
    parser.add_argument("--exp-id", type=int, default=0, help="0: latest run")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="default: two episodes")
    parser.add_argument("-o", "--output", default=None, help="MP4 path (default: <run>/videos/<env>.mp4)")
    parser.add_argument("--gif", action="store_true", help="also write a GIF beside the MP4")
    parser.add_argument("--load-best", action="store_true")
    parser.add_argument("--stochastic", action="store_true")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--trust-pickle", action="store_true", help="load with SB3 (unpickles the run: trusted runs only)")
    args = parser.parse_args(argv)
    args.folder = args.folder or _default_folder(args.algo, args.env)
    model, env, log_path = _load_trained(
        args.algo, args.env, args.folder, args.exp_id, args.load_best, args.seed, True, trust_pickle=args.trust_pickle
    )
    spec_steps = env.get_attr("spec")[0].max_episode_steps or 200
    steps = args.n_timesteps or 2 * spec_steps
    frames = []
    obs = env.reset()
    for _ in range(steps):
        frames.append(env.env_method("render")[0])
        action, _ = model.predict(obs, deterministic=not args.stochastic)
        obs, _, _, _ = env.step(action)
    env.close()
    output = Path(args.output) if args.output else Path(log_path) / "videos" / f"{args.env}.mp4"
    return write_video(frames, output, fps=round(1.0 / env.get_attr("dt")[0]), gif=args.gif)


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
    from sb3_trpo_plus.plotting import learning_curve_figure

    parser = argparse.ArgumentParser(prog="trpo-plus plot")
    parser.add_argument("--env", required=True)
    parser.add_argument("--algos", nargs="+", default=list(ALGO_CHOICES))
    parser.add_argument("-f", "--folder", default="logs", help="rl-zoo log folder")
    parser.add_argument("--runs", nargs="*", default=None, help="explicit run folders as LABEL=DIR or DIR")
    parser.add_argument("-o", "--output", default=None)
    args = parser.parse_args(argv)
    groups: dict[str, list[Path]] = {}
    if args.runs:
        for run in args.runs:
            label, _, folder = run.rpartition("=")
            groups.setdefault(label or Path(folder).parent.name, []).append(Path(folder))
    else:
        for algo in args.algos:
            runs = sorted(Path(args.folder, algo).glob(f"{args.env}_*"))
            if runs:
                groups[algo] = runs
    if not groups:
        raise SystemExit(f"trpo-plus plot: no runs of {args.env} found under {args.folder}/{{{','.join(args.algos)}}}")
    output = Path(args.output or Path(args.folder) / f"{args.env}_learning_curve.png")
    learning_curve_figure(groups, args.env, output)
    print(f"wrote {output}")
    return output


def main_job(argv: Sequence[str]) -> dict[str, Any]:
    """``trpo-plus main``: train with the zoo hyperparameters, then evaluate, plot and film the result."""
    _headless()
    parser = argparse.ArgumentParser(prog="trpo-plus main")
    parser.add_argument("--env", default="Reacher2D-v1")
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("--steps", type=int, default=None, help="training budget (default: the YAML's n_timesteps)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", default="results", help="output folder")
    parser.add_argument("--eval-episodes", type=int, default=50)
    args = parser.parse_args(argv)
    out = Path(args.out)
    logs = out / "logs"
    zoo_args = ["--seed", str(args.seed), "-f", str(logs), "-tb", str(out / "tensorboard"), "--eval-episodes", "10"]
    zoo_args += ["--eval-freq", "10000", "--progress", "--num-threads", "1"]
    if args.steps:
        zoo_args += ["-n", str(args.steps)]
    train(["--algo", args.algo, "--env", args.env, *zoo_args])

    model, env, log_path = _load_trained(args.algo, args.env, str(logs), 0, False, 10_000 + args.seed, False)
    summary = {"env": args.env, "algo": args.algo, "seed": args.seed, "model": str(Path(log_path) / f"{args.env}.zip")}
    from sb3_trpo_plus.evaluation import evaluate_agent

    # the env was made with this seed; one seeded stream of episodes, as the command always evaluated
    result = evaluate_agent(model, env, args.eval_episodes, seed=10_000 + args.seed, seed_every_episode=False)
    summary.update(
        {"episodes": result.episodes, "mean_reward": result.mean_return, "std_reward": result.std_return,
         "success_rate": result.success_rate}
    )  # fmt: skip
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
    return summary


COMMANDS = {"train": train, "enjoy": enjoy, "record-video": record_video, "plot": plot, "main": main_job}


def main(argv: Sequence[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in {"-h", "--help"} or argv[0] not in COMMANDS:
        print("usage: trpo-plus {" + ",".join(COMMANDS) + "} [options]   (trpo-plus <command> --help)")
        raise SystemExit(0 if not argv or argv[0] in {"-h", "--help"} else 2)
    COMMANDS[argv[0]](argv[1:])


if __name__ == "__main__":
    main()
