"""The convergence study's evaluation protocol, and the re-evaluation of kept checkpoints.

Every evaluation runs the deterministic policy with the VecNormalize statistics of its checkpoint (fixed) on the
variant's evaluation env (its env kwargs, no training wrappers), the env seeded once (``sb3_trpo_plus.application.evaluation``
with ``seed_every_episode=False``): during training EVAL_EPISODES episodes from reset seed EVAL_SEED, the same at
every chunk and in every run. ``reevaluate`` evaluates kept checkpoints again on more episodes from other reset
seeds, and ``confirm`` runs the confirmation protocol, which decides whether a Grasper run holds its target after 2M
(docs/results.md, "The target, seed by seed"): every checkpoint on REEVALUATION_EPISODES from REEVALUATION_SEED, then
each one below the target on CONFIRMATION_EPISODES more from each of CONFIRMATION_SEEDS, all of them pooled deciding.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.builders import algorithm_class, evaluation_env, model_settings
from benchmarks.runs import job_folder, read_progress, read_reevaluation, write_reevaluation
from benchmarks.study import TARGETS

EVAL_EPISODES = 20
EVAL_SEED = 10_000
REEVALUATION_EPISODES, REEVALUATION_SEED = 100, 20_000  # reevaluate's defaults, and the report's count of them
# a checkpoint whose REEVALUATION_EPISODES fall below the target is evaluated on CONFIRMATION_EPISODES more from each of
# CONFIRMATION_SEEDS, and all of them decide
CONFIRMATION_EPISODES, CONFIRMATION_SEEDS = 200, (30_000, 40_000)


def evaluate(model: Any, env: Any, episodes: int, seed: int = EVAL_SEED) -> tuple[float, float]:
    """(mean return, success rate) of the deterministic policy over ``episodes`` episodes, the env seeded once with
    ``seed``."""
    from sb3_trpo_plus.application.evaluation import evaluate_agent

    result = evaluate_agent(model, env, episodes, seed, seed_every_episode=False)
    return result.mean_return, result.success_rate


def evaluate_checkpoint(env_id: str, variant: str, folder: Path, episodes: int, seed: int) -> tuple[float, float]:
    """``evaluate`` of the checkpoint in ``folder`` (model.zip, vecnormalize.pkl), in the run's evaluation env."""
    import torch as th

    th.set_num_threads(1)
    statistics = folder / "vecnormalize.pkl"
    if model_settings(env_id, variant).normalize:
        if not statistics.exists():
            raise FileNotFoundError(f"{folder}: the run normalizes its observations, and vecnormalize.pkl is missing")
        env = evaluation_env(env_id, variant, seed, statistics)
    else:
        env = evaluation_env(env_id, variant, seed)
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
    (episodes, reset_seed), into each run's reevaluation.csv; print a summary."""
    if not kept.is_dir():
        raise FileNotFoundError(f"--kept {kept}: no such folder (convergence run --keep-checkpoints makes it)")
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
        row = {
            "timesteps": timesteps,
            "episodes": episodes,
            "reset_seed": reset_seed,
            "eval_success": result[1],
            "eval_return": round(result[0], 4),
        }
        write_reevaluation(out, env_id, variant, seed, row)
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
        rows = [
            row
            for row in reevaluations(out, env_id, variant, seed, episodes, reset_seed, after)
            if not timesteps or row["timesteps"] in timesteps
        ]
        target = TARGETS.get(env_id, 0.0)
        reached = sum(row["eval_success"] >= target for row in rows)
        lowest = min(row["eval_success"] for row in rows)
        print(
            f"{env_id} {variant} seed{seed}: {reached} of {len(rows)} evaluations past {after} >= {target} "
            f"(lowest {lowest:.3f})"
        )


def confirm(
    kept: Path, out: Path, envs: Sequence[str], variants: Sequence[str], seeds: Sequence[int], after: int, jobs: int
) -> dict[tuple[str, str, int], bool | None]:
    """The confirmation protocol end to end: every checkpoint past ``after`` on REEVALUATION_EPISODES from
    REEVALUATION_SEED, then each one those leave undecided (below the env's target) on CONFIRMATION_EPISODES from each
    of CONFIRMATION_SEEDS; evaluations already recorded are not run again. Prints and returns each run's verdict."""
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
        below = [t for t, row in first.items() if row is not None and row["eval_success"] < target]  # by this call or another
        confirmed = ", ".join(f"{t}: {pooled_success(at(rows, t)):.3f}" for t in below)
        episodes = REEVALUATION_EPISODES + len(CONFIRMATION_SEEDS) * CONFIRMATION_EPISODES
        print(
            f"{env_id} {variant} seed{seed}: {word} ({len(checkpoints)} checkpoints past {after}; below {target} on "
            f"{REEVALUATION_EPISODES} episodes: {len(below)}{f', on {episodes}: {confirmed}' if below else ''})",
            flush=True,
        )
    return verdicts


def at(rows: Sequence[dict[str, float]], timesteps: float) -> list[dict[str, float]]:
    """The re-evaluations of the checkpoint at ``timesteps``."""
    return [row for row in rows if row["timesteps"] == timesteps]


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
    """The confirmation protocol's verdict on one checkpoint, from its re-evaluations: at or above ``target`` on
    REEVALUATION_EPISODES episodes from REEVALUATION_SEED or, where those fall below it, on them and
    CONFIRMATION_EPISODES from each of CONFIRMATION_SEEDS together (successes pooled); None while an evaluation it
    needs has not been run."""
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
    """The confirmation protocol's verdict on one run, from its re-evaluations: False if a checkpoint of
    ``checkpoints`` fails it, True if every one passes, None while one is undecided."""
    verdicts = [checkpoint_verdict(at(rows, t), target) for t in checkpoints]
    return False if False in verdicts else None if None in verdicts else True
