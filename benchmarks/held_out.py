"""Success of a saved run's deterministic policy on held-out episodes of its env as registered.

    python -m benchmarks.held_out logs/trpo_plus/Grasper3D-v7_1 --env Grasper3D-v7 --episodes 200 --seed 30000

Loads the run through the weights-only path (``sb3_trpo_plus.application.agents.load_eval_agent``: nothing unpickled or
evaluated; VecNormalize statistics frozen; the training-only wrappers, such as ``ScriptedStarts``, left out) and
runs ``--episodes`` episodes, episode ``k`` reset with seed ``--seed + k`` (``evaluate_agent``). Prints one JSON
object: episodes, first reset seed, success rate, successes, mean return. Pick the seeds away from those that chose
the run (the study's evaluations use 10,000 and 20,000), so that the episodes played no part in picking it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sb3_trpo_plus.application.agents import load_eval_agent
from sb3_trpo_plus.application.evaluation import evaluate_agent


def held_out(run: Path, env_id: str | None, episodes: int, seed: int) -> dict[str, Any]:
    """The run's held-out evaluation as a JSON-ready mapping."""
    model, env = load_eval_agent(run, env_id, seed=seed)
    try:
        result = evaluate_agent(model, env, episodes, seed=seed)
    finally:
        env.close()
    return {
        "episodes": result.episodes,
        "eval_seed": seed,
        "success_rate": round(result.success_rate, 4),
        "successes": int(sum(result.successes)),
        "mean_reward": round(result.mean_return, 3),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a run folder of trpo-plus train (logs/<algo>/<env>_<n>)")
    parser.add_argument("--env", default=None, help="the env id (default: the run's)")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=30_000, help="reset seed of the first episode")
    args = parser.parse_args(argv)
    print(json.dumps(held_out(args.run, args.env, args.episodes, args.seed)))


if __name__ == "__main__":
    main()
