"""Where a result came from: the record every bench and study writes beside its numbers.

``provenance()`` returns a JSON-ready dict: the command line, the git commit of the source
tree (and whether it has uncommitted changes), the date, the machine's load, the CPU time the
hypervisor stole over the run, the CPU count, the Python version and the versions of the
packages that move the numbers. Writers put it under one key, ``"provenance"``.

"The run" is measured by a ``RunMeter``: it reads the wall clock and the Linux ``/proc/stat``
``steal`` counter when it starts and again when ``provenance()`` is called. One meter starts
when this module is first imported (the CLI imports it before it parses its arguments), so a
plain ``provenance()`` covers the process so far; a writer that wants a tighter window passes
its own ``RunMeter``.

Nothing here imports torch or any other heavy package: versions come from the installed
distributions' metadata.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

PROVENANCE_KEY = "provenance"
"""The key under which result files carry the record."""

PACKAGES = ("torch", "numpy", "eclipse-zenoh", "mcap", "wrenchd")
"""Distributions whose versions are recorded."""

GIT_TIMEOUT_S = 5.0

_SOURCE_DIR = Path(__file__).resolve().parent


def steal_ticks() -> int | None:
    """CPU time the hypervisor gave to others while this machine's CPUs wanted to run, summed
    over all CPUs, in clock ticks (Linux /proc/stat ``steal``); None where unknown."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
        return int(fields[8]) if fields[0] == "cpu" and len(fields) > 8 else None
    except (OSError, ValueError, IndexError):
        return None


def ticks_per_s() -> int:
    """Clock ticks per second of the /proc counters (``SC_CLK_TCK``, 100 on Linux)."""
    try:
        return int(os.sysconf("SC_CLK_TCK"))
    except (AttributeError, ValueError, OSError):
        return 100


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (runnable processes), or None where unknown."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (AttributeError, OSError):
        return None


class RunMeter:
    """Wall time and stolen CPU time from its creation to each ``measure()``."""

    def __init__(self) -> None:
        self.started_s = time.monotonic()
        self.started_steal = steal_ticks()

    def measure(self) -> dict[str, float | None]:
        """``run_wall_s`` [s], ``steal_cpu_s`` (stolen CPU time summed over all CPUs [s]) and
        ``steal_share`` (stolen CPU time / (wall time x CPU count), 0..1) since creation."""
        wall_s = time.monotonic() - self.started_s
        now = steal_ticks()
        if self.started_steal is None or now is None:
            return {"run_wall_s": round(wall_s, 3), "steal_cpu_s": None, "steal_share": None}
        stolen_s = (now - self.started_steal) / ticks_per_s()
        capacity_s = wall_s * (os.cpu_count() or 1)
        share = stolen_s / capacity_s if capacity_s > 0 else 0.0
        return {"run_wall_s": round(wall_s, 3), "steal_cpu_s": round(stolen_s, 3),
                "steal_share": round(share, 5)}


PROCESS_METER = RunMeter()
"""Meter started when this module is first imported."""


def _git(*args: str) -> str | None:
    try:
        done = subprocess.run(["git", "-C", str(_SOURCE_DIR), *args], capture_output=True,
                              text=True, timeout=GIT_TIMEOUT_S, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return done.stdout if done.returncode == 0 else None


def git_state() -> dict[str, Any]:
    """``git_commit`` (40 hex digits) of the tree that holds this source and ``git_dirty``
    (tracked files changed since that commit); both None outside a git work tree."""
    head = _git("rev-parse", "HEAD")
    if head is None:
        return {"git_commit": None, "git_dirty": None}
    status = _git("status", "--porcelain", "--untracked-files=no")
    return {"git_commit": head.strip(), "git_dirty": None if status is None else bool(status.strip())}


def package_versions(names: tuple[str, ...] = PACKAGES) -> dict[str, str | None]:
    """Installed version of each distribution, None where it is not installed."""
    out: dict[str, str | None] = {}
    for name in names:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    return out


def provenance(argv: list[str] | None = None, run: RunMeter | None = None) -> dict[str, Any]:
    """The provenance record of a result produced now; ``argv`` defaults to ``sys.argv`` and
    ``run`` to the meter started with the process."""
    argv = list(sys.argv if argv is None else argv)
    record: dict[str, Any] = {
        "argv": argv,
        **git_state(),
        "date_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "load_average": load_average(),
        **(run or PROCESS_METER).measure(),
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
        "packages": package_versions(),
    }
    return record


def stamp(data: dict[str, Any], argv: list[str] | None = None,
          run: RunMeter | None = None) -> dict[str, Any]:
    """Put ``provenance(argv, run)`` into ``data`` under ``PROVENANCE_KEY``; returns ``data``."""
    data[PROVENANCE_KEY] = provenance(argv, run)
    return data
