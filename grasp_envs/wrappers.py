"""Training aids: wrappers for training envs only, never for evaluation (they change the start-state distribution)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from grasp_envs.grasper3d import Grasper3DEnv
from grasp_envs.scripted import grasper3d_policy

# Wrappers that pass the Grasper's observations through unchanged, so ScriptedStarts may lie outside them, by name:
# rl-zoo3 replaces gymnasium.wrappers.TimeLimit by its own subclass when imported (so the class bound to that name
# depends on the import order), and importing stable_baselines3 here would import torch with every env.
OBSERVATION_PRESERVING_WRAPPERS = (
    "gymnasium.wrappers.common.TimeLimit",
    "gymnasium.wrappers.common.OrderEnforcing",
    "gymnasium.wrappers.common.PassiveEnvChecker",
    "gymnasium.wrappers.common.RecordEpisodeStatistics",
    "rl_zoo3.gym_patches.PatchedTimeLimit",  # TimeLimit that also sets info["TimeLimit.truncated"]
    "stable_baselines3.common.monitor.Monitor",
)
# wrapper bases whose reset and step hand the observation on as it came
_PASS_THROUGH_BASES = (gym.Wrapper, gym.ActionWrapper, gym.RewardWrapper)


def changes_observations(wrapper: gym.Wrapper[Any, Any, Any, Any]) -> bool:
    """Whether ``wrapper`` may return other observations than the env it wraps: an ``ObservationWrapper``, a wrapper
    with another observation space, or one whose own ``reset`` or ``step`` is not a known pass-through."""
    if isinstance(wrapper, gym.ObservationWrapper):
        return True
    kind = type(wrapper)
    if f"{kind.__module__}.{kind.__qualname__}" in OBSERVATION_PRESERVING_WRAPPERS:
        return False
    if wrapper.observation_space != wrapper.env.observation_space:
        return True
    return any(
        getattr(kind, method) not in [getattr(base, method) for base in _PASS_THROUGH_BASES] for method in ("reset", "step")
    )


class ScriptedStarts(
    gym.Wrapper[NDArray[np.float64], NDArray[np.float32], NDArray[np.float64], NDArray[np.float32]],
    gym.utils.RecordConstructorArgs,
):
    """Start a share of the Grasper's episodes somewhere along the scripted grasp (Popov et al. 2017).

    After each reset, with probability ``probability`` the scripted controller (``grasp_envs.scripted``) drives the
    arm for a uniform number of steps in ``[steps[0], steps[1])``, and the episode starts from there: the policy sees
    grasps and lifts long before its own exploration finds them. The scripted controller first has both claw halves
    on the cube after 24-59 steps from the ready pose (``Grasper3D-v7``, seeds 0-19) and after 53-100 from the
    thesis' stretched pose (``Grasper3D-v6``; one of the 20 not within 100 steps), so ``steps=(50, 100)`` ("late"
    starts) begins most of those episodes with the cube grasped or lifted (``Grasper3D-v7``, seeds 0-19: 18 grasped,
    17 of them lifted; ``Grasper3D-v6``: 12 grasped, 8 lifted). These steps are not part of the episode (no reward,
    no time-limit step, nothing seen by the wrappers inside). ``hold_height``: the scripted grasp holds the cube with
    its bottom that high (m) instead of raising it until the arm runs out of reach.

    The episode's first observation is then the Grasper's own (``_get_obs``), and its info the inner reset's with
    ``is_success`` and ``unstable`` of the new state: so every wrapper between this one and the Grasper must leave
    observations unchanged (Gymnasium's ``TimeLimit``, ``OrderEnforcing``, ``PassiveEnvChecker``,
    ``RecordEpisodeStatistics``, rl-zoo3's ``TimeLimit``, SB3's ``Monitor``, action and reward wrappers); any other
    raises ``TypeError``: apply it outside ``ScriptedStarts``.

    If a scripted step makes the simulation unstable (MuJoCo resets a diverging state), the episode starts instead
    from a fresh draw of the task's start state (the Grasper's ``reset_model``, its generator going on from where the
    scripted start left it; ``info["unstable"]`` is ``False``), with no scripted steps after it.

    Random numbers come from the env's own generator, and only when ``probability > 0``, so a seeded reset is
    reproducible. Wrap training envs only (in rl-zoo YAML: ``env_wrapper``; the ``trpo-plus`` command leaves
    ``training_only`` wrappers out of its evaluation and enjoy envs). The arguments are recorded
    (``env.spec.additional_wrappers``).

    :param env: a Grasper3D env (``gymnasium.make("Grasper3D-v7")``), with or without the wrappers above
    :param probability: share of resets that start along the scripted grasp, in [0, 1]
    :param steps: ``(low, high)``: the number of scripted steps is uniform in ``[low, high)``, ``0 <= low < high``
    :param hold_height: ``None``, or the height (m, > 0) of the cube's bottom at which the scripted grasp holds it
    """

    training_only = True

    def __init__(
        self,
        env: gym.Env[NDArray[np.float64], NDArray[np.float32]],
        probability: float = 0.25,
        steps: Sequence[int] = (0, 100),
        hold_height: float | None = None,
    ):
        super().__init__(env)
        if not isinstance(env.unwrapped, Grasper3DEnv):
            raise TypeError(f"ScriptedStarts wraps a Grasper3D env, got {type(env.unwrapped).__name__}")
        inner: gym.Env[Any, Any] = env
        while isinstance(inner, gym.Wrapper):
            if changes_observations(inner):
                raise TypeError(
                    f"ScriptedStarts returns the Grasper's own observation after a scripted start, so the wrappers "
                    f"inside it must leave observations unchanged; {type(inner).__name__} may change them: apply it "
                    f"outside ScriptedStarts"
                )
            inner = inner.env
        checked = self.check_arguments(probability, steps, hold_height)
        self.probability, self.steps, self.hold_height = checked["probability"], checked["steps"], checked["hold_height"]
        gym.utils.RecordConstructorArgs.__init__(
            self, probability=self.probability, steps=self.steps, hold_height=self.hold_height
        )

    @staticmethod
    def check_arguments(
        probability: float = 0.25, steps: Sequence[int] = (0, 100), hold_height: float | None = None
    ) -> dict[str, Any]:
        """The arguments checked and normalised (``ValueError`` naming a bad one); the batched engine runs them too."""
        if isinstance(probability, bool) or not isinstance(probability, int | float) or not 0.0 <= probability <= 1.0:
            raise ValueError(f"ScriptedStarts probability must be a number in [0, 1], got {probability!r}")
        bounds = tuple(steps) if isinstance(steps, tuple | list) else ()
        if not (
            len(bounds) == 2
            and all(isinstance(n, int | np.integer) and not isinstance(n, bool) for n in bounds)
            and 0 <= bounds[0] < bounds[1]
        ):
            raise ValueError(f"ScriptedStarts steps must be (low, high) integers with 0 <= low < high, got {steps!r}")
        if hold_height is not None and (
            isinstance(hold_height, bool)
            or not isinstance(hold_height, int | float | np.integer | np.floating)
            or not hold_height > 0
        ):
            raise ValueError(f"ScriptedStarts hold_height must be None or a positive height (m), got {hold_height!r}")
        return {"probability": float(probability), "steps": (int(bounds[0]), int(bounds[1])), "hold_height": hold_height}

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float64], dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        grasper: Grasper3DEnv = self.env.unwrapped  # type: ignore[assignment]
        if self.probability > 0 and grasper.np_random.uniform() < self.probability:
            for _ in range(int(grasper.np_random.integers(*self.steps))):
                action = grasper3d_policy(grasper, hold_height=self.hold_height)
                if grasper._simulate(grasper._checked_action(action)):  # unstable: start from a fresh state instead
                    return grasper.reset_model(), {**info, **grasper._get_reset_info()}
            observation, info = grasper._get_obs(), {**info, **grasper._get_reset_info()}
        return observation, info
