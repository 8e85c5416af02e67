"""The documented cluster path: ``ray start --head`` with token authentication, and drivers with and without its token.

The head runs as a subprocess in a process group of its own on loopback (the suite's settings, tests/conftest.py), and
the whole group is stopped at the end, also when a test fails: that cluster only, not every Ray on the machine as
``ray stop`` would.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

pytestmark = pytest.mark.xdist_group("ray")  # one Ray instance at a time on this machine

RAY = str(Path(sys.executable).with_name("ray"))
ONE_LINE = "RAY_AUTH_MODE=token"
# Ray's own driver retries a refused connection for about 20 s; the check answers within a second (RayRollouts is
# timed without the imports; the command's one line of stderr shows that no retry loop ran)
FAST = 12.0


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.fixture(scope="module")
def token_cluster() -> Iterator[str]:
    """The address of a one-node cluster started with ``ray start --head`` and ``RAY_AUTH_MODE=token``."""
    port = _free_port()
    temp_dir = tempfile.mkdtemp(prefix="rh")  # short: Ray's socket paths live under it
    command = [
        RAY,
        "start",
        "--head",
        "--block",
        f"--port={port}",
        "--num-cpus=2",
        "--include-dashboard=false",
        f"--ray-client-server-port={_free_port()}",
        f"--dashboard-port={_free_port()}",
        f"--temp-dir={temp_dir}",
        "--disable-usage-stats",
    ]
    log = open(Path(temp_dir) / "head.log", "w+")  # noqa: SIM115 - read while the head runs
    head = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 90
        while "Ray runtime started" not in Path(log.name).read_text():
            if head.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"ray start --head did not start:\n{Path(log.name).read_text()[-3000:]}")
            time.sleep(0.5)
        yield f"127.0.0.1:{port}"
    finally:
        _stop_session(head)
        log.close()


def _stop_session(head: subprocess.Popen) -> None:
    """Stop the head and every process of its group (GCS, raylet, workers): SIGTERM, then SIGKILL."""
    for sig, wait in ((signal.SIGTERM, 20.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(head.pid, sig)
        except ProcessLookupError:
            return
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            try:
                os.killpg(head.pid, 0)
            except ProcessLookupError:
                head.wait()
                return
            head.poll()
            time.sleep(0.2)


def _driver_env(address: str, **auth: str | None) -> dict[str, str]:
    """This process' environment for a driver of ``address``, with the token settings in ``auth`` (``None``: unset)."""
    env = {**os.environ, "RAY_ADDRESS": address}
    for name, value in auth.items():
        if value is None:
            env.pop(name, None)
        else:
            env[name] = value
    return env


def test_the_head_and_its_gcs_listen_on_loopback_only(token_cluster: str) -> None:
    from test_rollouts_ray import assert_loopback_only

    ray.init(address=token_cluster, log_to_driver=False)
    try:
        assert_loopback_only()
    finally:
        ray.shutdown()


def test_train_with_ray_workers_on_a_token_cluster(token_cluster: str, tmp_path: Path) -> None:
    """The documented multi-machine command, driven with the cluster's token: two iterations, then saved."""
    command = [
        sys.executable,
        "-m",
        "sb3_trpo_plus",
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
    result = subprocess.run(command, env=_driver_env(token_cluster), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    from sb3_trpo_plus import TRPOPlus

    assert TRPOPlus.load(tmp_path / "trpo_plus" / "Reacher2D-v1_1" / "Reacher2D-v1.zip").num_timesteps == 256


# a driver without the cluster's token: Ray's auth mode unset (the default for a driver given an address), or the
# token mode with a token of another cluster
REFUSED = {
    "no token": {"RAY_AUTH_MODE": None, "RAY_AUTH_TOKEN_PATH": None},
    "wrong token": {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": "0" * 64},
}


@pytest.mark.parametrize("case", REFUSED)
def test_the_train_command_without_the_clusters_token_stops_at_once_with_one_line(
    token_cluster: str, tmp_path: Path, case: str
) -> None:
    command = [
        sys.executable,
        "-m",
        "sb3_trpo_plus",
        "train",
        "--env",
        "Reacher2D-v1",
        "-f",
        str(tmp_path),
        "--workers",
        "ray:2",
    ]
    result = subprocess.run(command, env=_driver_env(token_cluster, **REFUSED[case]), capture_output=True, text=True)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("trpo-plus train --workers ray:2: the Ray cluster at " + token_cluster)
    assert ONE_LINE in lines[0] and "auth_token" in lines[0]
    assert not (tmp_path / "trpo_plus").exists(), "nothing is built before the cluster accepts the driver"


@pytest.mark.parametrize("case", REFUSED)
def test_rayrollouts_without_the_clusters_token_raises_at_once(token_cluster: str, case: str) -> None:
    script = (
        "import time\n"
        "from sb3_trpo_plus.rollouts import RayRollouts\n"
        "from sb3_trpo_plus.rollouts.ray_cluster import RayAuthenticationError\n"
        "start = time.monotonic()\n"
        "try:\n"
        "    RayRollouts('Reacher2D-v1', num_workers=1, envs_per_worker=1)\n"
        "except RayAuthenticationError as error:\n"
        "    print(f'{time.monotonic() - start:.2f}'); print(error)\n"
    )
    env = _driver_env(token_cluster, **REFUSED[case])
    result = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    seconds, message = result.stdout.strip().splitlines()
    assert float(seconds) < FAST
    assert message.startswith(f"the Ray cluster at {token_cluster} requires token authentication")
    assert ONE_LINE in message
    expected = "sent the token of the RAY_AUTH_TOKEN environment variable" if case == "wrong token" else "sends no token"
    assert expected in message


@pytest.mark.parametrize(
    ("address", "ray_address", "expected"),
    [
        ("10.0.0.5:6379", None, "10.0.0.5:6379"),
        (None, "127.0.0.1:6391", "127.0.0.1:6391"),
        ("10.0.0.5:6379", "127.0.0.1:6391", "10.0.0.5:6379"),  # the argument wins, as in ray.init
        (None, None, None),  # Ray starts a local instance
        ("auto", None, None),  # Ray finds the local cluster itself
        ("ray://10.0.0.5:10001", None, None),  # Ray Client
        ("no-port", None, None),
    ],
)
def test_cluster_address_is_what_ray_init_connects_to(monkeypatch, address, ray_address, expected) -> None:
    from sb3_trpo_plus.rollouts.ray_cluster import cluster_address

    if ray_address is None:
        monkeypatch.delenv("RAY_ADDRESS", raising=False)
    else:
        monkeypatch.setenv("RAY_ADDRESS", ray_address)
    assert cluster_address(address) == expected


def test_token_location_follows_rays_order(monkeypatch, tmp_path: Path) -> None:
    from sb3_trpo_plus.rollouts.ray_cluster import token_location

    token = tmp_path / "token"
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(token))
    monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
    assert token_location() == f"the file {token} (missing)"
    token.write_text("a" * 64)
    assert token_location() == f"the file {token}"
    monkeypatch.setenv("RAY_AUTH_TOKEN", "b" * 64)
    assert token_location() == "the RAY_AUTH_TOKEN environment variable"
    monkeypatch.delenv("RAY_AUTH_TOKEN")
    monkeypatch.delenv("RAY_AUTH_TOKEN_PATH")
    assert token_location().startswith(f"the file {Path.home() / '.ray' / 'auth_token'}")


def test_nothing_listening_is_left_to_ray_init(monkeypatch) -> None:
    """No cluster at the address: the check returns at once and ray.init reports the address itself."""
    from sb3_trpo_plus.rollouts.ray_cluster import check_cluster_token

    start = time.monotonic()
    check_cluster_token(f"127.0.0.1:{_free_port()}")
    assert time.monotonic() - start < 5
