"""Per-iteration time of TRPOPlus against sb3-contrib TRPO, split by phase, in one process.

    python -m benchmarks.speed [--envs Reacher2D-v0 Grasper3D-v0 Hopper-v5] [--n-envs 8] [--n-steps 256]
                               [--repeats 7] [--out benchmarks/results/speed.json]
    python -m benchmarks.speed --batch --envs Grasper3D-v7 --n-envs 64 --n-steps 32 --sim-threads 2

Contenders (identical hyperparameters, n_envs and network): sb3-contrib TRPO, TRPOPlus with replay off,
TRPOPlus with replay_memory=3. Each contender trains one warm-up iteration, then the repeats are
interleaved (contender A, B, C, A, B, C, ...). Phases: rollout collection, advantage / replay
recomputation, policy update (gradient, CG with its Fisher products, line search), critic update.
"Simulation share" = time of raw mj_step calls for the iteration's physics steps / iteration time.

``--batch``: the contenders are sb3-contrib TRPO and TRPOPlus on SB3's DummyVecEnv, and TRPOPlus on the batched
engine (``grasp_envs.make_batch_env``, ``--sim-threads`` threads), all at the same hyperparameters and ``n_envs``;
"physics share" is then the time inside ``mujoco.batch``'s steps / the batched contender's collection time.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
import sb3_contrib
import stable_baselines3
import torch as th
from sb3_contrib import TRPO
from stable_baselines3.common.env_util import make_vec_env
from torch import nn

from benchmarks.env_speed import time_mj_step
from benchmarks.scaling import PhysicsTimer
from grasp_envs import make_batch_env
from sb3_trpo_plus import TRPOPlus

PHASES = ("rollout", "recompute", "policy", "critic")


class PhaseTimer:
    """Wraps a model's methods to time each phase of one iteration."""

    def __init__(self, model: Any):
        self.model = model
        self.times: dict[str, float] = defaultdict(float)
        self.fvp = 0
        self._wrap("collect_rollouts", "rollout")
        if isinstance(model, TRPOPlus):
            self._read_trpo_plus_timings()
        else:
            self._wrap_trpo_train()
            original_hvp = model.hessian_vector_product

            def counted(*args: Any, **kwargs: Any) -> th.Tensor:
                self.fvp += 1
                return original_hvp(*args, **kwargs)

            model.hessian_vector_product = counted

    def _wrap(self, name: str, phase: str) -> None:
        original = getattr(self.model, name)

        def timed(*args: Any, **kwargs: Any) -> Any:
            start = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                self.times[phase] += time.perf_counter() - start

        setattr(self.model, name, timed)

    def _read_trpo_plus_timings(self) -> None:
        """TRPOPlus logs its update's phases (train/prepare_time, policy_step_time, value_fit_time): read them after
        each train(), before SB3 writes the logger out."""
        model, original_train = self.model, self.model.train

        def timed_train() -> None:
            original_train()
            logged = model.logger.name_to_value
            self.times["recompute"] += logged["train/prepare_time"]
            self.times["policy"] += logged["train/policy_step_time"]
            self.times["critic"] += logged["train/value_fit_time"]

        model.train = timed_train

    def _wrap_trpo_train(self) -> None:
        """sb3-contrib's train(): policy part until the first critic minibatch is requested, critic after."""
        model, original_train = self.model, self.model.train

        def timed_train() -> None:
            buffer = model.rollout_buffer
            original_get = buffer.get
            marks: dict[str, float] = {}

            def get(batch_size: int | None = None):
                if batch_size is not None and "critic" not in marks:
                    marks["critic"] = time.perf_counter()
                return original_get(batch_size)

            buffer.get = get
            start = time.perf_counter()
            try:
                original_train()
            finally:
                end = time.perf_counter()
                buffer.get = original_get
                critic_start = marks.get("critic", end)
                self.times["policy"] += critic_start - start
                self.times["critic"] += end - critic_start

        model.train = timed_train

    def fisher_products(self) -> int:
        if isinstance(self.model, TRPOPlus):
            return int(self.model.logger.name_to_value["train/fisher_vector_products"])
        return self.fvp

    def reset(self) -> None:
        self.times.clear()
        self.fvp = 0


BATCHED = "TRPOPlus[batch]"


def build(name: str, env_id: str, n_envs: int, n_steps: int, seed: int, sim_threads: int = 1) -> Any:
    env: Any
    if name == BATCHED:
        env = make_batch_env(env_id, n_envs, seed=seed, n_threads=sim_threads)
    else:
        env = make_vec_env(env_id, n_envs=n_envs, seed=seed)
    common: dict[str, Any] = dict(
        n_steps=n_steps,
        batch_size=n_steps * n_envs // 4,
        cg_max_steps=10,
        n_critic_updates=10,
        seed=seed,
        policy_kwargs=dict(net_arch=[100, 100], activation_fn=nn.Tanh),
        device="cpu",
    )
    if name == "sb3_contrib.TRPO":
        return TRPO("MlpPolicy", env, **common)
    if name in ("TRPOPlus", BATCHED):
        return TRPOPlus("MlpPolicy", env, **common)
    if name == "TRPOPlus(k=3)":
        return TRPOPlus("MlpPolicy", env, replay_memory=3, **common)
    return TRPOPlus("MlpPolicy", env, replay_memory=3, fisher_sub_sampling=4, **common)


def _table_row(name: str, s: dict[str, Any]) -> str:
    def ms(key: str) -> str:
        return f"{s[key]['median'] * 1e3:.1f}"

    total = f"{ms('total')} [{s['total']['min'] * 1e3:.0f}-{s['total']['max'] * 1e3:.0f}]"
    cells = [name, total, ms("rollout"), ms("recompute"), ms("policy"), ms("critic"), f"{s['fisher_products']['median']:.0f}"]
    cells += [f"{s[k]:.2f}" for k in ("ratio_policy_update_vs_trpo", "ratio_update_vs_trpo_update", "ratio_iteration_vs_trpo")]
    cells.append(f"{s['simulation_share']:.0%}")
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=["Reacher2D-v0", "Grasper3D-v0", "Hopper-v5"])
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--n-steps", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--batch", action="store_true", help="TRPO and TRPOPlus on DummyVecEnv, TRPOPlus batched")
    parser.add_argument("--sim-threads", type=int, default=1, help="threads of the batched engine's physics")
    parser.add_argument("--out", default=None, help="default: benchmarks/results/speed[_batch].json")
    args = parser.parse_args()
    args.out = args.out or f"benchmarks/results/speed{'_batch' * args.batch}.json"
    th.set_num_threads(args.threads)
    if args.batch:
        contenders = ["sb3_contrib.TRPO", "TRPOPlus", BATCHED]
    else:
        contenders = ["sb3_contrib.TRPO", "TRPOPlus", "TRPOPlus(k=3)", "TRPOPlus(k=3,fisher/4)"]
    results: dict[str, Any] = {
        "command": "python -m benchmarks.speed --envs "
        + " ".join(args.envs)
        + "".join(f" --{k.replace('_', '-')} {v}" for k, v in vars(args).items() if not isinstance(v, list)),
        "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version()},
        "versions": {
            "torch": th.__version__,
            "stable_baselines3": stable_baselines3.__version__,
            "sb3_contrib": sb3_contrib.__version__,
            "gymnasium": gym.__version__,
            "mujoco": mujoco.__version__,
        },
        "settings": {
            "n_envs": args.n_envs,
            "n_steps": args.n_steps,
            "repeats": args.repeats,
            "threads": args.threads,
            "net_arch": [100, 100],
            "cg_max_steps": 10,
            "n_critic_updates": 10,
        },
        "envs": {},
    }
    samples = args.n_envs * args.n_steps
    for env_id in args.envs:
        models = {name: build(name, env_id, args.n_envs, args.n_steps, 0, args.sim_threads) for name in contenders}
        timers = {name: PhaseTimer(model) for name, model in models.items()}
        physics = PhysicsTimer(models[BATCHED].get_env().unwrapped) if BATCHED in models else None
        for name, model in models.items():  # warm-up, and fills the replay memory
            model.learn(samples * (4 if "k=3" in name else 1))
        rows: dict[str, list[dict[str, float]]] = defaultdict(list)
        for _ in range(args.repeats):
            for name, model in models.items():
                timers[name].reset()
                if physics is not None:
                    physics.seconds = 0.0
                start = time.perf_counter()
                model.learn(samples, reset_num_timesteps=False)
                total = time.perf_counter() - start
                row = {phase: timers[name].times.get(phase, 0.0) for phase in PHASES}
                row.update(total=total, fisher_products=timers[name].fisher_products())
                if name == BATCHED and physics is not None:
                    row["physics_share_of_rollout"] = physics.seconds / row["rollout"]
                rows[name].append(row)
            rows["raw_mj_step"].append({"total": time_mj_step(env_id, samples) * samples})  # `samples` env steps
        summary: dict[str, Any] = {}
        for name, name_rows in rows.items():
            summary[name] = {
                key: {
                    "median": float(np.median([r[key] for r in name_rows])),
                    "min": float(np.min([r[key] for r in name_rows])),
                    "max": float(np.max([r[key] for r in name_rows])),
                }
                for key in name_rows[0]
            }
        anchor = summary["sb3_contrib.TRPO"]
        raw = summary["raw_mj_step"]["total"]["median"]
        for name in contenders:
            s = summary[name]
            s["ratio_policy_update_vs_trpo"] = s["policy"]["median"] / anchor["policy"]["median"]
            s["ratio_update_vs_trpo_update"] = (s["recompute"]["median"] + s["policy"]["median"]) / anchor["policy"]["median"]
            s["ratio_iteration_vs_trpo"] = s["total"]["median"] / anchor["total"]["median"]
            s["simulation_share"] = raw / s["total"]["median"]
            s["env_steps_per_s"] = samples / s["total"]["median"]
            s["ratio_rollout_vs_trpo"] = s["rollout"]["median"] / anchor["rollout"]["median"]
        results["envs"][env_id] = summary
        print(f"\n## {env_id}  ({samples} samples / iteration, raw mj_step {raw * 1e3:.1f} ms)")
        print(
            "| contender | iteration (ms) | rollout | recompute | policy update | critic | FVPs | policy vs TRPO | "
            "update vs TRPO | iteration vs TRPO | sim. share |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for name in contenders:
            print(_table_row(name, summary[name]))
        if BATCHED in summary:
            b = summary[BATCHED]
            print(
                f"\n{BATCHED}: training {1 / b['ratio_iteration_vs_trpo']:.2f}x sb3-contrib TRPO on DummyVecEnv, "
                f"collection {1 / b['ratio_rollout_vs_trpo']:.2f}x, physics "
                f"{b['physics_share_of_rollout']['median']:.0%} of the collection time"
            )
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"\nraw results: {args.out}")


if __name__ == "__main__":
    main()
