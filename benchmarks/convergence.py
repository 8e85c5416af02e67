"""Does replay memory / warm-started CG speed up learning? The thesis' experiments (section 5.3), resumable.

    python benchmarks/convergence.py run --envs Reacher2D-v0 --seeds 0 1 2 3 4 [--variants ...] [--jobs 2]
    python benchmarks/convergence.py report          # figures, tables, rliable -> docs/results.md
    python benchmarks/convergence.py agents          # best TRPOPlus run per env -> trained_agents/

Variants: TRPOPlus plain (k = 0, zero CG start), + replay (k = 3), + warm start, + both, sb3-contrib TRPO
and SB3 PPO, each with the zoo hyperparameters of its algorithm (zoo_hyperparams/*.yml) and the
variant's two switches on top. Every (env, variant, seed) is one job in its own process, trained in
chunks of budget / 25 steps; after each chunk the job evaluates the deterministic policy on 20 held-out
episodes (reset seed 10,000, the same episodes at every point and in every run), saves the model and the
VecNormalize statistics atomically and appends a row to
benchmarks/results/convergence/<env>/<variant>/seed<k>/progress.csv. A rerun continues every unfinished
job from its last row, so the study can be stopped at any time (a resumed job's env seeds differ from an
uninterrupted run's; the CSV says where it resumed).

Checkpoints (model.zip, vecnormalize.pkl) are git-ignored, so a fresh clone holds a run's CSV without them, and
`run` starts such a run again from zero (its CSV removed). A session that stops in the middle of a long run keeps it
resumable across machines by committing that run's two checkpoint files with ``git add -f``.

A job overwrites its checkpoint at every chunk. ``--keep-checkpoints DIR`` also keeps each chunk's:
DIR/<timesteps>/<env>/<variant>/seed<k>/ holds model.zip, vecnormalize.pkl and progress.csv up to that row, so
DIR/<timesteps> is the study's folder as it stood then (``--out`` of ``report``, ``--runs`` of grasper_probe.py).

    python benchmarks/convergence.py reevaluate --kept DIR --envs Grasper3D-v6 --variants ... --seeds 3 4 \
        --after 2000000 --episodes 100 --reset-seed 20000

evaluates every kept checkpoint past ``--after`` (and each run's own last one) again, the study's way (deterministic
policy, VecNormalize statistics of the checkpoint, the env seeded once) on more episodes from another reset seed,
into <out>/<env>/<variant>/seed<k>/reevaluation.csv; a checkpoint already evaluated so is not evaluated again.
``reevaluate --confirm --after 2000000`` runs the Grasper's declared reading (docs/benchmarks.md) end to end: every
checkpoint on 100 episodes from reset seed 20,000, then each one below the target on 200 more from each of 30,000 and
40,000 (the 500 pooled decide), and prints each run's verdict.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "convergence"
BUDGETS = {
    "Reacher2D-v0": 300_000,
    "Reacher2D-v1": 300_000,
    "Reacher3D-v0": 1_000_000,
    "Reacher3D-v1": 1_000_000,
    "WallReacher3D-v0": 2_000_000,
    "Grasper3D-v0": 5_000_000,
    "Grasper3D-v1": 5_000_000,
    "Grasper3D-v2": 5_000_000,
    "Grasper3D-v3": 5_000_000,
    "Grasper3D-v4": 5_000_000,
    "Grasper3D-v5": 5_000_000,
    "Grasper3D-v6": 5_000_000,
}
TARGETS = {
    "Reacher2D-v0": 0.9,
    "Reacher2D-v1": 0.9,
    "Reacher3D-v0": 0.9,
    "Reacher3D-v1": 0.9,
    "WallReacher3D-v0": 0.8,
    "Grasper3D-v0": 0.9,
    "Grasper3D-v1": 0.9,
    "Grasper3D-v2": 0.9,
    "Grasper3D-v3": 0.9,
    "Grasper3D-v4": 0.9,
    "Grasper3D-v5": 0.9,
    "Grasper3D-v6": 0.9,
}
# the targets: each reached within these steps (the budget, but the Grasper's: 2M of 5M), and on the Grasper
# held to the end: every evaluation after TARGET_WITHIN at or above the target, for every seed
TARGET_WITHIN = {env_id: 2_000_000 if env_id.startswith("Grasper") else budget for env_id, budget in BUDGETS.items()}
TARGET_HELD = {env_id for env_id in BUDGETS if env_id.startswith("Grasper")}


@dataclass(frozen=True)
class HoldThenShrink:
    """A ``target_kl`` schedule: ``start`` until ``hold`` of the run is done, then linear to ``end`` at its end."""

    start: float
    end: float
    hold: float

    def __call__(self, progress_remaining: float) -> float:
        done = 1.0 - progress_remaining
        if done <= self.hold:
            return self.start
        return self.start + (self.end - self.start) * (done - self.hold) / (1.0 - self.hold)


# the thesis' two switches; the variants below change one setting on top of one of these
PLAIN: dict[str, Any] = {"replay_memory": 0, "cg_warm_start": False}
REPLAY: dict[str, Any] = {"replay_memory": 3, "cg_warm_start": False}
WARM: dict[str, Any] = {"replay_memory": 0, "cg_warm_start": True}
BOTH: dict[str, Any] = {"replay_memory": 3, "cg_warm_start": True}
SCRIPTED, SCRIPTED25 = "scripted25", {"scripted_start_prob": 0.25}  # a quarter of the training resets along the scripted grasp
SCRIPTED25_LATE = {**SCRIPTED25, "scripted_start_steps": (50, 100)}  # ... each 50-99 steps along it
HOLD_HEIGHT = 0.07  # m: where the scripted grasp of the <...>_hold variants holds the cube (its bottom)
# Discounts the YAML had before it took gamma 0.98: Reacher2D-v1 ran with v0's 0.99 until session 11, WallReacher3D-v0
# with the thesis' 0.995 until session 12. The rows recorded before keep their discount through the variants
# <study variant>_<suffix> and the Reacher2D-v1-only variants that set G099 (docs/results.md)
FORMER_DISCOUNTS: dict[str, float] = {"g099": 0.99, "g0995": 0.995}
G099: dict[str, Any] = {"gamma": FORMER_DISCOUNTS["g099"]}
STUDY: dict[str, tuple[str, dict[str, Any]]] = {
    "plain": ("trpo_plus", PLAIN),
    "replay": ("trpo_plus", REPLAY),
    "warm": ("trpo_plus", WARM),
    "both": ("trpo_plus", BOTH),
    "trpo": ("trpo", {}),
    "ppo": ("ppo", {}),
}
VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    **STUDY,
    # the six above with a former discount (*_g099: Reacher2D-v1 before session 11, *_g0995: WallReacher3D-v0 before 12)
    **{
        f"{name}_{suffix}": (algo, {**overrides, "gamma": gamma})
        for suffix, gamma in FORMER_DISCOUNTS.items()
        for name, (algo, overrides) in STUDY.items()
    },
    # sb3-contrib TRPO with its CG started at 0 like TRPOPlus (benchmarks/trpo_divergence.py): same algorithm
    "trpo_cg0": ("trpo", G099),
    # why does the combination hurt? (docs/results.md): CG run closer to convergence, or cut shorter
    "replay_cg25": ("trpo_plus", {**REPLAY, **G099, "cg_max_steps": 25}),
    "both_cg5": ("trpo_plus", {**BOTH, **G099, "cg_max_steps": 5}),
    # tuning the best variant on Reacher2D-v1 (docs/results.md): a larger trust region, or twice the updates
    "warm_kl02": ("trpo_plus", {**WARM, **G099, "target_kl": 0.02}),
    "warm_n128": ("trpo_plus", {**WARM, **G099, "n_steps": 128, "batch_size": 128}),
    # session 10, towards 90 % within 300k on Reacher2D-v1 (docs/results.md): one setting at a time around the
    # zoo's, after 24 trials of `trpo-plus train -optimize` over rl-zoo3's TRPO space all ended below it; gamma 0.98
    # won and went into the YAML (its Reacher2D-v1 runs, and PPO's with the same discount, are now warm and ppo)
    "warm_std06": ("trpo_plus", {**WARM, **G099, "policy_kwargs": {"log_std_init": -0.5}}),
    "warm_std037": ("trpo_plus", {**WARM, **G099, "policy_kwargs": {"log_std_init": -1.0}}),
    "warm_lam098": ("trpo_plus", {**WARM, **G099, "gae_lambda": 0.98}),
    "warm_lam090": ("trpo_plus", {**WARM, **G099, "gae_lambda": 0.9}),
    "warm_vf20": ("trpo_plus", {**WARM, **G099, "n_critic_updates": 20}),
    # Grasper3D-v3/-v4: the six above with a quarter of the training episodes starting along the scripted grasp
    # (Popov et al. 2017; TRAIN_ENV_KWARGS); run so far: warm (v3, v4), plain and PPO (v4)
    **{f"{name}_{SCRIPTED}": (algo, overrides) for name, (algo, overrides) in STUDY.items()},
    # Grasper3D-v4: half of the training episodes
    "warm_scripted50": ("trpo_plus", WARM),
    # PPO with scripted starts learned the lift faster than TRPOPlus: a trust region three times as large
    "warm_scripted25_kl03": ("trpo_plus", {**WARM, "target_kl": 0.03}),
    # ... twice the updates (5,000 samples each), or a smaller initial action std (0.61, log_std_init -0.5)
    "warm_scripted25_n500": ("trpo_plus", {**WARM, "n_steps": 500}),
    "warm_scripted25_std06": (
        "trpo_plus",
        {**WARM, "policy_kwargs": {"log_std_init": -0.5}},
    ),
    # ... the critic's Adam step size of PPO (3e-4; TRPO's default is 1e-3), the same 10 epochs of minibatches
    "warm_scripted25_vf3e4": ("trpo_plus", {**WARM, "learning_rate": 3e-4}),
    # ... and PPO with one epoch over each batch instead of ten (20 Adam steps per batch instead of 200)
    "ppo_scripted25_e1": ("ppo", {"n_epochs": 1}),
    # Grasper3D-v4 with the shorter horizon that met the WallReacher3D and Reacher2D-v1 targets (session 13)
    "warm_scripted25_g098": ("trpo_plus", {**WARM, "gamma": 0.98}),
    "plain_scripted25_g098": ("trpo_plus", {**PLAIN, "gamma": 0.98}),
    # Grasper3D-v4, session 14: CG's relative residual after its 10 iterations grows to 0.2-0.5 at 2M (0.7-1.1 at 5M)
    # as the policy's std shrinks (a truer natural gradient?), and twice the updates per sample with plain TRPOPlus
    "plain_scripted25_cg25": ("trpo_plus", {**PLAIN, "cg_max_steps": 25}),
    "plain_scripted25_n500": ("trpo_plus", {**PLAIN, "n_steps": 500}),
    # Grasper3D-v4, session 15: three natural-gradient steps per batch inside the one trust region, like PPO's many
    # small steps (benchmarks/multistep.py; the class is MULTI_STEP's, the settings trpo_plus.yml's)
    "plain_scripted25_ms3": ("trpo_plus", {**PLAIN, "n_policy_steps": 3}),
    # ... which moved the policy twice as far per update (KL 0.009 against 0.0045) and learned slower, as target_kl
    # 0.03 did; PPO's updates are the smallest (0.002 per action dimension): half the trust region
    "plain_scripted25_kl005": ("trpo_plus", {**PLAIN, "target_kl": 0.005}),
    # Grasper3D-v5, session 17: v5 grasps almost every cube and then fails to lift (docs/benchmarks.md); the six
    # study variants (STUDY) with the same quarter of scripted starts, each 50-99 steps along the scripted grasp
    # (62 % start grasped instead of 26 %); run so far: plain (session 17), PPO and sb3-contrib TRPO (session 19)
    **{f"{name}_{SCRIPTED}_late": (algo, overrides) for name, (algo, overrides) in STUDY.items()},
    # Grasper3D-v5, session 18: the late starts with the smaller initial action std (0.61) that brought the first
    # lifts earlier on v4 (warm_scripted25_std06): the two settings that each helped, together
    "plain_scripted25_late_std06": ("trpo_plus", {**PLAIN, "policy_kwargs": {"log_std_init": -0.5}}),
    # Grasper3D-v5, session 19 (a 16-core machine lent for half an hour, 16 runs at once): is the algorithm the limit
    # (ppo_ and trpo_scripted25_late above), the policy's size (two layers of 256 instead of the thesis' 100), or the
    # share of late starts (half of the training resets instead of a quarter)?
    "plain_scripted25_late_net256": ("trpo_plus", {**PLAIN, "policy_kwargs": {"net_arch": [256, 256]}}),
    "plain_scripted50_late": ("trpo_plus", PLAIN),
    # Grasper3D-v5, session 20: the late starts copy the scripted grasp, which kept raising the cube until the arm ran
    # out of reach and lost 13 of 40 held-out cubes after lifting them; here it holds the cube 7 cm up (3 lost)
    **{f"{name}_{SCRIPTED}_late_hold": (algo, overrides) for name, (algo, overrides) in STUDY.items()},
    # Grasper3D-v6, session 22: its first form let the cube turn about every axis (a ball joint), and the claw tumbled
    # it on the floor; the registered v6 turns it about the vertical only
    "plain_scripted25_late_freecube": ("trpo_plus", {**PLAIN, "env_kwargs": {"cube_rotation": "free"}}),
    # Grasper3D-v6, session 24: a grip twice as fast (max_grip_speed 0.8 m/s; 0.4 moves it 8 mm per step), so that the
    # cubes behind the shoulder, farthest from the arm's start, are reached sooner; and so with half the initial std
    # (0.5, log_std_init -0.69), the same exploration noise in m/s as at 0.4. Both learned slower: not a new version
    "warm_scripted25_late_speed08": ("trpo_plus", {**WARM, "env_kwargs": {"max_grip_speed": 0.8}}),
    "warm_scripted25_late_speed08_std05": (
        "trpo_plus",
        {**WARM, "env_kwargs": {"max_grip_speed": 0.8}, "policy_kwargs": {"log_std_init": -0.69}},
    ),
    # Grasper3D-v6, session 25: the arm starts in a ready pose above the cubes (start_pose "ready": forearm down, the grip
    # 8.7 cm out along +x) instead of stretched along +x, 0.3 m from a cube behind the shoulder; the scripted grasp from
    # there touches every cube of 300 held-out resets, first at step 42 (median; stretched: 67, and 11 never), and
    # lifts 0.95 of them by step 100 (stretched: 0.88)
    "warm_scripted25_late_ready": ("trpo_plus", {**WARM, "env_kwargs": {"start_pose": "ready"}}),
    # Grasper3D-v6, session 25: the policies' evaluations keep swinging between 0.7 and 1.0 after 2M, each update moving
    # the policy by about the same KL (0.005-0.008); a trust region that shrinks from 0.01 after 2M to 0.001 at 5M is
    # meant to let it settle, as rl-zoo's PPO settings often anneal the learning rate (TRPOPlus' target_kl takes a
    # schedule too); over ten paired seeds on the ready pose it was a small gain at most (docs/benchmarks.md)
    "warm_scripted25_late_klshrink": ("trpo_plus", {**WARM, "target_kl": HoldThenShrink(0.01, 0.001, 0.4)}),
    # ... with the ready pose; its runs branch at 2M from warm_scripted25_late_ready's checkpoints (copied)
    "warm_scripted25_late_ready_klshrink": (
        "trpo_plus",
        {**WARM, "env_kwargs": {"start_pose": "ready"}, "target_kl": HoldThenShrink(0.01, 0.001, 0.4)},
    ),
    # Grasper3D-v6, session 27: after 2M, a batch of less noise instead of a smaller step. The thesis' Grasper runs
    # took 300 trajectories per update (30,000 samples; the YAML takes its reachers' 100), and its replay memory
    # (k = 3) reuses the last three batches, importance-weighted. Runs branch at 2M from warm_scripted25_late_ready's
    # checkpoints (copied); run from scratch, a variant takes its setting from the first update. Over ten seeds the larger
    # batch kept nine runs >= 90 % at every evaluation from 3.9M; replay did not help (five seeds; docs/benchmarks.md)
    "warm_scripted25_late_ready_n3000": ("trpo_plus", {**WARM, "env_kwargs": {"start_pose": "ready"}, "n_steps": 3000}),
    "warm_scripted25_late_ready_replay3": (
        "trpo_plus",
        {**WARM, "env_kwargs": {"start_pose": "ready"}, "replay_memory": 3},
    ),
    # Grasper3D-v6, session 28: three of ten ready-pose seeds are below 0.90 at 2M, the first lift found late. On v4,
    # 25 CG iterations instead of 10 gave every seed its first lift within 0.64-0.72M (10: 0.6-1.4M); CG's relative
    # residual after 10 iterations is 0.24-0.83 at 2M and 0.61-1.30 at 5M here: the step is far from the natural gradient.
    # With 25: 8 of 10 seeds reach 0.90 within 2M (10: 7), the slow ones others; 2 of 10 to 5M meet both halves
    "warm_scripted25_late_ready_cg25": (
        "trpo_plus",
        {**WARM, "env_kwargs": {"start_pose": "ready"}, "cg_max_steps": 25},
    ),
    # Grasper3D-v6, session 29: the two best second-half settings together: 25 CG iterations, and from 2M 30,000 samples
    # per update; its runs branch at 2M from warm_scripted25_late_ready_cg25's checkpoints (copied). Ten seeds (6-9 in
    # session 29, 0-5 in 30): >= 0.90 in 125 of the 150 evaluations after 2M, as either alone; 3 of 10 meet both halves
    "warm_scripted25_late_ready_cg25_n3000": (
        "trpo_plus",
        {**WARM, "env_kwargs": {"start_pose": "ready"}, "cg_max_steps": 25, "n_steps": 3000},
    ),
    # Grasper3D-v6, session 31: the first half's slow seeds find their first lifts late. Reacher2D-v1 and WallReacher3D-v0
    # met their targets only with a shorter horizon (gamma 0.98 instead of 0.99 / the thesis' 0.995); the Grasper keeps
    # the thesis' 0.995 over 100-step episodes whose ends are bootstrapped from a critic without a clock. Ten seeds to 2M
    "warm_scripted25_late_ready_cg25_g098": (
        "trpo_plus",
        {**WARM, "env_kwargs": {"start_pose": "ready"}, "cg_max_steps": 25, "gamma": 0.98},
    ),
    # Grasper3D-v4: exploration that persists over an episode: gSDE (Raffin et al. 2022), a new noise matrix
    # every 100 steps (one episode), initial action std ~0.8 (log_std_init -2; white noise starts at 1)
    "warm_sde": (
        "trpo_plus",
        {
            **WARM,
            "use_sde": True,
            "sde_sample_freq": 100,
            "policy_kwargs": {"log_std_init": -2.0},
        },
    ),
}
# variants that change the training envs only (the evaluation envs keep the YAML's env_kwargs): every variant
# named <...>_scripted25<...> starts a quarter of its training episodes along the scripted grasp (those named
# <...>_scripted25_late<...> 50-99 steps along it, and those named <...>_hold with a scripted grasp that holds the
# cube HOLD_HEIGHT up)
TRAIN_ENV_KWARGS: dict[str, dict[str, Any]] = {
    **{name: SCRIPTED25 for name in VARIANTS if f"_{SCRIPTED}" in name},
    "warm_scripted50": {"scripted_start_prob": 0.5},
    **{name: SCRIPTED25_LATE for name in VARIANTS if "_scripted25_late" in name},
    "plain_scripted50_late": {**SCRIPTED25_LATE, "scripted_start_prob": 0.5},
    **{name: {**SCRIPTED25_LATE, "scripted_start_hold_height": HOLD_HEIGHT} for name in VARIANTS if name.endswith("_hold")},
}
# the settings a variant may change on a checkpoint it resumes (branches from): the trust region, the batch, the memory
BRANCH_SETTINGS = ("target_kl", "n_steps", "replay_memory")
MULTI_STEP = {"plain_scripted25_ms3"}  # variants trained by multistep.MultiStepTRPOPlus
ZERO_CG_START = {"trpo_cg0"}  # variants whose sb3-contrib TRPO starts its conjugate gradient at 0
STUDY_VARIANTS = list(STUDY)  # the default set of `run`
CHUNKS = 25
EVAL_EPISODES = 20
EVAL_SEED = 10_000
# Per-update diagnostics read from the logger after each policy update (mean over the chunk's updates).
DIAGNOSTICS = {
    "kl": "train/kl_divergence_loss",
    "line_search_success": "train/is_line_search_success",
    "line_search_steps": "train/line_search_steps",
    "cg_residual": "train/cg_residual",
    "cg_relative_residual": "train/cg_relative_residual",
    "step_gradient_cosine": "train/step_gradient_cosine",
    "warm_start_cosine": "train/cg_warm_start_cosine",
    "replay_ess": "train/replay_ess",
    "std": "train/std",
}
COLUMNS = [
    "timesteps", "train_seconds", "eval_success", "eval_return", "train_success", "train_return", "train_episodes",
    *DIAGNOSTICS, "kl_overshoot", "resumed",
]  # fmt: skip


# ---------------------------------------------------------------------------------------------- one job
def add_run_arguments(parser: argparse.ArgumentParser, env_id: str, variant: str) -> None:
    """``--env``, ``--variant`` and ``--seed``: the study run a diagnostic script looks at."""
    parser.add_argument("--env", default=env_id)
    parser.add_argument("--variant", default=variant, choices=list(VARIANTS))
    parser.add_argument("--seed", type=int, default=0)


def job_folder(out: Path, env_id: str, variant: str, seed: int) -> Path:
    return out / env_id / variant / f"seed{seed}"


def read_progress(folder: Path, name: str = "progress.csv") -> list[dict[str, float]]:
    """The rows of a run's CSV (``progress.csv``, or ``reevaluation.csv``) as floats; a blank cell is NaN."""
    path = folder / name
    if not path.exists():
        return []
    with path.open() as file:
        return [
            {key: float(value) if value != "" else float("nan") for key, value in row.items()} for row in csv.DictReader(file)
        ]


def _hyperparameters(algo: str, env_id: str, overrides: dict[str, Any]) -> dict[str, Any]:
    from sb3_trpo_plus.zoo import load_hyperparameters

    params = dict(load_hyperparameters(ROOT / "zoo_hyperparams" / f"{algo}.yml", algo, [env_id])[env_id])
    for key, value in overrides.items():  # a variant's policy_kwargs add to the YAML's (net_arch, activation)
        params[key] = {**params.get(key, {}), **value} if key == "policy_kwargs" else value
    return params


def model_settings(algo: str, env_id: str, overrides: dict[str, Any]) -> tuple[dict[str, Any], int, bool, str, Any]:
    """(constructor kwargs, n_envs, normalize, policy, env_kwargs) from the zoo settings of ``algo`` on ``env_id``."""
    params = _hyperparameters(algo, env_id, overrides)
    n_envs, normalize = int(params.pop("n_envs", 1)), bool(params.pop("normalize", False))
    policy = params.pop("policy")
    for key in ("n_timesteps", "callback", "monitor_kwargs", "normalize_kwargs", "env_wrapper", "vec_env_wrapper"):
        params.pop(key, None)
    env_kwargs = params.pop("env_kwargs", None)  # the YAML's env_kwargs, as rl-zoo3 applies them
    return params, n_envs, normalize, policy, env_kwargs


def training_env_kwargs(variant: str, env_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """The YAML's env kwargs with the variant's training-only changes on top (evaluation envs keep the YAML's)."""
    return {**(env_kwargs or {}), **TRAIN_ENV_KWARGS.get(variant, {})}


def evaluation_env_kwargs(env_id: str, variant: str) -> dict[str, Any]:
    """The kwargs of ``variant``'s evaluation envs on ``env_id``, as ``run_job`` makes them: the YAML's env_kwargs, or
    the variant's own where it sets them (its training envs add TRAIN_ENV_KWARGS on top)."""
    algo, overrides = VARIANTS[variant]
    return dict(model_settings(algo, env_id, overrides)[4] or {})


def evaluation_env(env_id: str, variant: str, seed: int, normalize: bool) -> Any:
    """One monitored evaluation env of ``variant`` seeded with ``seed``; with ``normalize``, a VecNormalize that neither
    updates its statistics nor scales rewards (its caller sets ``obs_rms``)."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    env = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=evaluation_env_kwargs(env_id, variant))
    return VecNormalize(env, training=False, norm_reward=False) if normalize else env


def training_envs(env_id: str, variant: str, seed: int) -> Any:
    """New unmonitored training envs of ``variant`` seeded with ``seed``, for the diagnostic scripts: the variant's
    training-env kwargs, VecNormalize where the YAML asks for it. ``run_job`` builds its own (it monitors episodes)."""
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    import grasp_envs  # noqa: F401

    algo, overrides = VARIANTS[variant]
    params, n_envs, normalize, _, env_kwargs = model_settings(algo, env_id, overrides)
    env = make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=training_env_kwargs(variant, env_kwargs))
    return VecNormalize(env, gamma=params.get("gamma", 0.99)) if normalize else env


def new_model(env_id: str, variant: str, seed: int, env: Any = None) -> Any:
    """A new model of ``variant`` (zoo settings plus its switches) on ``env``, or on ``training_envs``."""
    algo, overrides = VARIANTS[variant]
    params, _, _, policy, _ = model_settings(algo, env_id, overrides)
    env = training_envs(env_id, variant, seed) if env is None else env
    return algorithm_class(variant)(policy, env, seed=seed, device="cpu", **params)


def algorithm_class(variant: str) -> Any:
    """The class that trains ``variant``: its zoo algorithm's, or a probe's subclass of it."""
    if variant in MULTI_STEP:
        from multistep import MultiStepTRPOPlus  # benchmarks/ is on sys.path when this file runs as a script

        return MultiStepTRPOPlus
    from sb3_trpo_plus.zoo import algorithms

    return algorithms()[VARIANTS[variant][0]]


def _atomic_replace(write: Any, path: Path) -> None:
    temporary = path.with_name(f"{path.stem}.tmp{path.suffix}")  # SB3 keeps a name that ends in .zip
    write(temporary)
    os.replace(temporary, path)


def run_job(env_id: str, variant: str, seed: int, steps: int, out: Path, keep: Path | None = None) -> None:
    """Train one (env, variant, seed) to ``steps`` in chunks, resuming from the last saved chunk.

    With ``keep``, every chunk's checkpoint and CSV are also copied to ``keep/<timesteps>/<env>/<variant>/seed<k>``.
    """
    import torch as th
    from grasper_reward import EpisodeStats  # benchmarks/ is on sys.path when this file runs as a script
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.logger import Logger
    from stable_baselines3.common.vec_env import VecNormalize

    import grasp_envs  # noqa: F401

    th.set_num_threads(1)
    if variant in ZERO_CG_START:
        from trpo_divergence import use_zero_start_in_sb3_contrib_trpo

        use_zero_start_in_sb3_contrib_trpo()
    folder = job_folder(out, env_id, variant, seed)
    folder.mkdir(parents=True, exist_ok=True)
    rows = read_progress(folder)
    done = int(rows[-1]["timesteps"]) if rows else 0
    if done >= steps:
        return
    if rows and not (folder / "model.zip").exists():  # a committed CSV of an unfinished run, without its checkpoint
        print(f"{folder}: no checkpoint to resume from, starting again", flush=True)
        (folder / "progress.csv").unlink()
        rows, done = [], 0
    algo, overrides = VARIANTS[variant]
    params, n_envs, normalize, policy, env_kwargs = model_settings(algo, env_id, overrides)
    algo_class = algorithm_class(variant)
    monitor = {"info_keywords": ("is_success",)}
    train_env_kwargs = training_env_kwargs(variant, env_kwargs)
    venv = make_vec_env(
        env_id, n_envs=n_envs, seed=seed + 100_000 * len(rows), env_kwargs=train_env_kwargs, monitor_kwargs=monitor
    )
    model_path, stats_path = folder / "model.zip", folder / "vecnormalize.pkl"
    if rows:
        env = VecNormalize.load(str(stats_path), venv) if normalize else venv
        # a variant's own BRANCH_SETTINGS (a target_kl schedule, say) apply to a checkpoint it resumes, so that a run
        # can branch from another variant's checkpoint; every other setting is the checkpoint's
        branch = {key: overrides[key] for key in BRANCH_SETTINGS if key in overrides} or None
        model = algo_class.load(model_path, env=env, device="cpu", custom_objects=branch)
        model.__dict__.pop("train", None)  # checkpoints saved before 2026-11-22 03:50 pickled the wrapper below
    else:
        env = VecNormalize(venv, gamma=params.get("gamma", 0.99)) if normalize else venv
        model = algo_class(policy, env, seed=seed, device="cpu", verbose=0, **params)
    eval_env = evaluation_env(env_id, variant, EVAL_SEED, normalize)
    diagnostics: dict[str, list[float]] = {name: [] for name in DIAGNOSTICS}
    overshoots: list[float] = []  # each TRPO update's KL over its trust region's radius
    original_train = model.train

    def train_and_record() -> None:  # the update's logged values, read before SB3 dumps the logger
        original_train()
        values = model.logger.name_to_value
        for name, key in DIAGNOSTICS.items():
            if key in values:
                diagnostics[name].append(float(values[key]))
        # TRPOPlus logs each update's radius (target_kl may be a schedule); sb3-contrib's TRPO has a constant one
        radius = float(values.get("train/target_kl", getattr(model, "target_kl", None) or 0.0))
        if radius > 0 and "train/kl_divergence_loss" in values:
            overshoots.append(float(values["train/kl_divergence_loss"]) / radius)

    model.train = train_and_record  # type: ignore[method-assign]
    # the CSV is the study's log; SB3's default logger (verbose 0, no TensorBoard) would make an empty folder
    # <tempdir>/SB3-<date> at every chunk's learn(): 25-40 per run
    model.set_logger(Logger(folder=None, output_formats=[]))
    progress_over_budget(model, max(BUDGETS.get(env_id, steps), steps))

    chunk = max(steps // CHUNKS, 1)
    seconds = rows[-1]["train_seconds"] if rows else 0.0
    resumed = 1.0 if rows else 0.0
    while done < steps:
        recorder = EpisodeStats()
        start = time.perf_counter()
        model.learn(min(chunk, steps - done), callback=recorder, reset_num_timesteps=False)
        seconds += time.perf_counter() - start
        done = int(model.num_timesteps)
        if normalize:
            eval_env.obs_rms = env.obs_rms  # type: ignore[attr-defined]
        eval_return, eval_success = evaluate(model, eval_env, EVAL_EPISODES)
        returns = [r for r, _, _ in recorder.episodes]
        successes = [float(s) for _, s, _ in recorder.episodes]
        means = {name: float(np.mean(v)) if v else float("nan") for name, v in diagnostics.items()}
        overshoot = max(overshoots) if overshoots else float("nan")
        overshoots.clear()
        for values in diagnostics.values():
            values.clear()
        row = {
            "timesteps": done, "train_seconds": round(seconds, 2), "eval_success": eval_success,
            "eval_return": round(eval_return, 4), "train_success": float(np.mean(successes)) if successes else float("nan"),
            "train_return": round(float(np.mean(returns)), 4) if returns else float("nan"), "train_episodes": len(returns),
            **{k: round(v, 5) for k, v in means.items()},
            "kl_overshoot": round(overshoot, 4),
            "resumed": resumed,
        }  # fmt: skip
        resumed = 0.0
        # not the wrappers of train() and of the progress
        _atomic_replace(lambda p: model.save(p, exclude=["train", "_update_current_progress_remaining"]), model_path)
        if normalize:
            _atomic_replace(lambda p: env.save(str(p)), stats_path)  # type: ignore[attr-defined]
        _append_row(folder / "progress.csv", row)
        if keep is not None:
            keep_checkpoint(folder, job_folder(keep / str(done), env_id, variant, seed))
    env.close()
    eval_env.close()


def keep_checkpoint(folder: Path, destination: Path) -> None:
    """Copy a job folder's checkpoint files and CSV to ``destination``, which appears whole or not at all.

    A copy already there (a run started again from zero, into the same folder) is replaced, as SB3's
    CheckpointCallback overwrites its files.
    """
    temporary = destination.with_name(destination.name + ".tmp")
    shutil.rmtree(temporary, ignore_errors=True)  # a copy cut short by a stop
    temporary.mkdir(parents=True)
    for name in ("model.zip", "vecnormalize.pkl", "progress.csv"):
        if (folder / name).exists():
            shutil.copy2(folder / name, temporary / name)
    shutil.rmtree(destination, ignore_errors=True)
    os.replace(temporary, destination)


def progress_over_budget(model: Any, budget: int) -> None:
    """Make ``model``'s remaining progress (what SB3's schedules read) ``1 - timesteps / budget``.

    SB3 measures it against the ``total_timesteps`` of the running ``learn`` call; a job learns in chunks, and
    may stop at ``--steps`` and later resume to the budget, so a schedule would restart with every chunk. Against
    the env's study budget, it runs once over the whole run, however the run is cut.
    """

    def update(num_timesteps: int, total_timesteps: int) -> None:
        model._current_progress_remaining = 1.0 - float(num_timesteps) / float(budget)

    model._update_current_progress_remaining = update


def _append_row(path: Path, row: dict[str, Any]) -> None:
    """Append a row; a CSV written by an older version (fewer columns) is first rewritten with blanks."""
    cell = {key: ("" if isinstance(v, float) and not np.isfinite(v) else v) for key, v in row.items()}
    if path.exists():
        with path.open() as file:
            header = next(csv.reader(file), [])
        if header != COLUMNS:
            with path.open() as file:
                old = list(csv.DictReader(file))

            def rewrite(temporary: Path) -> None:
                with temporary.open("w", newline="") as file:
                    writer = csv.DictWriter(file, fieldnames=COLUMNS, restval="", extrasaction="ignore")
                    writer.writeheader()
                    writer.writerows(old)

            _atomic_replace(rewrite, path)
    new = not path.exists()
    with path.open("a", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=COLUMNS)
        if new:
            writer.writeheader()
        writer.writerow(cell)


def evaluate(model: Any, env: Any, episodes: int, seed: int = EVAL_SEED) -> tuple[float, float]:
    """Deterministic return and success rate (final step) over ``episodes`` episodes from reset seed ``seed``."""
    from sb3_trpo_plus.cli import evaluate as evaluate_policy

    env.seed(seed)
    result = evaluate_policy(model, env, episodes)
    return result["mean_reward"], result["success_rate"]


# ---------------------------------------------------------------------------------------------- reevaluation
REEVALUATION_COLUMNS = ["timesteps", "episodes", "reset_seed", "eval_success", "eval_return"]
REEVALUATION_EPISODES, REEVALUATION_SEED = 100, 20_000  # reevaluate's defaults, and the report's count of them
# the Grasper's second half as read since session 37 (docs/benchmarks.md): a checkpoint whose REEVALUATION_EPISODES
# fall below the target is evaluated on CONFIRMATION_EPISODES more from each of CONFIRMATION_SEEDS, and all of them decide
CONFIRMATION_EPISODES, CONFIRMATION_SEEDS = 200, (30_000, 40_000)


def evaluate_checkpoint(env_id: str, variant: str, folder: Path, episodes: int, seed: int) -> tuple[float, float]:
    """``evaluate`` of the checkpoint in ``folder`` (model.zip, vecnormalize.pkl), in the run's evaluation env."""
    import pickle

    import torch as th

    import grasp_envs  # noqa: F401

    th.set_num_threads(1)
    algo, overrides = VARIANTS[variant]
    normalize = model_settings(algo, env_id, overrides)[2]
    if normalize and not (folder / "vecnormalize.pkl").exists():
        raise FileNotFoundError(f"{folder}: the run normalizes its observations, and vecnormalize.pkl is missing")
    env = evaluation_env(env_id, variant, seed, normalize)
    if normalize:
        with (folder / "vecnormalize.pkl").open("rb") as file:
            env.obs_rms = pickle.load(file).obs_rms  # as run_job's evaluation env takes the training env's
    model = algorithm_class(variant).load(folder / "model.zip", device="cpu")
    try:
        return evaluate(model, env, episodes, seed)
    finally:
        env.close()


def checkpoints_after(kept: Path, out: Path, env_id: str, variant: str, seed: int, after: int) -> dict[int, Path]:
    """Timesteps -> folder of every checkpoint of the run past ``after``: those kept, and the run's own last one."""
    found = {}
    for snapshot in kept.iterdir() if kept.is_dir() else []:
        folder = job_folder(snapshot, env_id, variant, seed)
        if snapshot.name.isdigit() and int(snapshot.name) > after and (folder / "model.zip").exists():
            found[int(snapshot.name)] = folder
    folder = job_folder(out, env_id, variant, seed)
    rows = read_progress(folder)
    if rows and (folder / "model.zip").exists() and int(rows[-1]["timesteps"]) > after:
        found.setdefault(int(rows[-1]["timesteps"]), folder)
    return dict(sorted(found.items()))


def reevaluate(
    kept: Path,
    out: Path,
    envs: Sequence[str],
    variants: Sequence[str],
    seeds: Sequence[int],
    after: int,
    episodes: int,
    reset_seed: int,
    jobs: int,
    timesteps: Sequence[int] | None = None,
) -> None:
    """Evaluate every checkpoint past ``after`` (of ``timesteps`` only, if given) not yet evaluated with
    (episodes, reset_seed); print a summary."""
    if not kept.is_dir():
        raise FileNotFoundError(f"--kept {kept}: no such folder (convergence.py run --keep-checkpoints makes it)")
    if episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {episodes}")
    runs = [(env_id, variant, seed) for env_id in envs for variant in variants for seed in seeds]
    todo = []
    for env_id, variant, seed in runs:
        checkpoints = checkpoints_after(kept, out, env_id, variant, seed, after)
        if not checkpoints:
            raise FileNotFoundError(f"no checkpoint of {env_id} {variant} seed {seed} past {after} in {kept} or {out}")
        if timesteps:
            if missing := sorted(set(timesteps) - set(checkpoints)):
                raise FileNotFoundError(f"no checkpoint of {env_id} {variant} seed {seed} at {missing} past {after}")
            checkpoints = {t: checkpoints[t] for t in timesteps}
        done = {
            (row["timesteps"], row["episodes"], row["reset_seed"]) for row in read_reevaluation(out, env_id, variant, seed)
        }
        todo += [
            (env_id, variant, seed, t, folder) for t, folder in checkpoints.items() if (t, episodes, reset_seed) not in done
        ]
    print(f"{len(todo)} checkpoints to evaluate on {episodes} episodes from reset seed {reset_seed}", flush=True)

    def record(job: tuple[str, str, int, int, Path], result: tuple[float, float]) -> None:
        env_id, variant, seed, timesteps, _ = job
        row = {"timesteps": timesteps, "episodes": episodes, "reset_seed": reset_seed,
               "eval_success": result[1], "eval_return": round(result[0], 4)}  # fmt: skip
        _write_reevaluation(out, env_id, variant, seed, row)
        print(f"{env_id} {variant} seed{seed} {timesteps}: success {result[1]:.3f}", flush=True)

    if jobs > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {
                pool.submit(evaluate_checkpoint, e, v, f, episodes, reset_seed): (e, v, s, t, f) for e, v, s, t, f in todo
            }
            for future, job in futures.items():
                record(job, future.result())
    else:
        for job in todo:
            record(job, evaluate_checkpoint(job[0], job[1], job[4], episodes, reset_seed))
    for env_id, variant, seed in runs:
        rows = [row for row in reevaluations(out, env_id, variant, seed, episodes, reset_seed, after)
                if not timesteps or row["timesteps"] in timesteps]  # fmt: skip
        target = TARGETS.get(env_id, 0.0)
        reached = sum(row["eval_success"] >= target for row in rows)
        lowest = min(row["eval_success"] for row in rows)
        print(f"{env_id} {variant} seed{seed}: {reached} of {len(rows)} evaluations past {after} >= {target} "
              f"(lowest {lowest:.3f})")  # fmt: skip


def confirm(kept: Path, out: Path, envs: Sequence[str], variants: Sequence[str], seeds: Sequence[int], after: int,
            jobs: int) -> dict[tuple[str, str, int], bool | None]:  # fmt: skip
    """The declared reading end to end: every checkpoint past ``after`` on REEVALUATION_EPISODES from REEVALUATION_SEED,
    then each one those leave undecided (below the env's target) on CONFIRMATION_EPISODES from each of
    CONFIRMATION_SEEDS; evaluations already recorded are not run again. Prints and returns each run's verdict."""
    reevaluate(kept, out, envs, variants, seeds, after, REEVALUATION_EPISODES, REEVALUATION_SEED, jobs)
    verdicts = {}
    for env_id, variant, seed in [(e, v, s) for e in envs for v in variants for s in seeds]:
        target, checkpoints = TARGETS[env_id], list(checkpoints_after(kept, out, env_id, variant, seed, after))
        rows = read_reevaluation(out, env_id, variant, seed)
        if undecided := [t for t in checkpoints if checkpoint_verdict(at(rows, t), target) is None]:
            for reset_seed in CONFIRMATION_SEEDS:
                reevaluate(kept, out, [env_id], [variant], [seed], after, CONFIRMATION_EPISODES, reset_seed, jobs, undecided)
            rows = read_reevaluation(out, env_id, variant, seed)
        verdicts[env_id, variant, seed] = verdict = seed_verdict(rows, checkpoints, target)
        word = "undecided" if verdict is None else "pass" if verdict else "FAIL"
        first = {t: _protocol_runs(at(rows, t)).get(REEVALUATION_SEED) for t in checkpoints}
        below = [t for t, row in first.items() if row is not None and row["eval_success"] < target]  # now or earlier
        confirmed = ", ".join(f"{t}: {pooled_success(at(rows, t)):.3f}" for t in below)
        episodes = REEVALUATION_EPISODES + len(CONFIRMATION_SEEDS) * CONFIRMATION_EPISODES
        print(f"{env_id} {variant} seed{seed}: {word} ({len(checkpoints)} checkpoints past {after}; below {target} on "
              f"{REEVALUATION_EPISODES} episodes: {len(below)}{f', on {episodes}: {confirmed}' if below else ''})",
              flush=True)  # fmt: skip
    return verdicts


def at(rows: Sequence[dict[str, float]], timesteps: float) -> list[dict[str, float]]:
    """The re-evaluations of the checkpoint at ``timesteps``."""
    return [row for row in rows if row["timesteps"] == timesteps]


def read_reevaluation(out: Path, env_id: str, variant: str, seed: int) -> list[dict[str, float]]:
    return read_progress(job_folder(out, env_id, variant, seed), "reevaluation.csv")


def reevaluations(
    out: Path, env_id: str, variant: str, seed: int, episodes: int, reset_seed: int, after: float
) -> list[dict[str, float]]:
    """The run's re-evaluations on ``episodes`` episodes from ``reset_seed`` of its checkpoints past ``after``."""
    return [
        row
        for row in read_reevaluation(out, env_id, variant, seed)
        if row["episodes"] == episodes and row["reset_seed"] == reset_seed and row["timesteps"] > after
    ]


def checkpoint_verdict(rows: Sequence[dict[str, float]], target: float) -> bool | None:
    """The declared reading at one checkpoint, from its re-evaluations: at or above ``target`` on REEVALUATION_EPISODES
    episodes from REEVALUATION_SEED or, where those fall below it, on them and CONFIRMATION_EPISODES from each of
    CONFIRMATION_SEEDS together (successes pooled); None while an evaluation it needs has not been run."""
    runs = _protocol_runs(rows)
    if REEVALUATION_SEED not in runs:
        return None
    if runs[REEVALUATION_SEED]["eval_success"] >= target:
        return True
    if len(runs) < 1 + len(CONFIRMATION_SEEDS):
        return None
    return pooled_success(rows) >= target


def _protocol_runs(rows: Sequence[dict[str, float]]) -> dict[int, dict[str, float]]:
    """Reset seed -> the re-evaluation of one checkpoint's ``rows`` on that seed's episode count of the protocol."""
    protocol = {REEVALUATION_SEED: REEVALUATION_EPISODES, **dict.fromkeys(CONFIRMATION_SEEDS, CONFIRMATION_EPISODES)}
    return {int(r["reset_seed"]): r for r in rows if protocol.get(int(r["reset_seed"])) == r["episodes"]}


def pooled_success(rows: Sequence[dict[str, float]]) -> float:
    """One checkpoint's success rate over all the protocol's episodes among its re-evaluations ``rows``."""
    runs = _protocol_runs(rows).values()
    return sum(round(r["eval_success"] * r["episodes"]) for r in runs) / sum(r["episodes"] for r in runs)


def seed_verdict(rows: Sequence[dict[str, float]], checkpoints: Sequence[float], target: float) -> bool | None:
    """The declared reading for one run, from its re-evaluations: False if a checkpoint of ``checkpoints`` fails it,
    True if every one passes, None while one is undecided."""
    verdicts = [checkpoint_verdict(at(rows, t), target) for t in checkpoints]
    return False if False in verdicts else None if None in verdicts else True


def _write_reevaluation(out: Path, env_id: str, variant: str, seed: int, row: dict[str, Any]) -> None:
    """Add ``row`` to the run's reevaluation.csv (sorted by timesteps, episodes, seed), replacing the file atomically."""
    rows = [*read_reevaluation(out, env_id, variant, seed), row]
    rows.sort(key=lambda r: (r["timesteps"], r["episodes"], r["reset_seed"]))

    def write(temporary: Path) -> None:
        with temporary.open("w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=REEVALUATION_COLUMNS)
            writer.writeheader()
            for r in rows:
                writer.writerow(
                    {
                        key: int(r[key]) if key in ("timesteps", "episodes", "reset_seed") else r[key]
                        for key in REEVALUATION_COLUMNS
                    }
                )

    _atomic_replace(write, job_folder(out, env_id, variant, seed) / "reevaluation.csv")


# ---------------------------------------------------------------------------------------------- scheduler
def run_study(
    envs: Sequence[str],
    variants: Sequence[str],
    seeds: Sequence[int],
    jobs: int,
    out: Path,
    steps: int | None,
    keep: Path | None = None,
) -> None:
    """Run every unfinished job, ``jobs`` at a time, each in its own process (``job`` subcommand)."""
    todo = []
    for env_id in envs:
        budget = steps or BUDGETS[env_id]
        for seed in seeds:
            for variant in variants:
                rows = read_progress(job_folder(out, env_id, variant, seed))
                if not rows or rows[-1]["timesteps"] < budget:
                    todo.append((env_id, variant, seed, budget))
    print(f"{len(todo)} unfinished jobs", flush=True)

    def launch(job: tuple[str, str, int, int]) -> None:
        env_id, variant, seed, budget = job
        command = [sys.executable, __file__, "job", "--env", env_id, "--variant", variant, "--seed", str(seed),
                   "--steps", str(budget), "--out", str(out)]  # fmt: skip
        if keep is not None:
            command += ["--keep-checkpoints", str(keep)]
        start = time.time()
        result = subprocess.run(command, capture_output=True, text=True)
        status = "ok" if result.returncode == 0 else f"FAILED ({result.returncode}):\n{result.stderr[-2000:]}"
        print(f"{env_id} {variant} seed{seed}: {time.time() - start:.0f} s {status}", flush=True)

    with ThreadPoolExecutor(jobs) as pool:
        list(pool.map(launch, todo))


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run (or resume) the study")
    run.add_argument("--envs", nargs="+", default=list(BUDGETS), choices=list(BUDGETS))
    run.add_argument("--variants", nargs="+", default=STUDY_VARIANTS, choices=list(VARIANTS))
    run.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    run.add_argument("--steps", type=int, default=None, help="override the per-env budget (default: BUDGETS)")
    run.add_argument("--jobs", type=int, default=2)
    job = sub.add_parser("job", help="one (env, variant, seed); used by run")
    job.add_argument("--env", required=True, choices=list(BUDGETS))
    job.add_argument("--variant", required=True, choices=list(VARIANTS))
    job.add_argument("--seed", type=int, required=True)
    job.add_argument("--steps", type=int, required=True)
    report = sub.add_parser("report", help="figures, tables and rliable aggregates into docs/results.md")
    report.add_argument("--docs", default=str(ROOT / "docs" / "results.md"))
    agents = sub.add_parser("agents", help="export the best TRPOPlus run of each env to trained_agents/")
    agents.add_argument("--envs", nargs="+", default=list(BUDGETS), choices=list(BUDGETS))
    agents.add_argument("--folder", default=str(ROOT / "trained_agents"))
    again = sub.add_parser("reevaluate", help="evaluate kept checkpoints again on more episodes")
    again.add_argument("--kept", type=Path, required=True, help="the folder of run --keep-checkpoints")
    again.add_argument("--envs", nargs="+", required=True, choices=list(BUDGETS))
    again.add_argument("--variants", nargs="+", required=True, choices=list(VARIANTS))
    again.add_argument("--seeds", type=int, nargs="+", required=True)
    again.add_argument("--after", type=int, default=0, help="only checkpoints past these timesteps")
    again.add_argument("--episodes", type=int, default=None, help=f"default {REEVALUATION_EPISODES}")
    again.add_argument("--reset-seed", type=int, default=None, help=f"not the study's 10,000; default {REEVALUATION_SEED}")
    again.add_argument("--jobs", type=int, default=2)
    again.add_argument("--timesteps", type=int, nargs="+", default=None, help="only the checkpoints at these")
    again.add_argument(
        "--confirm", action="store_true",
        help=f"the declared reading: {REEVALUATION_EPISODES} episodes from {REEVALUATION_SEED}, then "
        f"{CONFIRMATION_EPISODES} from each of {', '.join(map(str, CONFIRMATION_SEEDS))} where those fall below the target",
    )  # fmt: skip
    for command in (run, job, report, agents, again):
        command.add_argument("--out", default=str(OUT))
    for command in (run, job):
        command.add_argument(
            "--keep-checkpoints", type=Path, default=None, metavar="DIR",
            help="also keep every chunk's checkpoint, in DIR/<timesteps>/<env>/<variant>/seed<k>/",
        )  # fmt: skip
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.command == "run":
        run_study(args.envs, args.variants, args.seeds, args.jobs, out, args.steps, args.keep_checkpoints)
    elif args.command == "job":
        run_job(args.env, args.variant, args.seed, args.steps, out, args.keep_checkpoints)
    elif args.command == "reevaluate" and args.confirm:
        names = ("episodes", "reset_seed", "timesteps")
        if given := [f"--{n.replace('_', '-')}" for n in names if getattr(args, n) is not None]:
            parser.error(f"reevaluate --confirm sets the episodes and checkpoints itself; drop {' '.join(given)}")
        confirm(args.kept, out, args.envs, args.variants, args.seeds, args.after, args.jobs)
    elif args.command == "reevaluate":
        episodes = REEVALUATION_EPISODES if args.episodes is None else args.episodes
        reset_seed = REEVALUATION_SEED if args.reset_seed is None else args.reset_seed
        reevaluate(
            args.kept, out, args.envs, args.variants, args.seeds, args.after, episodes, reset_seed, args.jobs, args.timesteps
        )
    elif args.command == "report":
        from convergence_report import write_report  # benchmarks/convergence_report.py

        write_report(out, Path(args.docs))
    else:
        from convergence_report import export_agents

        export_agents(out, args.envs, Path(args.folder))


if __name__ == "__main__":
    main()
