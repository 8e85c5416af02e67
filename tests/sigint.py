"""SIGINT as a terminal's Ctrl-C delivers it, for the tests that send one, whether or not the suite runs as a
background job (``make test &``, ``nohup``), which starts every process with SIGINT ignored."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager


def handled_in_child() -> None:
    """``preexec_fn`` of a child that Ctrl-C should reach: SIGINT to its default, which Python turns into
    ``KeyboardInterrupt`` at start-up (a child that inherits an ignored SIGINT keeps ignoring it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def ignored_in_child() -> None:
    """``preexec_fn`` of a child started as a background job is: SIGINT ignored."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextmanager
def handled_here() -> Iterator[object]:
    """Python's own Ctrl-C handler in this process for the duration (yielded: the handler in place); the
    disposition before is restored after."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield signal.getsignal(signal.SIGINT)
    finally:
        signal.signal(signal.SIGINT, before)
