"""How fast do sb3-contrib's TRPO and plain TRPOPlus drift apart when they start from the same seed?

    python -m benchmarks.trpo_divergence --env Reacher2D-v1 --seeds 5 6 7 --updates 147
    python -m benchmarks.trpo_divergence --env Reacher2D-v1 --study   # P(X > Y) of the study's runs

Both models are built with the zoo settings of the env (zoo_hyperparams/trpo.yml and trpo_plus.yml, the
same values) and the same seed, so they start with the same weights and collect the same first rollout.
sb3-contrib's conjugate gradient starts at 1e-4 * randn, a draw from torch's global generator that
TRPOPlus does not make; here it starts at 0 (``benchmarks.builders.zero_start_solver``), which removes the
algorithms' only difference except floating-point rounding (analytic Fisher products against double
backpropagation). The script prints the relative distance ||θ_TRPO - θ_TRPOPlus|| / ||θ_TRPO|| of the policy
parameters after each update. The convergence study's variant ``trpo_cg0`` trains with the same solver.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th

from benchmarks.builders import new_model, use_zero_start_in_sb3_contrib_trpo


def _flat_parameters(model: Any) -> np.ndarray:
    return th.nn.utils.parameters_to_vector(model.policy.parameters()).detach().double().numpy().copy()


def _model(algo: str, env_id: str, seed: int, env: Any = None) -> Any:
    """A model with the zoo settings of ``algo`` on ``env_id`` (TRPOPlus: plain), on ``env`` or a new seeded env."""
    variant = "plain" if algo == "trpo_plus" else algo  # the study's plain TRPOPlus / sb3-contrib TRPO
    return new_model(env_id, variant, seed, env)


def parameter_trajectory(algo: str, env_id: str, seed: int, updates: int) -> list[np.ndarray]:
    """Flat policy parameters before the first update and after each update (zoo settings of ``algo``)."""
    from stable_baselines3.common.callbacks import BaseCallback

    model = _model(algo, env_id, seed)
    trajectory: list[np.ndarray] = []

    class Record(BaseCallback):
        def _on_rollout_start(self) -> None:
            trajectory.append(_flat_parameters(self.model))

        def _on_step(self) -> bool:
            return True

    model.learn(model.n_steps * model.n_envs * updates, callback=Record())
    model.env.close()
    return trajectory


def update_agreement(env_id: str, seed: int, updates: int) -> list[float]:
    """Along a plain TRPOPlus run, sb3-contrib's ``train()`` on the same input: ||Δθ_TRPO - Δθ_TRPOPlus|| / ||Δθ_TRPOPlus||.

    Before each TRPOPlus update, a TRPO model gets TRPOPlus' weights, critic optimiser state, rollout buffer,
    learning-rate progress and numpy / torch generator states, and makes its update; TRPOPlus then makes its
    own from the same state. A difference between the two algorithms anywhere on the trajectory (e.g. after a
    rejected line search, or once the policy's std has moved) shows as a ratio far above float rounding.
    """
    import copy

    from stable_baselines3.common.logger import Logger

    use_zero_start_in_sb3_contrib_trpo()
    th.set_num_threads(1)
    plus = _model("trpo_plus", env_id, seed)
    reference = _model("trpo", env_id, seed, env=plus.env)
    reference.set_logger(Logger(folder=None, output_formats=[]))
    ratios: list[float] = []
    plus_train = plus.train

    def compared_train() -> None:
        before = _flat_parameters(plus)
        numpy_state, torch_state = np.random.get_state(), th.get_rng_state()
        reference.policy.load_state_dict(plus.policy.state_dict())
        reference.policy.optimizer.load_state_dict(copy.deepcopy(plus.policy.optimizer.state_dict()))
        reference.rollout_buffer = copy.deepcopy(plus.rollout_buffer)
        reference._current_progress_remaining = plus._current_progress_remaining
        reference.train()
        np.random.set_state(numpy_state)
        th.set_rng_state(torch_state)
        plus_train()
        step_plus, step_reference = _flat_parameters(plus) - before, _flat_parameters(reference) - before
        ratios.append(float(np.linalg.norm(step_reference - step_plus) / max(float(np.linalg.norm(step_plus)), 1e-12)))

    plus.train = compared_train
    plus.learn(plus.n_steps * plus.n_envs * updates)
    plus.env.close()
    return ratios


def divergence(env_id: str, seed: int, updates: int) -> list[float]:
    """Relative parameter distance between sb3-contrib TRPO (CG started at 0) and plain TRPOPlus, per update."""
    use_zero_start_in_sb3_contrib_trpo()
    th.set_num_threads(1)
    trpo = parameter_trajectory("trpo", env_id, seed, updates)
    plus = parameter_trajectory("trpo_plus", env_id, seed, updates)
    return [float(np.linalg.norm(a - b) / np.linalg.norm(a)) for a, b in zip(trpo, plus, strict=True)]


def study_pairs(env_id: str, pairs: Sequence[tuple[str, str]]) -> list[str]:
    """P(X > Y) on the success area over every seed both variants finished in the convergence study (rliable)."""
    from rliable import metrics

    from benchmarks.report import LABELS, complete_runs, interval_estimates, success_score
    from benchmarks.runs import OUT

    lines = [f"{env_id}: P(X > Y), success area, every seed both finished", "| X > Y | seeds | estimate [95 % CI] |"]
    lines.append("|---|---|---|")
    for a, b in pairs:
        runs_a, runs_b = complete_runs(OUT, env_id, a), complete_runs(OUT, env_id, b)
        seeds = sorted(set(runs_a) & set(runs_b))
        if not seeds:
            lines.append(f"| {LABELS[a]} > {LABELS[b]} | 0 | no common finished seed |")
            continue
        area_a = np.array([[success_score(runs_a[s], "area")] for s in seeds])
        area_b = np.array([[success_score(runs_b[s], "area")] for s in seeds])
        point, interval = interval_estimates({"pair": (area_a, area_b)}, metrics.probability_of_improvement)
        low, high = float(np.squeeze(interval["pair"][0])), float(np.squeeze(interval["pair"][1]))
        estimate = float(np.squeeze(point["pair"]))
        lines.append(f"| {LABELS[a]} > {LABELS[b]} | {len(seeds)} | {estimate:.2f} [{low:.2f}, {high:.2f}] |")
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="Reacher2D-v1")
    parser.add_argument("--seeds", type=int, nargs="+", default=[5])
    parser.add_argument("--updates", type=int, default=60)
    parser.add_argument("--study", action="store_true", help="only the study's P(X > Y) tables (no training)")
    args = parser.parse_args(argv)
    if args.study:
        print("\n".join(study_pairs(args.env, [("plain", "trpo_cg0"), ("trpo_cg0", "trpo"), ("plain", "trpo")])))
        return
    agreement = {seed: update_agreement(args.env, seed, args.updates) for seed in args.seeds}
    print(f"{args.env}: the same update from the same state, ||Δθ_TRPO - Δθ_TRPOPlus|| / ||Δθ_TRPOPlus||")
    half = args.updates // 2
    print(f"| seed | median, updates 1-{half} | median, updates {half + 1}-{args.updates} | max | update of the max |")
    print("|---|---|---|---|---|")
    for seed, ratios in agreement.items():
        first, second = np.median(ratios[:half]), np.median(ratios[half:])
        print(f"| {seed} | {first:.1e} | {second:.1e} | {max(ratios):.1e} | {int(np.argmax(ratios)) + 1} |")
    curves: dict[int, Any] = {seed: divergence(args.env, seed, args.updates) for seed in args.seeds}
    shown = [u for u in (1, 2, 4, 6, 8, 10, 12, 15, 20, 30, 40, 50, 60, 80, 100) if u < args.updates]
    print(f"{args.env}: ||θ_TRPO - θ_TRPOPlus|| / ||θ_TRPO|| after k updates")
    print("| seed | " + " | ".join(f"k={u}" for u in shown) + " |")
    print("|---|" + "---|" * len(shown))
    for seed, curve in curves.items():
        print(f"| {seed} | " + " | ".join(f"{curve[u]:.1e}" for u in shown) + " |")


if __name__ == "__main__":
    main()
