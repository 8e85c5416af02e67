"""The machine a measurement ran on, as the benchmarks record it beside their numbers."""

from __future__ import annotations

import platform
from pathlib import Path


def cpu_name(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The processor's model name (Linux's ``/proc/cpuinfo``, e.g. ``AMD EPYC``), else what ``platform`` knows
    (``platform.processor()``, or the architecture, e.g. ``x86_64``)."""
    try:
        for line in cpuinfo.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()
