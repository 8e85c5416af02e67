"""Does replay memory / warm-started CG speed up learning? The thesis' experiments (section 5.3), resumable.

    python -m benchmarks.convergence run --envs Reacher2D-v0 --seeds 0 1 2 3 4 [--variants ...] [--jobs 2]
    python -m benchmarks.convergence report          # figures, tables, rliable -> docs/results-tables.md (+ results.md block)
    python -m benchmarks.convergence agents          # best TRPOPlus run per env -> trained_agents/

The envs and the variants are data (benchmarks/study.yml, read by benchmarks/study.py): TRPOPlus plain (k = 0, zero
CG start), + replay (k = 3), + warm start, + both, sb3-contrib TRPO and SB3 PPO, each with the zoo hyperparameters of
its algorithm (zoo_hyperparams/*.yml), and the variants that change one setting on top of those. Every
(env, variant, seed) is one job in its own process (benchmarks/runner.py), trained in chunks of budget / 25 steps;
after each chunk the job evaluates the deterministic policy on 20 held-out episodes (reset seed 10,000, the same
episodes at every point and in every run; benchmarks/protocol.py), saves the model and the VecNormalize statistics
atomically and appends a row to benchmarks/results/convergence/<env>/<variant>/seed<k>/progress.csv
(benchmarks/runs.py). A rerun continues every unfinished job from its last row, so the study can be stopped at any
time (a resumed job's env seeds differ from an uninterrupted run's; the CSV says where it resumed).

Checkpoints (model.zip, vecnormalize.pkl) are git-ignored, so a fresh clone holds a run's CSV without them, and
`run` starts such a run again from zero (its CSV removed). Committing a run's two checkpoint files with ``git add -f``
keeps a long run resumable on another machine.

A job overwrites its checkpoint at every chunk. ``--keep-checkpoints DIR`` also keeps each chunk's:
DIR/<timesteps>/<env>/<variant>/seed<k>/ holds model.zip, vecnormalize.pkl and progress.csv up to that row, so
DIR/<timesteps> is the study's folder as it stood then (``--out`` of ``report``, ``--runs`` of
``python -m benchmarks.grasper_probe``).

    python -m benchmarks.convergence reevaluate --kept DIR --envs Grasper3D-v6 --variants ... --seeds 3 4 \
        --after 2000000 --episodes 100 --reset-seed 20000

evaluates every kept checkpoint past ``--after`` (and each run's own last one) again, the study's way (deterministic
policy, VecNormalize statistics of the checkpoint, the env seeded once) on more episodes from another reset seed,
into <out>/<env>/<variant>/seed<k>/reevaluation.csv; a checkpoint already evaluated so is not evaluated again.
``reevaluate --confirm --after 2000000`` runs the confirmation protocol (docs/results.md, "The target, seed by seed")
end to end: every checkpoint past 2M on 100 episodes from reset seed 20,000, then each one below the target on 200
more from each of 30,000 and 40,000 (the 500 pooled decide), and prints each run's verdict.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from benchmarks.protocol import (
    CONFIRMATION_EPISODES,
    CONFIRMATION_SEEDS,
    REEVALUATION_EPISODES,
    REEVALUATION_SEED,
    confirm,
    reevaluate,
)
from benchmarks.report import export_agents, write_report
from benchmarks.runner import run_job, run_study
from benchmarks.runs import OUT
from benchmarks.study import BUDGETS, ROOT, STUDY_VARIANTS, VARIANTS


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.convergence", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run (or resume) the study")
    run.add_argument("--envs", nargs="+", default=list(BUDGETS), choices=list(BUDGETS))
    run.add_argument("--variants", nargs="+", default=STUDY_VARIANTS, choices=list(VARIANTS))
    run.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    run.add_argument("--steps", type=int, default=None, help="override the per-env budget (default: study.yml's)")
    run.add_argument("--jobs", type=int, default=2)
    job = sub.add_parser("job", help="one (env, variant, seed); used by run")
    job.add_argument("--env", required=True, choices=list(BUDGETS))
    job.add_argument("--variant", required=True, choices=list(VARIANTS))
    job.add_argument("--seed", type=int, required=True)
    job.add_argument("--steps", type=int, required=True)
    report = sub.add_parser(
        "report", help="figures, tables and rliable aggregates into docs/results-tables.md and docs/results.md's block"
    )
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
        "--confirm",
        action="store_true",
        help=f"the confirmation protocol: {REEVALUATION_EPISODES} episodes from {REEVALUATION_SEED}, then "
        f"{CONFIRMATION_EPISODES} from each of {', '.join(map(str, CONFIRMATION_SEEDS))} where those fall below the target",
    )
    for command in (run, job, report, agents, again):
        command.add_argument("--out", default=str(OUT))
    for command in (run, job):
        command.add_argument(
            "--keep-checkpoints",
            type=Path,
            default=None,
            metavar="DIR",
            help="also keep every chunk's checkpoint, in DIR/<timesteps>/<env>/<variant>/seed<k>/",
        )
        command.add_argument(
            "--vec-env",
            choices=("dummy", "batch"),
            default="dummy",
            help="training envs: SB3's DummyVecEnv or the batched engine (the same transitions, faster)",
        )
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.command == "run":
        run_study(args.envs, args.variants, args.seeds, args.jobs, out, args.steps, args.keep_checkpoints, args.vec_env)
    elif args.command == "job":
        run_job(args.env, args.variant, args.seed, args.steps, out, args.keep_checkpoints, args.vec_env)
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
        write_report(out, Path(args.docs))
    else:
        export_agents(out, args.envs, Path(args.folder))


if __name__ == "__main__":
    main()
