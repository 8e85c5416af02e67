"""Soak: a long TRPOPlus run that saves, reloads and resumes every few minutes, against an uninterrupted one.

The run trains in cycles of ``--cycle-steps``; after each it saves the model (replay memory and random generators
included) and the VecNormalize statistics atomically, drops the model, loads both back and resumes, and it
evaluates the policy in a fresh ``SubprocVecEnv`` that it closes again. Beside it, a second process trains the
same seed for the same total in one ``learn`` call. The run checks:

(a) the final parameters equal the uninterrupted run's (same seed, CPU);
(b) the resident memory after warm-up (the first ``--warmup`` cycles) grows by at most ``--max-rss-growth``;
(c) no file descriptor and no process leaks: after every cycle the counts of open file descriptors and of processes
    below this one (the training env's workers; the evaluation env's are gone) equal those after the first.

    python -m benchmarks.soak --cycles 20 --cycle-steps 102400 --out benchmarks/results/soak.json

Observations are normalised, rewards are not: SB3's VecNormalize does not save the running discounted return
that reward normalisation divides by, so a resumed run would restart it at zero.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

ENV_ID = "Reacher2D-v1"
N_ENVS, N_STEPS = 4, 256
SETTINGS: dict[str, Any] = {
    "n_steps": N_STEPS,
    "batch_size": 256,
    "gamma": 0.98,
    "replay_memory": 3,
    "cg_warm_start": True,
    "policy_kwargs": {"net_arch": [64, 64]},
}


def make_env(seed: int) -> Any:
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecNormalize

    import grasp_envs  # noqa: F401

    env = make_vec_env(ENV_ID, n_envs=N_ENVS, seed=seed, vec_env_cls=SubprocVecEnv)
    return VecNormalize(env, norm_obs=True, norm_reward=False)


def make_model(env: Any, seed: int) -> Any:
    from sb3_trpo_plus import TRPOPlus

    return TRPOPlus("MlpPolicy", env, seed=seed, device="cpu", **SETTINGS)


def parameters(model: Any) -> dict[str, np.ndarray]:
    return {name: value.detach().cpu().numpy().copy() for name, value in model.policy.state_dict().items()}


def rss_mib() -> float:
    """Resident set size of this process now (MiB), from /proc."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


def descendant_processes(exclude: int | None = None) -> int:
    """Live (not zombie) processes below this one, the subtree of ``exclude`` left out. SubprocVecEnv's workers are
    children of multiprocessing's forkserver (SB3's default start method), itself a child of this process."""
    parents: dict[str, list[str]] = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            with open(f"/proc/{pid}/stat") as stat:
                fields = stat.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            parents.setdefault(fields[1], []).append(pid)
    count, stack = 0, [str(os.getpid())]
    while stack:
        for child in parents.get(stack.pop(), []):
            if child != str(exclude):
                count += 1
                stack.append(child)
    return count


def evaluate_in_fresh_env(model: Any, vec_normalize: Any, seed: int) -> float:
    """Mean return of 4 deterministic episodes in a new SubprocVecEnv, closed afterwards (its workers must go)."""
    from stable_baselines3.common.evaluation import evaluate_policy
    from stable_baselines3.common.vec_env import VecNormalize

    env = make_env(seed)
    try:
        env.obs_rms = vec_normalize.obs_rms
        assert isinstance(env, VecNormalize)
        env.training = False
        mean, _ = evaluate_policy(model, env, n_eval_episodes=4, deterministic=True)
    finally:
        env.close()
    return float(mean)  # type: ignore[arg-type]


def reference(total: int, seed: int, out: Path) -> None:
    """The uninterrupted run: one learn call of ``total`` steps; its parameters go to ``out`` (npz)."""
    import torch as th

    th.set_num_threads(1)
    env = make_env(seed)
    model = make_model(env, seed)
    model.learn(total)
    np.savez(out, **parameters(model))  # type: ignore[arg-type]
    env.close()


def soak(args: argparse.Namespace) -> dict[str, Any]:
    import torch as th
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus import TRPOPlus
    from sb3_trpo_plus.application.callbacks import save_vec_normalize

    th.set_num_threads(1)
    total = args.cycles * args.cycle_steps
    work = Path(tempfile.mkdtemp(prefix="soak-"))
    ref_out = work / "reference.npz"
    ref = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "benchmarks.soak",
            "--reference",
            str(total),
            "--seed",
            str(args.seed),
            "--ref-out",
            str(ref_out),
        ]
    )
    start = time.perf_counter()
    env = make_env(args.seed)
    model = make_model(env, args.seed)
    cycles: list[dict[str, Any]] = []
    for cycle in range(args.cycles):
        model.learn(args.cycle_steps, reset_num_timesteps=cycle == 0)
        model.save(work / "model.zip")
        save_vec_normalize(env, work / "vecnormalize.pkl")
        del model
        env = VecNormalize.load(str(work / "vecnormalize.pkl"), env.venv)
        model = TRPOPlus.load(work / "model.zip", env=env, device="cpu", force_reset=False)
        mean_return = evaluate_in_fresh_env(model, env, seed=10_000 + cycle)
        row = {
            "cycle": cycle + 1,
            "timesteps": int(model.num_timesteps),
            "minutes": round((time.perf_counter() - start) / 60, 2),
            "rss_mib": round(rss_mib(), 1),
            "open_fds": open_fds(),
            "processes": descendant_processes(exclude=ref.pid),
            "eval_return": round(mean_return, 3),
            "replay_memory": len(model.rollout_memory or ()),
        }
        cycles.append(row)
        print(json.dumps(row), flush=True)
    soak_minutes = (time.perf_counter() - start) / 60
    if ref.wait() != 0:
        raise RuntimeError(f"the uninterrupted run failed with exit status {ref.returncode}")
    expected = dict(np.load(ref_out))
    final = parameters(model)
    max_difference = max(float(np.abs(final[name] - expected[name]).max()) for name in expected)
    env.close()
    warm = cycles[args.warmup - 1]
    peak_rss = max(row["rss_mib"] for row in cycles[args.warmup - 1 :])
    growth = peak_rss / warm["rss_mib"] - 1.0
    checks = {
        "parameters_equal": max_difference == 0.0,
        "rss_growth_ok": growth <= args.max_rss_growth,
        "no_fd_leak": all(row["open_fds"] == cycles[0]["open_fds"] for row in cycles),
        "no_process_leak": all(row["processes"] == cycles[0]["processes"] for row in cycles),
    }
    return {
        "command": " ".join(["python -m benchmarks.soak", *sys.argv[1:]]),
        "env": ENV_ID,
        "n_envs": N_ENVS,
        "settings": SETTINGS,
        "seed": args.seed,
        "cycles": cycles,
        "soak_minutes": round(soak_minutes, 1),
        "total_timesteps": total,
        "max_parameter_difference": max_difference,
        "rss_growth_after_warmup": round(growth, 4),
        "peak_rss_mib_after_warmup": peak_rss,
        "max_rss_mib_ru": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "checks": checks,
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        "versions": _versions(),
    }


def _versions() -> dict[str, str]:
    from importlib.metadata import version

    return {name: version(name) for name in ("torch", "stable-baselines3", "sb3-contrib", "gymnasium", "mujoco")}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.soak", description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=20, help="save / reload / resume cycles")
    parser.add_argument("--cycle-steps", type=int, default=N_ENVS * N_STEPS * 100, help="env steps per cycle")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--warmup", type=int, default=2, help="cycles before the memory baseline")
    parser.add_argument("--max-rss-growth", type=float, default=0.05)
    parser.add_argument("--out", type=Path, default=None, help="JSON report")
    parser.add_argument("--reference", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--ref-out", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.reference is not None:
        reference(args.reference, args.seed, args.ref_out)
        return
    if args.cycle_steps % (N_ENVS * N_STEPS):
        parser.error(f"--cycle-steps must be a multiple of {N_ENVS * N_STEPS} (one rollout)")
    if not 1 <= args.warmup <= args.cycles:
        parser.error("--warmup must be between 1 and --cycles")
    report = soak(args)
    print(json.dumps({k: v for k, v in report.items() if k != "cycles"}, indent=1))
    if args.out is not None:
        args.out.write_text(json.dumps(report, indent=1) + "\n")
    if not all(report["checks"].values()):
        raise SystemExit(f"soak failed: {report['checks']}")


if __name__ == "__main__":
    main()
