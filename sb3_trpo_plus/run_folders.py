"""A trained run in rl-zoo3's layout (``<folder>/<algo>/<env>_<N>/``): where it is, and its agent and test env.

``trpo-plus enjoy``, ``record-video`` and ``main`` find runs here; :func:`load_trained` reads one through the
weights-only path of :mod:`sb3_trpo_plus.agents`; :func:`validated_run_folders` guards rl-zoo3's own ``enjoy``
(``--trust-pickle``).
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

# Shipped agents: the source checkout's folder; a wheel carries none, so then ./trained_agents (a clone or a download)
_CHECKOUT_AGENTS = Path(__file__).resolve().parents[1] / "trained_agents"
TRAINED_AGENTS = _CHECKOUT_AGENTS if _CHECKOUT_AGENTS.is_dir() else Path("trained_agents")


def default_folder(algo: str, env: str) -> str:
    """``logs`` when it holds a run of (algo, env), else the shipped ``trained_agents`` when that does."""
    for folder in (Path("logs"), TRAINED_AGENTS):
        if any((folder / algo).glob(f"{env}_[0-9]*")):
            return str(folder)
    return "logs"


@contextlib.contextmanager
def validated_run_folders(env_id: str) -> Iterator[None]:
    """While open, each run folder rl-zoo3's enjoy picks (``get_model_path``: a local run, or one it has just
    downloaded from the Hugging Face hub) is checked by :func:`sb3_trpo_plus.agents.validate_run_files` before
    rl-zoo3 reads its ``config.yml`` / ``args.yml`` with ``yaml.UnsafeLoader`` and evaluates ``normalize``; a damaged
    ``vecnormalize.pkl`` raises :class:`~sb3_trpo_plus.agents.RunFileError` naming it; the test env gets the run's
    ``env_wrapper`` without its training aids (:func:`sb3_trpo_plus.zoo.evaluation_wrappers`). rl-zoo3's ``enjoy``
    has no hooks for these: its module's names are replaced for the call and restored after it."""
    import rl_zoo3.enjoy as enjoy_module
    import rl_zoo3.utils as zoo_utils
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_trpo_plus.agents import load_trusted_file, validate_run_files
    from sb3_trpo_plus.zoo import evaluation_wrappers

    original = enjoy_module.get_model_path

    @functools.wraps(original)
    def get_model_path(exp_id: int, folder: str, *args: Any, **kwargs: Any) -> tuple[str, str, str]:
        if "rl-trained-agents" in folder:  # rl-zoo3 downloads a run it does not find there
            name_prefix, model_path, log_path = original(exp_id, folder, *args, **kwargs)
        else:
            name_prefix, model_path, log_path = locate_model(original, exp_id, folder, *args, **kwargs)
        validate_run_files(log_path, env_id)
        return name_prefix, model_path, log_path

    class NamingVecNormalize(VecNormalize):
        """What rl-zoo3's ``create_test_env`` calls to unpickle the run's statistics."""

        @staticmethod
        def load(load_path: str, venv: Any) -> VecNormalize:
            return load_trusted_file(lambda: VecNormalize.load(load_path, venv), Path(load_path))

    create_test_env = enjoy_module.create_test_env

    @functools.wraps(create_test_env)
    def evaluation_test_env(*args: Any, **kwargs: Any) -> Any:
        hyperparams = kwargs.get("hyperparams")
        if hyperparams is not None and "env_wrapper" in hyperparams:
            kwargs["hyperparams"] = {**hyperparams, "env_wrapper": evaluation_wrappers(hyperparams["env_wrapper"])}
        return create_test_env(*args, **kwargs)

    enjoy_module.get_model_path = get_model_path
    enjoy_module.create_test_env = evaluation_test_env
    zoo_utils.VecNormalize = NamingVecNormalize  # type: ignore[misc]
    try:
        yield
    finally:
        enjoy_module.get_model_path = original
        enjoy_module.create_test_env = create_test_env
        zoo_utils.VecNormalize = VecNormalize  # type: ignore[misc]


def load_trained(
    algo: str,
    env_id: str,
    folder: str,
    exp_id: int,
    load_best: bool,
    seed: int,
    render: bool,
    *,
    trust_pickle: bool = False,
    n_envs: int = 1,
    render_mode: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    load_checkpoint: str | None = None,
    load_last_checkpoint: bool = False,
    norm_reward: bool = False,
    device: str = "cpu",
) -> tuple[Any, Any, str]:
    """Agent and test env of an rl-zoo3 run (VecNormalize statistics and env kwargs restored), and the run folder.

    The weights-only path by default (:mod:`sb3_trpo_plus.agents`: nothing in the run is unpickled or evaluated);
    ``trust_pickle`` loads the full model with SB3. ``render`` makes the env render RGB frames.
    The env is seeded with ``seed`` (SB3's ``load(path, env=env)`` would reseed it with the model's training seed).
    """
    from huggingface_sb3 import EnvironmentName
    from rl_zoo3.utils import get_model_path

    from sb3_trpo_plus.agents import load_eval_agent

    env_name = EnvironmentName(env_id)
    _, model_path, log_path = locate_model(
        get_model_path, exp_id, folder, algo, env_name, load_best, load_checkpoint, load_last_checkpoint
    )
    agent, env = load_eval_agent(
        log_path,
        env_id,
        model_path=model_path,
        trust_pickle=trust_pickle,
        seed=seed,
        n_envs=n_envs,
        render_mode="rgb_array" if render else render_mode,
        env_kwargs=env_kwargs,
        norm_reward=norm_reward,
        device=device,
    )
    return agent, env, log_path


class RunNotFoundError(FileNotFoundError):
    """No run, or no model file in it, where the command line points (``-f``, ``--algo``, ``--env``, ``--exp-id``)."""


def locate_model(
    get_model_path: Callable[..., tuple[str, str, str]],
    exp_id: int,
    folder: str,
    algo: str,
    env_name: Any,
    load_best: bool = False,
    load_checkpoint: str | None = None,
    load_last_checkpoint: bool = False,
) -> tuple[str, str, str]:
    """rl-zoo3's ``get_model_path`` (name prefix, model file, run folder), a missing run folder or model file raised
    as :class:`RunNotFoundError` naming it (rl-zoo3 asserts, and takes ``<folder>/<algo>`` for the run when it holds
    none)."""
    from rl_zoo3.utils import get_latest_run_id

    algo_folder = os.path.join(folder, algo)
    if not os.path.isdir(algo_folder):
        raise RunNotFoundError(f"no run of {env_name} for --algo {algo} in {folder}: {algo_folder} is no folder")
    if exp_id == 0 and get_latest_run_id(algo_folder, env_name) == 0:
        raise RunNotFoundError(f"no run of {env_name} in {algo_folder} (<env>_<N> folders)")
    if exp_id > 0 and not os.path.isdir(os.path.join(algo_folder, f"{env_name}_{exp_id}")):
        raise RunNotFoundError(f"--exp-id {exp_id}: no run folder {os.path.join(algo_folder, f'{env_name}_{exp_id}')}")
    try:
        return get_model_path(exp_id, folder, algo, env_name, load_best, load_checkpoint, load_last_checkpoint)
    except (AssertionError, ValueError) as error:  # rl-zoo3's words for a missing run folder or model file
        raise RunNotFoundError(str(error)) from None
