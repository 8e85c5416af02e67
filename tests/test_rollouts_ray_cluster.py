"""RayRollouts on a two-node Ray cluster (ray.cluster_utils.Cluster, both nodes on this machine)."""

from __future__ import annotations

import pytest
from test_rollouts import SMALL
from test_rollouts_ray import assert_loopback_only

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.rollouts import RayRollouts

ray = pytest.importorskip("ray")
cluster_utils = pytest.importorskip("ray.cluster_utils")

pytestmark = pytest.mark.xdist_group("ray")  # one Ray instance at a time on this machine

FAST_FAILURE_DETECTION = {"health_check_period_ms": 500, "health_check_failure_threshold": 4}


def test_workers_spread_over_two_nodes_and_training_survives_losing_one() -> None:
    cluster = cluster_utils.Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 2, "include_dashboard": False, "_system_config": FAST_FAILURE_DETECTION},
    )
    second = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    ray.init(address=cluster.address, log_to_driver=False)
    pool = None
    try:
        assert_loopback_only()
        pool = RayRollouts("Reacher2D-v1", num_workers=2, envs_per_worker=2, seed=0, max_restarts=1, placement_timeout=60)
        nodes = {worker["node"] for worker in pool.workers}
        assert len(nodes) == 2, "SPREAD scheduling puts one worker on each node"
        lost = next(i for i, worker in enumerate(pool.workers) if worker["node"] == second.node_id)
        model = TRPOPlus("MlpPolicy", pool, seed=0, **SMALL)
        model.learn(SMALL["n_steps"] * pool.num_envs)
        cluster.remove_node(second)
        model.learn(SMALL["n_steps"] * pool.num_envs, reset_num_timesteps=False)
        assert pool.restarts[lost] == 1 and sum(pool.restarts) == 1
        assert pool.workers[lost]["node"] != second.node_id
        assert model.num_timesteps == 2 * SMALL["n_steps"] * pool.num_envs
    finally:
        if pool is not None:
            pool.close()
        ray.shutdown()
        cluster.shutdown()
