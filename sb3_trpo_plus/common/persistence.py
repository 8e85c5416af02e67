"""Saving files atomically: the one writer of the models and the VecNormalize statistics.

A save writes a temporary file beside the target, flushes it to disk and renames it over the target, so a reader
(or a crash, or a full disk) sees either the previous file or the new one, never half of one.
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def atomic_write(path: str | os.PathLike[str], write: Callable[[io.BufferedWriter], None]) -> Path:
    """``write`` the file's bytes to a temporary file beside ``path``, then rename it over ``path``.

    The new file gets the mode a plain ``open`` would give it (``mkstemp`` makes it private). On failure the
    temporary file is removed, ``path`` is left as it was, and an ``OSError`` raised by the writing (a full disk, a
    lost mount) comes back with its ``errno`` and a message naming ``path``.

    :return: ``path``
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        # os.chmod, not os.fchmod, which Windows lacks before Python 3.13
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_name, 0o666 & ~umask)
        try:
            with open(tmp_name, "wb") as file:
                write(file)
                file.flush()
                os.fsync(file.fileno())
            os.replace(tmp_name, target)
        except OSError as error:  # e.g. a full disk: the previous file was never touched
            message = f"{error.strerror or error}: saving {target} failed; the previous file is unchanged"
            raise OSError(error.errno, message) from error
    finally:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
    return target
