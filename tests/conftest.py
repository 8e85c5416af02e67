"""Test configuration: one torch thread per process (pytest-xdist runs one process per core), and every Ray the suite
starts on loopback with token authentication and a token of its own.

Ray's processes inherit this environment: a local ``ray.init``, ``ray.cluster_utils.Cluster`` and a ``ray start``
subprocess listen on 127.0.0.1 only (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``), require a token
(``RAY_AUTH_MODE=token``) and read it from a temporary file (``RAY_AUTH_TOKEN_PATH``): nothing is written to the
user's ``~/.ray``, and a cluster of the user's (``RAY_ADDRESS``) is never joined.
"""

import atexit
import os
import secrets
import shutil
import tempfile
from pathlib import Path

import torch as th

os.environ.setdefault("MUJOCO_GL", "egl")
th.set_num_threads(1)

RAY_TOKEN_FOLDER = Path(tempfile.mkdtemp(prefix="sb3-trpo-plus-ray-token-"))
atexit.register(shutil.rmtree, RAY_TOKEN_FOLDER, ignore_errors=True)
(RAY_TOKEN_FOLDER / "auth_token").write_text(secrets.token_hex(32))
os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
os.environ["RAY_AUTH_MODE"] = "token"
os.environ["RAY_AUTH_TOKEN_PATH"] = str(RAY_TOKEN_FOLDER / "auth_token")
for name in ("RAY_AUTH_TOKEN", "RAY_ADDRESS"):
    os.environ.pop(name, None)
