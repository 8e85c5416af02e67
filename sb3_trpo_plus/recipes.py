"""The rl-zoo YAML recipes in Python: the model that ``trpo-plus train --env ID --algo ALGO`` would train.

>>> from sb3_trpo_plus import make_model
>>> model = make_model("Grasper3D-v7", seed=0)       # TRPOPlus, 10 envs, VecNormalize, scripted training starts
>>> model.learn(2_000_000)                           # doctest: +SKIP
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from sb3_trpo_plus.zoo import ALGO_FILES, ZOO_DIR, HyperparameterError, algorithms, load_hyperparameters

if TYPE_CHECKING:
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm

# keys of a recipe that describe the environment or the run, not the algorithm's constructor
_RUN_KEYS = ("n_timesteps", "n_envs", "policy", "normalize", "normalize_kwargs", "env_wrapper", "vec_env_wrapper",
             "callback", "frame_stack", "monitor_kwargs", "env_kwargs")  # fmt: skip


def recipe(env_id: str, algo: str = "trpo_plus") -> dict[str, Any]:
    """The validated hyperparameters of ``env_id`` in ``zoo_hyperparams/<algo>.yml``."""
    if algo not in ALGO_FILES:
        raise ValueError(f"algo must be one of {sorted(ALGO_FILES)}, got {algo!r}")
    recipes = load_hyperparameters(ZOO_DIR / ALGO_FILES[algo], algo)
    if env_id not in recipes:
        raise HyperparameterError(f"{ZOO_DIR / ALGO_FILES[algo]} has no recipe for {env_id!r} (it has {sorted(recipes)})")
    return recipes[env_id]


def make_model(env_id: str, algo: str = "trpo_plus", seed: int | None = None, **overrides: Any) -> OnPolicyAlgorithm:
    """The model of ``env_id``'s recipe, as rl-zoo3 builds it: ``n_envs`` seeded envs (``DummyVecEnv``) with the
    recipe's ``env_kwargs`` and ``env_wrapper`` (training aids included: these are training envs), Monitor with the
    success flag, ``VecNormalize`` with the recipe's discount where it normalises, and the algorithm with the
    recipe's hyperparameters, each of which ``overrides`` may replace (e.g. ``tensorboard_log="runs"``).
    Train for the recipe's budget with ``model.learn(recipe(env_id, algo)["n_timesteps"])``."""
    from rl_zoo3.utils import get_wrapper_class
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecFrameStack, VecNormalize

    params = dict(recipe(env_id, algo))
    env = make_vec_env(
        env_id,
        n_envs=int(params.get("n_envs", 1)),
        seed=seed,
        env_kwargs=params.get("env_kwargs"),
        wrapper_class=get_wrapper_class({"env_wrapper": params.get("env_wrapper")}),
        monitor_kwargs=params.get("monitor_kwargs"),
    )
    vec_wrapper = get_wrapper_class({"vec_env_wrapper": params.get("vec_env_wrapper")}, "vec_env_wrapper")
    if vec_wrapper is not None:
        env = vec_wrapper(env)  # type: ignore[assignment, arg-type]
    normalize = params.get("normalize", False)
    if normalize:
        kwargs = dict(normalize) if isinstance(normalize, dict) else {}
        if "gamma" in params:
            kwargs.setdefault("gamma", params["gamma"])
        env = VecNormalize(env, **kwargs)
    if params.get("frame_stack"):
        env = VecFrameStack(env, int(params["frame_stack"]))
    constructor = {key: value for key, value in params.items() if key not in _RUN_KEYS}
    return algorithms()[algo](params["policy"], env, seed=seed, **{**constructor, **overrides})
