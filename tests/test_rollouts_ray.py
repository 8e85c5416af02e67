"""RayRollouts on a local Ray instance of 2 CPUs: the same training as in-process workers, restarts, errors."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch as th
from test_rollouts import (
    check_crash_beyond_restarts,
    check_kill_beyond_restarts,
    check_restart_after_a_crash,
    check_restart_after_a_kill,
    parameters,
    train,
)

from sb3_trpo_plus import TRPOPlus
from sb3_trpo_plus.rollouts import InProcessRollouts, RayRollouts, RolloutWorkerError

ray = pytest.importorskip("ray")  # the `ray` extra; CI installs it

pytestmark = pytest.mark.xdist_group("ray")  # one Ray instance at a time on this machine
RAY_DEATH = r"(RayActorError|ActorDiedError): .+"  # how Ray reports an actor whose process died


HOME_TOKEN = Path.home() / ".ray" / "auth_token"


def _home_token_state() -> tuple[bool, float | None]:
    return HOME_TOKEN.exists(), HOME_TOKEN.stat().st_mtime if HOME_TOKEN.exists() else None


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    # Ray's processes inherit this environment: its workers import crashing_env from tests/
    tests = os.path.dirname(os.path.abspath(__file__))
    saved = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [tests, saved]))
    home_token = _home_token_state()
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        yield home_token
    finally:
        ray.shutdown()
        if saved is None:
            del os.environ["PYTHONPATH"]
        else:
            os.environ["PYTHONPATH"] = saved


def assert_loopback_only() -> None:
    """Every node of the connected Ray, and its GCS, listen on 127.0.0.1."""
    assert ray.get_runtime_context().gcs_address.rpartition(":")[0] == "127.0.0.1"
    nodes = [node for node in ray.nodes() if node["Alive"]]
    assert nodes and all(node["NodeManagerAddress"] == "127.0.0.1" for node in nodes), nodes


def test_the_suites_local_ray_listens_on_loopback_only_with_a_token_outside_the_home_directory(local_ray) -> None:
    assert_loopback_only()
    token = Path(os.environ["RAY_AUTH_TOKEN_PATH"])
    assert token.is_file() and Path.home() / ".ray" not in token.parents
    assert _home_token_state() == local_ray, "starting Ray wrote ~/.ray/auth_token"


@pytest.mark.parametrize("num_workers", [1, 2])
def test_ray_workers_train_the_in_process_workers_parameters(num_workers: int) -> None:
    """Bit-equal on CPU: rollouts, VecNormalize statistics, replay memory and weights, for the same partition."""
    results = []
    for pool_class in (InProcessRollouts, RayRollouts):
        pool = pool_class("Reacher2D-v1", num_workers=num_workers, envs_per_worker=4 // num_workers, seed=5)
        try:
            model, env = train(pool, replay_memory=2)
            results.append((parameters(model), env.obs_rms.var.copy(), model.rollout_buffer.returns.copy()))
        finally:
            pool.close()
    (a, b) = results
    assert th.equal(a[0], b[0])
    assert (a[1] == b[1]).all() and (a[2] == b[2]).all()


def test_a_ray_worker_that_dies_mid_segment_is_restarted(tmp_path) -> None:
    check_restart_after_a_crash(RayRollouts, tmp_path)


def test_a_dead_ray_worker_beyond_its_restarts_names_itself_and_leaves_the_weights(tmp_path) -> None:
    check_crash_beyond_restarts(RayRollouts, tmp_path, RAY_DEATH)


def test_a_killed_batched_engine_ray_worker_beyond_its_restarts_names_itself_and_leaves_the_weights() -> None:
    check_kill_beyond_restarts(
        RayRollouts("Grasper3D-v7", num_workers=2, envs_per_worker=2, seed=0, max_restarts=0), RAY_DEATH
    )


def test_a_ray_worker_killed_by_a_signal_is_restarted() -> None:
    check_restart_after_a_kill(RayRollouts("Grasper3D-v7", num_workers=1, envs_per_worker=2, seed=0, max_restarts=2), 1.0)


def test_an_error_inside_a_ray_worker_surfaces_with_its_traceback() -> None:
    with pytest.raises(RolloutWorkerError, match=r"(?s)RayRollouts worker 0 .*no_such_option"):
        RayRollouts("Grasper3D-v7", num_workers=1, envs_per_worker=1, env_kwargs={"no_such_option": 1})


def test_a_worker_that_cannot_be_placed_is_named() -> None:
    with pytest.raises(RolloutWorkerError, match=r"RayRollouts worker 0 .*not placed within 1 s"):
        RayRollouts("Reacher2D-v1", num_workers=1, envs_per_worker=1, cpus_per_worker=8, placement_timeout=1)


def test_the_train_command_collects_with_ray_workers(tmp_path, monkeypatch) -> None:
    from sb3_trpo_plus.application import cli

    monkeypatch.chdir(tmp_path)
    cli.main(
        [
            "train",
            "--env",
            "Reacher2D-v1",
            "-n",
            "256",
            "--seed",
            "1",
            "-f",
            str(tmp_path),
            "--eval-freq",
            "-1",
            "--workers",
            "ray:2",
            "-params",
            "n_envs:2",
            "n_steps:64",
            "batch_size:64",
            "--num-threads",
            "1",
        ]
    )
    run = tmp_path / "trpo_plus" / "Reacher2D-v1_1"
    assert TRPOPlus.load(run / "Reacher2D-v1.zip").num_timesteps == 256
    assert (run / "workers.monitor.csv").read_text().count("\n") > 2
