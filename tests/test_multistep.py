"""The multi-step probe (benchmarks/multistep.py): one step is TRPOPlus; more steps stay in the trust region."""

import pathlib
import sys
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3.common.distributions import kl_divergence
from stable_baselines3.common.env_util import make_vec_env

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm.natural_gradient import detached_distribution

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from multistep import MultiStepTRPOPlus  # benchmarks/multistep.py

TINY = dict(n_steps=64, batch_size=64, n_critic_updates=2, cg_max_steps=5, policy_kwargs=dict(net_arch=[16]))


def _make(cls: type, variant: dict, **kwargs: object) -> TRPOPlus:
    return cls("MlpPolicy", make_vec_env("Pendulum-v1", n_envs=2, seed=3), seed=3, **TINY, **variant, **kwargs)


@pytest.mark.parametrize("variant", [dict(), dict(cg_warm_start=True, replay_memory=2)])
def test_one_step_is_trpo_plus(variant: dict) -> None:
    plain = _make(TRPOPlus, variant).learn(4 * 128)
    one_step = _make(MultiStepTRPOPlus, variant, n_policy_steps=1).learn(4 * 128)
    a, b = plain.policy.state_dict(), one_step.policy.state_dict()
    for name in a:
        np.testing.assert_array_equal(b[name].numpy(), a[name].numpy(), err_msg=name)


def test_several_steps_stay_in_the_trust_region() -> None:
    model = _make(MultiStepTRPOPlus, dict(cg_warm_start=True), n_policy_steps=3)
    update = model.update_policy
    kls: list[float] = []
    steps: list[float] = []

    def measured(batch):  # type: ignore[no-untyped-def]
        before = detached_distribution(model.policy.get_distribution(batch.observations))
        result = update(batch)
        after = model.policy.get_distribution(batch.observations)
        kls.append(float(kl_divergence(after, before).mean().detach()))
        steps.append(model.logger.name_to_value["train/policy_steps"])
        assert result.line_search.kl == pytest.approx(kls[-1], rel=1e-5)  # the logged KL is the whole update's
        return result

    model.update_policy = measured  # type: ignore[method-assign]
    model.learn(6 * 128)
    assert len(kls) == 6
    assert max(kls) <= model.target_kl * (1 + 1e-6)
    assert max(steps) > 1  # the later steps are taken, not all rejected


@pytest.mark.parametrize("value", [0, -1, 1.5, True])
def test_bad_number_of_steps_is_named(value: object) -> None:
    with pytest.raises(ValueError, match="n_policy_steps"):
        _make(MultiStepTRPOPlus, dict(), n_policy_steps=value)


def test_save_load_keeps_the_number_of_steps(tmp_path: pathlib.Path) -> None:
    model = _make(MultiStepTRPOPlus, dict(), n_policy_steps=2).learn(128)
    model.save(tmp_path / "model")
    assert MultiStepTRPOPlus.load(tmp_path / "model.zip").n_policy_steps == 2
