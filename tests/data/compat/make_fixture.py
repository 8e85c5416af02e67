"""Write the compatibility fixture: a TRPOPlus model as this version saves it, for later versions to load.

    python tests/data/compat/make_fixture.py

writes ``trpo_plus-<version>/`` beside this script: ``model.zip`` (a tiny Pendulum-v1 policy after three updates,
its replay memory holding two rollouts, the CG warm start and the random generators' states),
``vecnormalize.pkl`` and ``manifest.json`` (the parameter names and shapes, the replay memory's length, the step
count). ``tests/test_faults.py`` loads every such folder and continues training. Run it once per released version
and commit the folder; never regenerate an old one.
"""

from __future__ import annotations

import json
from pathlib import Path

from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import sb3_trpo_plus
from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.application.callbacks import save_vec_normalize

HERE = Path(__file__).resolve().parent


def main() -> None:
    folder = HERE / f"trpo_plus-{sb3_trpo_plus.__version__}"
    folder.mkdir(exist_ok=True)
    env = VecNormalize(make_vec_env("Pendulum-v1", n_envs=1, seed=0))
    model = TRPOPlus(
        "MlpPolicy",
        env,
        n_steps=64,
        batch_size=64,
        replay_memory=2,
        cg_warm_start=True,
        policy_kwargs=dict(net_arch=[16]),
        seed=0,
        device="cpu",
    )
    model.learn(192)
    model.save(folder / "model.zip")
    save_vec_normalize(env, folder / "vecnormalize.pkl")
    manifest = {
        "version": sb3_trpo_plus.__version__,
        "env_id": "Pendulum-v1",
        "num_timesteps": model.num_timesteps,
        "n_updates": model._n_updates,
        "replay_rollouts": len(model.rollout_memory or ()),
        "parameters": {name: list(p.shape) for name, p in model.policy.state_dict().items()},
    }
    (folder / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    env.close()
    print(f"wrote {folder}")


if __name__ == "__main__":
    main()
