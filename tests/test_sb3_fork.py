"""``collect_segment`` is a fork of SB3's ``OnPolicyAlgorithm.collect_rollouts``: on the installed SB3 both fill the
same rollout buffer and make the same callback calls with the same locals, and the SB3 source the fork follows is
pinned, so that an SB3 upgrade that changes the loop fails here first."""

from __future__ import annotations

import hashlib
import inspect
from typing import Any

import numpy as np
import pytest
import stable_baselines3
from sb3_contrib import TRPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecNormalize

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.algorithm import segment

KWARGS: dict[str, Any] = dict(n_steps=160, batch_size=64, n_critic_updates=1, policy_kwargs=dict(net_arch=[16]), seed=11)
BUFFER_FIELDS = ("observations", "actions", "rewards", "episode_starts", "values", "log_probs", "advantages", "returns")
LOCALS = ("new_obs", "rewards", "dones", "actions", "values", "log_probs", "n_steps")


class Recorder(BaseCallback):
    """Every callback call, in order, with copies of the step's SB3 locals."""

    def __init__(self) -> None:
        super().__init__()
        self.calls: list[tuple[str, dict[str, Any]]] = []

    def _on_rollout_start(self) -> None:
        self.calls.append(("rollout_start", {"num_timesteps": self.num_timesteps}))

    def _on_step(self) -> bool:
        step = {key: np.array(_numpy(self.locals[key])) for key in LOCALS}
        step["infos"] = [sorted(info) for info in self.locals["infos"]]
        step["terminal"] = [
            np.array(info["terminal_observation"]) for info in self.locals["infos"] if "terminal_observation" in info
        ]
        self.calls.append(("step", {"num_timesteps": self.num_timesteps, **step}))
        return True

    def _on_rollout_end(self) -> None:
        self.calls.append(("rollout_end", {"num_timesteps": self.num_timesteps}))


def _numpy(value: Any) -> Any:
    return value.detach().cpu().numpy() if hasattr(value, "detach") else value


def _collect(cls: type[OnPolicyAlgorithm], env_id: str, normalize: bool) -> tuple[OnPolicyAlgorithm, Recorder]:
    env = make_vec_env(env_id, n_envs=2, seed=5)
    if normalize:
        env = VecNormalize(env, gamma=0.99)
    model = cls("MlpPolicy", env, **KWARGS)
    recorder = Recorder()
    total, callback = model._setup_learn(10 * model.n_steps, recorder)
    callback.on_training_start(locals(), globals())
    assert model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=model.n_steps)
    assert model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=model.n_steps)
    return model, recorder


# Pendulum-v1: its 200-step time limit truncates inside the 2 x 160 steps (the bootstrap with the terminal value);
# CartPole-v1: terminations and a discrete action; VecNormalize: the normalised locals and terminal observations
@pytest.mark.parametrize(("env_id", "normalize"), [("Pendulum-v1", False), ("Pendulum-v1", True), ("CartPole-v1", True)])
def test_collect_segment_fills_what_sb3_collect_rollouts_fills(env_id: str, normalize: bool) -> None:
    sb3, sb3_calls = _collect(TRPO, env_id, normalize)  # sb3-contrib's TRPO collects with SB3's collect_rollouts
    ours, our_calls = _collect(TRPOPlus, env_id, normalize)
    assert type(sb3).collect_rollouts is OnPolicyAlgorithm.collect_rollouts
    for name in BUFFER_FIELDS:
        np.testing.assert_array_equal(getattr(ours.rollout_buffer, name), getattr(sb3.rollout_buffer, name), err_msg=name)
    assert [kind for kind, _ in our_calls.calls] == [kind for kind, _ in sb3_calls.calls]
    assert sum(kind == "step" for kind, _ in our_calls.calls) == 2 * KWARGS["n_steps"]
    for (kind, mine), (_, theirs) in zip(our_calls.calls, sb3_calls.calls, strict=True):
        assert mine.keys() == theirs.keys(), kind
        for key in mine:
            if key in ("infos", "terminal"):
                assert len(mine[key]) == len(theirs[key]), key
                for a, b in zip(mine[key], theirs[key], strict=True):
                    np.testing.assert_array_equal(a, b, err_msg=key)
            else:
                np.testing.assert_array_equal(mine[key], theirs[key], err_msg=f"{kind} {key}")
    assert any(step.get("terminal") for kind, step in sb3_calls.calls if kind == "step"), "no episode ended: nothing checked"
    np.testing.assert_array_equal(ours._last_obs, sb3._last_obs)
    np.testing.assert_array_equal(ours._last_episode_starts, sb3._last_episode_starts)
    assert ours.num_timesteps == sb3.num_timesteps


def test_the_forked_source_is_the_one_collect_segment_follows() -> None:
    """``segment.FORKED_FROM`` names the SB3 version and function and the SHA-256 of its source; a new SB3 whose
    ``collect_rollouts`` differs fails here, saying what to re-read."""
    version, function, digest = segment.FORKED_FROM
    source = inspect.getsource(OnPolicyAlgorithm.collect_rollouts)
    assert function == "stable_baselines3.common.on_policy_algorithm.OnPolicyAlgorithm.collect_rollouts"
    assert hashlib.sha256(source.encode()).hexdigest() == digest, (
        f"SB3 {stable_baselines3.__version__}'s collect_rollouts differs from the {version} source that "
        "sb3_trpo_plus.algorithm.segment.collect_segment follows: compare the two loops, mend collect_segment, "
        "then update FORKED_FROM"
    )
