"""What every rollout pool, worker and worker-env argument accepts (checked before anything starts)."""

from __future__ import annotations

import multiprocessing as mp
import os

from sb3_trpo_plus.common.arguments import Rule, choice, integer, keywords, names, number, optional

POOL_ARGUMENT_RULES: dict[str, Rule] = {
    "env_id": Rule(lambda value: isinstance(value, str), "a registered Gymnasium id (str)"),
    "num_workers": integer(1),
    "envs_per_worker": integer(1),
    "seed": integer(0, optional=True),
    "sim_threads": integer(0),
    "env_kwargs": keywords("the env's options"),
    "scripted_starts": keywords("ScriptedStarts' options"),
    "info_keywords": names(optional=True),
    "monitor_file": optional(str | os.PathLike, "a file path (str or os.PathLike)"),
    "max_restarts": integer(0),
    # ProcessRollouts
    "start_method": choice(mp.get_all_start_methods(), optional=True),
    # RayRollouts
    "address": optional(str, "a Ray address (str)"),
    "cpus_per_worker": number(lambda x: x >= 0, ">= 0"),
    "placement_timeout": number(lambda x: x > 0, "> 0"),
}
"""Every constructor argument of the pools (:class:`RolloutWorkers` and its subclasses) and what it accepts."""

WORKER_ENVS_RULES: dict[str, Rule] = {
    "env_id": POOL_ARGUMENT_RULES["env_id"],
    "n_envs": integer(1),
    "sim_threads": POOL_ARGUMENT_RULES["sim_threads"],
    "env_kwargs": keywords("the env's options", optional=False),
    "scripted_starts": POOL_ARGUMENT_RULES["scripted_starts"],
    "info_keywords": names(),
}
"""Every field of :class:`WorkerEnvs` and what it accepts."""
