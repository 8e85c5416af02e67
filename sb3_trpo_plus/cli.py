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
from collections.abc import Sequence
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


def _name_tensorboard_runs() -> None:
    """TensorBoard runs under ``<tensorboard-log>/<env>/seed<seed>/<Algorithm>_<n>``: env, seed and algorithm."""
    from rl_zoo3.exp_manager import ExperimentManager

    if getattr(ExperimentManager.learn, "_named", False):
        return
    original = ExperimentManager.learn

    @functools.wraps(original)
    def learn(self: Any, model: Any) -> None:
        if model.tensorboard_log:  # a plain string attribute: the model stays picklable for checkpoints
            model.tensorboard_log = os.path.join(model.tensorboard_log, f"seed{self.seed}")
        original(self, model)

    learn._named = True  # type: ignore[attr-defined]
    ExperimentManager.learn = learn  # type: ignore[method-assign]


def train(argv: Sequence[str]) -> None:
    """``trpo-plus train --env ID [--algo trpo_plus|trpo|ppo] [rl_zoo3 train flags]``."""
    parser = argparse.ArgumentParser(prog="trpo-plus train", add_help=False)
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("--env", required=True)
    known, rest = parser.parse_known_args(argv)
    if "-h" in rest or "--help" in rest:
        parser.print_help()
    from rl_zoo3.train import train as zoo_train

    import grasp_envs  # noqa: F401

    _name_tensorboard_runs()
    sys.argv = ["trpo-plus train", *_zoo_argv(known.algo, known.env, rest)]
    zoo_train()


def enjoy(argv: Sequence[str]) -> None:
    """``trpo-plus enjoy --env ID [--algo ...] [rl_zoo3 enjoy flags]`` (headless without a display)."""
    _headless()
    parser = argparse.ArgumentParser(prog="trpo-plus enjoy", add_help=False)
    parser.add_argument("--algo", default="trpo_plus", choices=ALGO_CHOICES)
    parser.add_argument("--env", required=True)
    known, rest = parser.parse_known_args(argv)
    from rl_zoo3.enjoy import enjoy as zoo_enjoy

    from sb3_trpo_plus.zoo import register_in_rl_zoo

    register_in_rl_zoo()
    packages = [] if "--gym-packages" in rest else ["--gym-packages", "grasp_envs"]
    if os.environ.get("MUJOCO_GL") == "egl" and not os.environ.get("DISPLAY") and "--no-render" not in rest:
        print("trpo-plus enjoy: no display, running with --no-render (trpo-plus record-video films the agent)")
        rest = [*rest, "--no-render"]
    if "-f" not in rest and "--folder" not in rest:
        folder = _default_folder(known.algo, known.env)
        print(f"trpo-plus enjoy: loading from {folder}")
        rest = [*rest, "-f", folder]
    sys.argv = ["trpo-plus enjoy", "--algo", known.algo, "--env", known.env, *packages, *rest]
    zoo_enjoy()


def _load_trained(algo: str, env_id: str, folder: str, exp_id: int, load_best: bool, seed: int, render: bool) -> tuple:
    """Model and test env of an rl-zoo3 run (VecNormalize statistics and env kwargs restored)."""
    import yaml
    from huggingface_sb3 import EnvironmentName
    from rl_zoo3.utils import ALGOS, create_test_env, get_model_path, get_saved_hyperparams

    from sb3_trpo_plus.zoo import register_in_rl_zoo

    register_in_rl_zoo()
    env_name = EnvironmentName(env_id)
    _, model_path, log_path = get_model_path(exp_id, folder, algo, env_name, load_best)
    hyperparams, stats_path = get_saved_hyperparams(os.path.join(log_path, env_name), test_mode=True)
    # as rl-zoo3's enjoy: the config's env_kwargs, replaced by those of the command line that trained it (args.yml)
    env_kwargs: dict[str, Any] = dict(hyperparams.pop("env_kwargs", None) or {})
    args_path = Path(log_path) / env_name / "args.yml"
    if args_path.is_file():
        trained_with = yaml.load(args_path.read_text(), Loader=yaml.UnsafeLoader).get("env_kwargs")
        if trained_with is not None:
            env_kwargs = dict(trained_with)
    if render:
        env_kwargs["render_mode"] = "rgb_array"
    env = create_test_env(
        env_id, n_envs=1, stats_path=stats_path, seed=seed, should_render=False, hyperparams=hyperparams, env_kwargs=env_kwargs
    )
    model = ALGOS[algo].load(model_path, env=env, custom_objects={"learning_rate": 0.0, "lr_schedule": lambda _: 0.0})
    return model, env, log_path


def record_video(argv: Sequence[str]) -> list[Path]:
    """``trpo-plus record-video --env ID [--algo] [-f logs] [--exp-id 0] [-n steps] [-o out.mp4] [--gif]``."""
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
    args = parser.parse_args(argv)
    args.folder = args.folder or _default_folder(args.algo, args.env)
    model, env, log_path = _load_trained(args.algo, args.env, args.folder, args.exp_id, args.load_best, args.seed, True)
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


def evaluate(model: Any, env: Any, n_episodes: int) -> dict[str, Any]:
    """Deterministic evaluation: mean / std return (original rewards) and success rate over ``n_episodes``."""
    returns: list[float] = []
    successes: list[float] = []
    obs = env.reset()
    episode_return = 0.0
    while len(returns) < n_episodes:
        action, _ = model.predict(obs, deterministic=True)
        obs, _, done, info = env.step(action)
        episode_return += float(info[0].get("episode", {}).get("r", 0.0)) if done[0] else 0.0
        if done[0]:
            returns.append(episode_return)
            successes.append(float(info[0].get("is_success", False)))
            episode_return = 0.0
    return {
        "episodes": n_episodes,
        "mean_reward": float(np.mean(returns)),
        "std_reward": float(np.std(returns)),
        "success_rate": float(np.mean(successes)),
    }


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
    summary.update(evaluate(model, env, args.eval_episodes))
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
