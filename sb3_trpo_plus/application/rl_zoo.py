"""The one module that drives rl-zoo3: TRPOPlus in its tables, our checked recipes as its ``-conf``, its ``train``
with our experiment manager, its run lookup and its hub download for ``enjoy`` / ``record-video``.

Written against rl-zoo3 2.9.2 (:data:`WRITTEN_AGAINST`). rl-zoo3's extension points are used as such: its algorithm
and Optuna tables are dicts meant to be extended, ``-conf`` takes a module name, :class:`ExperimentManager` is
subclassed (:mod:`sb3_trpo_plus.application.experiment`) and ``get_model_path`` / ``download_from_hub`` are called.
Where rl-zoo3 offers none, :func:`train` replaces, for the length of one call, the attributes of :data:`REPLACED`:
``train()`` takes no arguments (it parses ``sys.argv``), builds the class its module names ``ExperimentManager`` and
parses with its module's ``argparse.ArgumentParser`` (whose errors are a usage block, not one line).
``tests/test_rl_zoo_adapter.py`` fails when rl-zoo3 changes any of them.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import types
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

WRITTEN_AGAINST = "2.9.2"
"""The rl-zoo3 version this adapter was written against."""

REPLACED = (("rl_zoo3.train", "ExperimentManager"), ("rl_zoo3.train", "argparse"), ("sys", "argv"))
"""What :func:`train` replaces for one call of ``rl_zoo3.train.train()``."""

TRAIN_SOURCE_SHA256 = "7138a19afaa9a80d1adc2bc2ce17a9ec4bd8c933aa6d1a83ddc837d288096171"
"""SHA-256 of the source of rl-zoo3 2.9.2's ``rl_zoo3.train.train``, which reads what :data:`REPLACED` holds."""


def register() -> None:
    """Add TRPOPlus to rl-zoo3's algorithm and Optuna-sampler tables (idempotent)."""
    from rl_zoo3 import utils as zoo_utils
    from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER

    from sb3_trpo_plus.algorithm.trpo_plus import TRPOPlus

    zoo_utils.ALGOS["trpo_plus"] = TRPOPlus
    HYPERPARAMS_SAMPLER["trpo_plus"] = sample_trpo_plus_params
    if "trpo" in HYPERPARAMS_CONVERTER:
        HYPERPARAMS_CONVERTER["trpo_plus"] = HYPERPARAMS_CONVERTER["trpo"]


def sample_trpo_plus_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """Optuna sampler: rl-zoo3's TRPO search space plus TRPOPlus' own hyperparameters."""
    from rl_zoo3.hyperparams_opt import sample_trpo_params

    params = sample_trpo_params(trial, n_actions, n_envs, additional_args)
    params["replay_memory"] = trial.suggest_int("replay_memory", 0, 5)
    params["cg_warm_start"] = trial.suggest_categorical("cg_warm_start", [False, True])
    params["cg_damping"] = trial.suggest_float("cg_damping", 0.01, 0.5, log=True)
    params["value_baseline"] = trial.suggest_categorical("value_baseline", ["critic", "linear"])
    return params


def config_module(algo: str, path: str | Path | None = None) -> str:
    """Validate our YAML for ``algo`` (for ``trpo_plus`` its values too:
    :func:`~sb3_trpo_plus.application.zoo.check_constructor_values`) and expose it to rl-zoo3 as an importable
    module; return its name. rl-zoo3's ``-conf`` accepts a module with a ``hyperparams`` attribute: no file is
    written and rl-zoo3 uses exactly the validated values."""
    from sb3_trpo_plus.application.zoo import ALGO_FILES, ZOO_DIR, check_constructor_values, load_hyperparameters

    path = Path(path) if path is not None else ZOO_DIR / ALGO_FILES[algo]
    hyperparams = load_hyperparameters(path, algo)
    if algo == "trpo_plus":
        for env_id, entry in hyperparams.items():
            check_constructor_values(entry, f"{path}: {env_id}")
    name = f"_sb3_trpo_plus_hyperparams_{algo}"
    module = types.ModuleType(name)
    vars(module)["hyperparams"] = hyperparams
    sys.modules[name] = module
    return name


def train(argv: Sequence[str], manager: type, prog: str = "trpo-plus train") -> None:
    """rl-zoo3's ``train()`` with the flags ``argv`` and the experiment manager class ``manager``; a flag rl-zoo3
    does not know, or a bad value of one, stops it with one line (``<prog>: error: ...``)."""
    import rl_zoo3.train as zoo_train

    command_line = [sys.argv[0] if sys.argv else prog, *argv]
    with (
        _replaced(sys, "argv", command_line),
        _replaced(zoo_train, "ExperimentManager", manager),
        _replaced(zoo_train, "argparse", _one_line_argparse(prog)),
    ):
        zoo_train.train()


def import_zoo_envs() -> None:
    """Register the envs rl-zoo3 registers (its ``train`` and ``enjoy`` import them too)."""
    import rl_zoo3.import_envs  # noqa: F401


def model_path(
    algo: str, env_id: str, folder: str, exp_id: int, load_best: bool, load_checkpoint: str | None, load_last: bool
) -> tuple[str, str, str]:
    """rl-zoo3's ``get_model_path``: (name prefix, model file, run folder). As rl-zoo3's enjoy, a run not found under
    a folder named ``rl-trained-agents`` is downloaded from the SB3 organisation on the Hugging Face hub first."""
    from huggingface_sb3 import EnvironmentName
    from rl_zoo3.utils import get_model_path

    env_name = EnvironmentName(env_id)
    arguments = (exp_id, folder, algo, env_name, load_best, load_checkpoint, load_last)
    try:
        return _locate(get_model_path, *arguments)
    except RunNotFoundError:
        if "rl-trained-agents" not in folder:
            raise
    print("Pretrained model not found, trying to download it from sb3 Huggingface hub: https://huggingface.co/sb3")
    download_run(algo, env_name, exp_id, folder)
    return _locate(get_model_path, *arguments)


class RunNotFoundError(FileNotFoundError):
    """No run, or no model file in it, where the command line points (``-f``, ``--algo``, ``--env``, ``--exp-id``)."""


def _locate(
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


def download_run(algo: str, env_name: Any, exp_id: int, folder: str) -> None:
    """rl-zoo3's ``download_from_hub`` of the SB3 organisation's run of ``algo`` on ``env_name`` into ``folder``."""
    from rl_zoo3.load_from_hub import download_from_hub

    download_from_hub(algo=algo, env_name=env_name, exp_id=exp_id, folder=folder, organization="sb3", repo_name=None)


@contextlib.contextmanager
def _replaced(owner: Any, name: str, value: Any) -> Iterator[None]:
    saved = getattr(owner, name)
    setattr(owner, name, value)
    try:
        yield
    finally:
        setattr(owner, name, saved)


def _one_line_argparse(prog: str) -> types.ModuleType:
    """``argparse`` whose ``ArgumentParser`` is named ``prog`` and says what is wrong in one line
    (:class:`~sb3_trpo_plus.common.arguments.CommandLineParser`)."""
    from sb3_trpo_plus.common.arguments import CommandLineParser

    class ZooParser(CommandLineParser):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            kwargs.setdefault("prog", prog)
            super().__init__(*args, **kwargs)

        def parse_known_args(self, *args: Any, **kwargs: Any) -> Any:
            try:
                return super().parse_known_args(*args, **kwargs)
            except (NameError, SyntaxError) as error:  # rl-zoo3 evaluates the VALUE of KEY:VALUE flags as Python
                self.error(
                    f"the VALUE of each KEY:VALUE (-params/--hyperparams, --env-kwargs) is Python, {error} (a string "
                    "is quoted: KEY:\"'text'\")"
                )

    module = types.ModuleType(argparse.__name__)
    vars(module).update(vars(argparse))
    vars(module)["ArgumentParser"] = ZooParser
    return module
