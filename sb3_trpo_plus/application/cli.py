"""``trpo-plus``: train / enjoy / record-video / plot / main, on top of rl-zoo3.

Every rl-zoo3 flag passes through ``train`` and ``enjoy`` unchanged; we register TRPOPlus in rl-zoo3,
import ``grasp_envs`` and default ``-conf`` to our validated YAML for the chosen algorithm.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import textwrap
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from sb3_trpo_plus.application.command_line import ALGO_CHOICES, ALGO_HELP, fail, headless
from sb3_trpo_plus.application.enjoy import enjoy, record_video
from sb3_trpo_plus.application.run_folders import load_trained
from sb3_trpo_plus.common.arguments import ArgumentError, CommandLineParser


def _zoo_argv(algo: str, env: str, conf_path: str | None, rest: Sequence[str]) -> list[str]:
    """rl-zoo3's train flags: ``conf_path`` (default: our YAML of ``algo``) checked and handed over as a module."""
    from sb3_trpo_plus.application import rl_zoo

    rl_zoo.register()
    module = rl_zoo.config_module(algo, conf_path)
    packages = [] if "--gym-packages" in rest else ["--gym-packages", "grasp_envs"]
    return ["--algo", algo, "--env", env, "-conf", module, *packages, *rest]


def _workers_option(value: str) -> tuple[str, int]:
    """``--workers BACKEND:N`` as ``(backend, N)``."""
    from sb3_trpo_plus.application.zoo import parse_workers

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
    from sb3_trpo_plus.application import rl_zoo
    from sb3_trpo_plus.application.experiment import TRPOPlusExperimentManager
    from sb3_trpo_plus.rollouts.engines import batch_engine_ids, has_batch_engine

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
            from sb3_trpo_plus.application.zoo import batch_training_env

            make = functools.partial(batch_training_env, n_threads=known.sim_threads)
        elif known.sim_threads != 1:
            parser.error("--sim-threads sets the physics threads of --vec-env batch or --workers")

    def recipe_workers(value: str) -> Callable[..., Any]:
        """The training envs of a recipe's ``rollout_workers`` on this command line."""
        if make is not None and known.workers is not None:
            return make  # --workers replaces the recipe's
        if chosen_vec_env is not None:
            fail(
                parser,
                f"the recipe of {known.env} collects with rollout workers (rollout_workers: {value});"
                f" --vec-env {chosen_vec_env} does not apply: leave it out, or add"
                " --hyperparams rollout_workers:None overlap_collection:False",
            )
        if known.algo != "trpo_plus":
            fail(parser, f"rollout_workers collect whole segments for trpo_plus, not {known.algo}")
        from sb3_trpo_plus.application.zoo import parse_workers

        try:
            backend, count = parse_workers(value)
        except ValueError as error:
            fail(parser, f"rollout_workers: {error}")
        origin = f"(the recipe's rollout_workers: {value})"
        return _workers_factory(backend, count, known.sim_threads, origin, _torch_threads_given(rest))

    _check_env_id(parser, known.env, rest)
    vec_env = "dummy" if known.vec_env == "batch" else known.vec_env
    conf_path, rest = _conf_file(parser, rest)
    try:
        manager = TRPOPlusExperimentManager.with_training_envs(make, recipe_workers)
        rl_zoo.train(_zoo_argv(known.algo, known.env, conf_path, [*rest, "--vec-env", vec_env]), manager)
    except ArgumentError as error:  # a YAML file or an override that cannot work (HyperparameterError names its file)
        from sb3_trpo_plus.application.zoo import ALGO_FILES, ZOO_DIR, HyperparameterError

        if isinstance(error, HyperparameterError):
            fail(parser, str(error))
        source = f"{conf_path or ZOO_DIR / ALGO_FILES[known.algo]}: {known.env}"
        overrides = [flag for flag in ("-params", "--hyperparams") if flag in rest]
        fail(parser, f"{source}{f' with {overrides[0]}' if overrides else ''}: {error}")


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


def _check_env_id(parser: argparse.ArgumentParser, env_id: str, rest: Sequence[str]) -> None:
    """``--env`` names a registered env once rl-zoo3's envs, grasp_envs and the ``--gym-packages`` are imported (as
    rl-zoo3 checks, but in one line)."""
    import difflib
    import importlib

    import gymnasium as gym

    from sb3_trpo_plus.application.rl_zoo import import_zoo_envs

    import_zoo_envs()
    packages = argparse.ArgumentParser(add_help=False)
    packages.add_argument("--gym-packages", nargs="+", default=[])
    for package in ["grasp_envs", *packages.parse_known_args(rest)[0].gym_packages]:
        try:
            importlib.import_module(package)
        except ImportError as error:
            fail(parser, f"argument --gym-packages: cannot import {package}: {error}")
    if env_id not in gym.registry:
        close = difflib.get_close_matches(env_id, list(gym.registry), n=1)
        fail(parser, f"argument --env: no env {env_id!r} is registered{f' (did you mean {close[0]}?)' if close else ''}")


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
``--num-threads`` is given: the learner's update then shares the cores with the workers' physics, and one thread is
the faster layout (``python -m benchmarks.torch_threads``; the figures are in docs/benchmarks.md). Where the learner's
own process collects (batched engine, ``DummyVecEnv``), PyTorch's default (every core) measured level or faster, and
stays."""


def _torch_threads_given(rest: Sequence[str]) -> bool:
    """Whether rl-zoo3's ``--num-threads`` is on the command line."""
    return any(arg == "--num-threads" or arg.startswith("--num-threads=") for arg in rest)


def _workers_factory(
    backend: str, count: int, sim_threads: int, origin: str, torch_threads_given: bool = False
) -> Callable[..., Any]:
    """The training envs of ``BACKEND:N`` workers (:func:`sb3_trpo_plus.application.zoo.workers_training_env`); a Ray cluster
    that refuses this process' token stops the command with one line naming ``origin`` (the flag or the key). With
    worker processes, the learner takes ``WORKER_LAYOUT_TORCH_THREADS`` unless ``--num-threads`` was given."""
    from sb3_trpo_plus.application.zoo import workers_training_env

    if backend in ("process", "ray") and not torch_threads_given:
        import torch as th

        th.set_num_threads(WORKER_LAYOUT_TORCH_THREADS)

    if backend == "ray":
        from sb3_trpo_plus.rollouts.ray_cluster import RayAuthenticationError, check_cluster_token

        try:
            check_cluster_token()  # before rl-zoo3 builds anything: one line, not Ray's 20 s of retries
        except RayAuthenticationError as error:
            raise SystemExit(f"trpo-plus train {origin}: {error}") from None
    return functools.partial(workers_training_env, backend=backend, num_workers=count, n_threads=sim_threads)


def plot(argv: Sequence[str]) -> Path:
    """``trpo-plus plot --env ID [--algos trpo_plus trpo ppo] [-f logs] [--runs DIR ...] [-o curve.png]``.

    Episode reward and success rate against timesteps, mean ± std over the runs (seeds) of each
    algorithm, from the runs' monitor CSVs.
    """
    from matplotlib.backend_bases import FigureCanvasBase
    from stable_baselines3.common.monitor import LoadMonitorResultsError

    from sb3_trpo_plus.application.plotting import learning_curve_figure

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
                fail(parser, f"--runs {run}: {folder} is no folder")
            groups.setdefault(label or Path(folder).parent.name, []).append(Path(folder))
    else:
        for algo in args.algos:
            runs = sorted(Path(args.folder, algo).glob(f"{args.env}_*"))
            if runs:
                groups[algo] = runs
    if not groups:
        fail(parser, f"no runs of {args.env} found under {args.folder}/{{{','.join(args.algos)}}}")
    try:
        learning_curve_figure(groups, args.env, output)
    except LoadMonitorResultsError as error:
        fail(parser, f"{error} (a run folder holds them)")
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
    headless()
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
    from sb3_trpo_plus.application.recipes import recipe
    from sb3_trpo_plus.rollouts.engines import has_batch_engine

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
    from sb3_trpo_plus.application.evaluation import evaluate_agent

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
        "TRPOPlus (TRPO with generalized sample reuse) on rl-zoo3.",
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
