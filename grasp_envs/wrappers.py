"""Training aids, for training envs only, never for evaluation (they change the start-state distribution).

The scripted starts: ``scripted_starts`` starts simulations along the scripted grasp, with ``ScriptedStartOptions``;
the ``ScriptedStarts`` wrapper runs it on a Gymnasium env, and the batched engine (``grasp_envs.make_batch_env``) on
its simulations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from grasp_envs.base import Physics, info_of
from grasp_envs.grasper3d import Grasper3DEnv, Grasper3DTask
from grasp_envs.options import Options, Rule, amount, is_int, is_number, option
from grasp_envs.scripted import grasper3d_actions

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


def _is_step_range(steps: Any) -> bool:
    return isinstance(steps, tuple | list) and len(steps) == 2 and all(map(is_int, steps)) and 0 <= steps[0] < steps[1]


@dataclass(frozen=True)
class ScriptedStartOptions(Options):
    """The scripted starts' options (``ScriptedStarts``' arguments), each checked when they are made; ``steps`` is
    kept as a tuple of two ``int`` and ``probability`` as a ``float``."""

    probability: float = option(0.25, Rule(lambda p: is_number(p) and 0.0 <= p <= 1.0, "a number in [0, 1]"))
    steps: Sequence[int] = option((0, 100), Rule(_is_step_range, "(low, high) integers with 0 <= low < high"))
    hold_height: float | None = option(None, amount(positive=True, optional=True))

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "probability", float(self.probability))
        object.__setattr__(self, "steps", (int(self.steps[0]), int(self.steps[1])))


def scripted_starts(
    physics: Physics, ids: NDArray[np.int64], rngs: Sequence[np.random.Generator], options: ScriptedStartOptions
) -> NDArray[np.bool_]:
    """Start each of the just-reset Grasper simulations ``ids`` somewhere along the scripted grasp, with probability
    ``options.probability``; return which did.

    Each simulation draws from its own generator (``rngs``, one per id): whether it starts along the grasp, then
    the number of scripted steps, uniform in ``[steps[0], steps[1])``. The chosen ones are stepped together with the
    scripted grasp's actions (``grasp_envs.scripted.grasper3d_actions``, holding the cube at ``hold_height``), each
    for its own number of steps; one that a scripted step made unstable starts instead from a fresh draw of the
    task's start state, with no scripted steps after it. With ``probability`` 0 nothing is drawn.
    """
    task = physics.task
    assert isinstance(task, Grasper3DTask), "scripted starts run the Grasper's scripted grasp"
    chosen = np.zeros(len(ids), dtype=bool)
    if options.probability == 0:
        return chosen
    remaining = np.zeros(physics.n, dtype=np.int64)
    low_steps, high_steps = options.steps
    for k, (i, rng) in enumerate(zip(ids, rngs, strict=True)):
        if rng.uniform() < options.probability:
            chosen[k] = True
            remaining[i] = rng.integers(low_steps, high_steps)
    generators = dict(zip(ids.tolist(), rngs, strict=True))
    low, high = physics.action_space.low, physics.action_space.high
    while (active := np.flatnonzero(remaining > 0)).size:
        every = active.size == physics.n  # then step the simulations' own arrays, not a copy of theirs
        sim = physics.sim if every else physics.sim.take(active)
        actions = grasper3d_actions(task, sim, low, high, hold_height=options.hold_height)
        unstable = physics.simulate(np.clip(actions.astype(np.float64), low, high), None if every else active, sim)
        remaining[active] -= 1
        if unstable.any():
            fresh = active[unstable]
            remaining[fresh] = 0
            physics.start(fresh, [generators[i] for i in fresh.tolist()])
    return chosen


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

    The episode's first observation is then the Grasper's own, and its info the inner reset's with
    ``is_success`` and ``unstable`` of the new state: so every wrapper between this one and the Grasper must leave
    observations unchanged (Gymnasium's ``TimeLimit``, ``OrderEnforcing``, ``PassiveEnvChecker``,
    ``RecordEpisodeStatistics``, rl-zoo3's ``TimeLimit``, SB3's ``Monitor``, action and reward wrappers); any other
    raises ``TypeError``: apply it outside ``ScriptedStarts``.

    If a scripted step makes the simulation unstable (MuJoCo resets a diverging state), the episode starts instead
    from a fresh draw of the task's start state (its generator going on from where the scripted start left it;
    ``info["unstable"]`` is ``False``), with no scripted steps after it. The batched engine runs the same scripted
    starts (``scripted_starts``) for its simulations: ``make_batch_env(..., wrapper_class=ScriptedStarts)``.

    Random numbers come from the env's own generator, and only when ``probability > 0``, so a seeded reset is
    reproducible. Wrap training envs only (in rl-zoo YAML: ``env_wrapper``; the ``trpo-plus`` command leaves
    ``training_only`` wrappers out of its evaluation and enjoy envs). The arguments are checked
    (``ScriptedStartOptions``: a bad value raises ``ValueError`` naming it) and recorded
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
        self.start_options = ScriptedStartOptions(probability, steps, hold_height)
        gym.utils.RecordConstructorArgs.__init__(self, **self.start_options.keywords())

    @property
    def probability(self) -> float:
        return self.start_options.probability

    @property
    def steps(self) -> tuple[int, ...]:
        return tuple(self.start_options.steps)

    @property
    def hold_height(self) -> float | None:
        return self.start_options.hold_height

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[NDArray[np.float64], dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        grasper: Grasper3DEnv = self.env.unwrapped  # type: ignore[assignment]
        if scripted_starts(grasper.physics, np.zeros(1, dtype=np.int64), [grasper.np_random], self.start_options)[0]:
            sim = grasper.physics.sim
            observation, info = grasper.task.observe(sim)[0], {**info, **info_of(grasper.task.reset_info(sim), 0)}
        return observation, info
