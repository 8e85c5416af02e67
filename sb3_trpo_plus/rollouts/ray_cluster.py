"""Connecting to a Ray cluster: a token check that answers in a second, and a local Ray on loopback.

Ray 2.50 and later secure a cluster with a shared token (``RAY_AUTH_MODE=token``). A driver that connects by
address without the cluster's token retries for about 20 seconds and then raises ``ConnectionError`` behind a
traceback; :func:`check_cluster_token` asks the cluster's GCS once, as Ray itself would, and raises
:class:`RayAuthenticationError` with one line that says what to set. It needs nothing but Ray.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

LOOPBACK_VARIABLE = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"
"""With this set to ``0``, Ray started on this machine listens on 127.0.0.1 only (Ray's own switch)."""


class RayAuthenticationError(ConnectionError):
    """The Ray cluster requires token authentication and did not accept this process' token (or it has none)."""


def cluster_address(address: str | None = None) -> str | None:
    """The ``host:port`` that ``ray.init(address)`` connects to: ``address``, else ``RAY_ADDRESS``; ``None`` where Ray
    would start a local instance or finds one by itself (``auto``, ``local``) or goes through Ray Client (``ray://``)."""
    target = address if address is not None else os.environ.get("RAY_ADDRESS")
    if not target or target in {"auto", "local"} or "://" in target:
        return None
    host, separator, port = target.rpartition(":")
    return target if separator and host and port.isdigit() else None


def token_location() -> str:
    """Where Ray reads this process' token from: ``RAY_AUTH_TOKEN``, else the file ``RAY_AUTH_TOKEN_PATH`` names,
    else ``~/.ray/auth_token``."""
    if os.environ.get("RAY_AUTH_TOKEN"):
        return "the RAY_AUTH_TOKEN environment variable"
    path = os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")
    return f"the file {path}" + ("" if os.path.isfile(path) else " (missing)")


def check_cluster_token(address: str | None = None, *, timeout: float = 2.0) -> None:
    """Raise :class:`RayAuthenticationError` when the cluster at ``address`` (else ``RAY_ADDRESS``) requires a token
    that this process does not send; return at once when there is no address to check (see :func:`cluster_address`)
    or nothing listens there (``ray.init`` reports that itself). Takes well under a second against a live cluster.

    :param address: the cluster's GCS address ``host:port``
    :param timeout: seconds to wait for a TCP connection to the address
    """
    target = cluster_address(address)
    if target is None:
        return
    host, _, port = target.rpartition(":")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError:
        return
    from ray.exceptions import AuthenticationError

    gcs_client = importlib.import_module("ray._raylet").GcsClient  # what ray.init connects with

    try:
        with _quiet_stderr():  # Ray's C++ client logs the refusal itself, a line that the error below replaces
            gcs_client(address=target)
    except AuthenticationError:
        mode = os.environ.get("RAY_AUTH_MODE")
        if (mode or "").lower() == "token":
            sent = f"sent the token of {token_location()}"
        else:
            sent = "sends no token (RAY_AUTH_MODE is " + ("unset" if mode is None else repr(mode)) + ", not 'token')"
        path = os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")
        raise RayAuthenticationError(
            f"the Ray cluster at {target} requires token authentication and refused this process, which {sent}: "
            f"set RAY_AUTH_MODE=token and put the cluster's token (`ray get-auth-token` on the head prints it) in "
            f"{path} (or name another file in RAY_AUTH_TOKEN_PATH, or give the token in RAY_AUTH_TOKEN)"
        ) from None
    except Exception:  # not a token problem: ray.init connects (or fails) with its own message
        return


def use_loopback_for_local_ray() -> None:
    """Make a Ray that this process starts on this machine listen on 127.0.0.1 only, unless the user chose otherwise
    (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER`` already set). Ray's processes inherit the setting."""
    os.environ.setdefault(LOOPBACK_VARIABLE, "0")


@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """File descriptor 2 sent to /dev/null for the duration (C++ code writes there, not to ``sys.stderr``)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
