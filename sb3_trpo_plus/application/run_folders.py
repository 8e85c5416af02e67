"""A trained run in rl-zoo3's layout (``<folder>/<algo>/<env>_<N>/``): where it is, and its agent and test env.

``trpo-plus enjoy``, ``record-video`` and ``main`` find runs here; :func:`load_trained` reads one through the
weights-only path of :mod:`sb3_trpo_plus.application.agents` (or SB3's unpickling, with ``trust_pickle``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sb3_trpo_plus.application.rl_zoo import model_path as find_model

# Shipped agents: the source checkout's folder; a wheel carries none, so then ./trained_agents (a clone or a download)
_CHECKOUT_AGENTS = Path(__file__).resolve().parents[2] / "trained_agents"
TRAINED_AGENTS = _CHECKOUT_AGENTS if _CHECKOUT_AGENTS.is_dir() else Path("trained_agents")


def default_folder(algo: str, env: str) -> str:
    """``logs`` when it holds a run of (algo, env), else the shipped ``trained_agents`` when that does."""
    for folder in (Path("logs"), TRAINED_AGENTS):
        if any((folder / algo).glob(f"{env}_[0-9]*")):
            return str(folder)
    return "logs"


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

    The weights-only path by default (:mod:`sb3_trpo_plus.application.agents`: nothing in the run is unpickled or evaluated);
    ``trust_pickle`` loads the full model with SB3. ``render`` makes the env render RGB frames.
    The env is seeded with ``seed`` (SB3's ``load(path, env=env)`` would reseed it with the model's training seed).
    """
    from sb3_trpo_plus.application.agents import load_eval_agent

    _, model_path, log_path = find_model(algo, env_id, folder, exp_id, load_best, load_checkpoint, load_last_checkpoint)
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
