"""With its extensions off, one TRPOPlus update is sb3-contrib's TRPO update.

Both models start from the same seed, so they build the same weights, collect the same rollout
(same env seeds, same torch draws for the actions) and run one ``train()`` on it.
"""

import sys
from pathlib import Path

import numpy as np
import pytest
import sb3_contrib.trpo.trpo as sb3_contrib_trpo
from sb3_contrib import TRPO
from stable_baselines3.common.env_util import make_vec_env

from sb3_trpo_plus import TRPOPlus

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/ is a package beside the installed ones
from benchmarks.builders import zero_start_solver  # sb3-contrib's CG started at 0

KWARGS = dict(n_steps=128, batch_size=64, n_critic_updates=3, policy_kwargs=dict(net_arch=[32, 32]), seed=3)


def _flat(model) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy().astype(np.float64) for k, v in model.policy.state_dict().items()}


def _train_once(cls, env_id: str, log_std_init: float = 0.0) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], object]:
    kwargs = {**KWARGS, "policy_kwargs": {**KWARGS["policy_kwargs"], "log_std_init": log_std_init}}  # type: ignore[dict-item]
    model = cls("MlpPolicy", make_vec_env(env_id, n_envs=2, seed=7), **kwargs)
    initial = _flat(model)
    model.learn(total_timesteps=model.n_steps * 2)  # one collect_rollouts + one train()
    return initial, _flat(model), model


# log_std_init -1.5 (std 0.22): the analytic Fisher's 1/std² terms, which a policy at std 1 cannot check
@pytest.mark.parametrize(
    ("env_id", "log_std_init"), [("Pendulum-v1", 0.0), ("CartPole-v1", 0.0), ("Reacher3D-v0", 0.0), ("Reacher3D-v0", -1.5)]
)
def test_update_matches_sb3_contrib_trpo_exactly_with_the_same_cg_start(env_id: str, log_std_init: float, monkeypatch) -> None:
    monkeypatch.setattr(sb3_contrib_trpo, "conjugate_gradient_solver", zero_start_solver)
    initial, trpo, trpo_model = _train_once(TRPO, env_id, log_std_init)
    initial_plus, plus, plus_model = _train_once(TRPOPlus, env_id, log_std_init)
    np.testing.assert_array_equal(trpo_model.rollout_buffer.observations, plus_model.rollout_buffer.observations)
    for name in trpo:
        np.testing.assert_array_equal(initial[name], initial_plus[name])
        step_trpo, step_plus = trpo[name] - initial[name], plus[name] - initial[name]
        scale = max(float(np.abs(step_trpo).max()), 1e-12)
        # the *update* agrees to 1e-4 of its own size, element by element (plus float32 rounding of the weight);
        # at std 0.22 the Fisher is worse conditioned and float32 CG rounding reaches 1.2e-4 (whole update: 2e-5
        # relative), so 1e-3 there; a wrong power of std in the analytic Fisher would differ by O(1)
        tolerance = 1e-4 if log_std_init == 0.0 else 1e-3
        rounding = 4 * np.finfo(np.float32).eps * np.abs(trpo[name])
        np.testing.assert_array_less(np.abs(step_plus - step_trpo), tolerance * scale + rounding + 1e-12, err_msg=name)
    moved = max(float(np.abs(trpo[n] - initial[n]).max()) for n in trpo)
    assert moved > 1e-4, "the update must move the parameters, or the comparison proves nothing"


@pytest.mark.parametrize("env_id", ["Pendulum-v1", "CartPole-v1", "Reacher3D-v0"])
def test_parameters_match_unmodified_sb3_contrib_trpo(env_id: str) -> None:
    _, trpo, _ = _train_once(TRPO, env_id)
    _, plus, _ = _train_once(TRPOPlus, env_id)
    # sb3-contrib starts CG at 1e-4 * randn: compare the whole parameter vector, relatively
    a = np.concatenate([trpo[n].ravel() for n in trpo])
    b = np.concatenate([plus[n].ravel() for n in trpo])
    relative = np.linalg.norm(b - a) / np.linalg.norm(a)
    assert relative < 1e-4, f"relative difference {relative:.2e}"
