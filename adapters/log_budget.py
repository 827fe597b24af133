"""The disk budget of the daemon's log directories: past it, the oldest closed log files go.

What counts is the daemon's own log files directly in the directory, named as
:class:`~wrenchd.adapters.mcap_log.McapLog` names them (``ARM-DATE-TIME-PID-SEQ.mcap``), of
any arm and any earlier run; other files and subdirectories (``models/``, a simulated robot's
recordings) are neither counted nor removed. When they total more than ``max_total_bytes``,
files are removed oldest first (by modification time) until the total fits; a file one of the
logs has open is never removed, so the open files alone may exceed a budget smaller than them.

A check lists the directory and stats its files: it runs after a log rotates and every
``budget_check_s``, never per record. Between checks the bytes in use are the closed files'
total at the last check plus what the open files hold now.
"""

from __future__ import annotations

import os
import re
import shutil
import time
from pathlib import Path

from wrenchd.adapters.mcap_log import McapLog

#: the name of a daemon log file (``McapLog._open``)
LOG_FILE_NAME = re.compile(r"^[A-Za-z0-9_\-]+-\d{8}-\d{6}-\d+-\d{3,}\.mcap$")


class DirectoryBudget:
    """One directory's log files under one budget (see the module docstring).

    Args:
        directory: the log directory.
        max_total_bytes: the budget [B]; None: nothing is removed, the total is only counted.
    """

    def __init__(self, directory: Path, max_total_bytes: int | None) -> None:
        self.directory, self.max_total_bytes = Path(directory), max_total_bytes
        self.closed_bytes = 0                  # the files not open, at the last check [B]
        self._failed: set[str] = set()         # paths whose removal failed (reported once)

    def _files(self) -> list[tuple[float, str, int, Path]]:
        """(modification time, name, bytes, path) of the directory's log files."""
        out = []
        try:
            entries = list(os.scandir(self.directory))
        except OSError:                        # not there (yet): nothing to count
            return []
        for entry in entries:
            if not LOG_FILE_NAME.match(entry.name):
                continue
            try:
                if not entry.is_file(follow_symlinks=False):
                    continue
                st = entry.stat(follow_symlinks=False)
            except OSError:                    # gone meanwhile
                continue
            out.append((st.st_mtime, entry.name, st.st_size, Path(entry.path)))
        return out

    def check(self, open_paths: set[Path]) -> list[tuple[str, str, object]]:
        """Count the files and remove the oldest closed ones while the total exceeds the
        budget. Returns the notices, oldest first: ``("removed", path, bytes)`` or
        ``("error", path, why)`` (a removal that failed; each path once)."""
        files = self._files()
        protected = {os.path.abspath(p) for p in open_paths}
        total = sum(size for _, _, size, _ in files)
        notices: list[tuple[str, str, object]] = []
        closed = sorted(f for f in files if os.path.abspath(f[3]) not in protected)
        for _, _, size, path in closed:
            if self.max_total_bytes is None or total <= self.max_total_bytes:
                break
            try:
                path.unlink()
            except FileNotFoundError:          # someone else removed it
                pass
            except OSError as exc:
                if str(path) not in self._failed:
                    self._failed.add(str(path))
                    notices.append(("error", str(path), f"cannot remove {path}: {exc}"))
                continue
            total -= size
            notices.append(("removed", str(path), size))
        open_total = sum(size for _, _, size, p in files if os.path.abspath(p) in protected)
        self.closed_bytes = max(total - open_total, 0)
        return notices


class LogBudgets:
    """The budgets of a writer's logs: one per directory, shared by the logs writing there.

    Args:
        logs: the logs (their configs give each directory's budget: the smallest set).
        clock: monotonic clock [s] (injectable for tests).
    """

    def __init__(self, logs: list[McapLog], clock=time.monotonic) -> None:
        self.clock = clock
        self._groups: list[tuple[DirectoryBudget, list[McapLog]]] = []
        by_dir: dict[str, list[McapLog]] = {}
        for log in logs:
            if log.config.enabled:
                by_dir.setdefault(os.path.abspath(log.config.directory), []).append(log)
        for directory, members in by_dir.items():
            budgets = [m.config.max_total_bytes for m in members
                       if m.config.max_total_bytes is not None]
            self._groups.append((DirectoryBudget(Path(directory),
                                                 min(budgets) if budgets else None), members))
        self.interval_s = min((m.config.budget_check_s for _, ms in self._groups for m in ms),
                              default=float("inf"))
        self._next_check = 0.0                 # the first tick checks (files of earlier runs)
        self._next_free = 0.0

    def tick(self, rotated: bool = False) -> bool:
        """Check every directory after a rotation or when the period is up; True if it did."""
        now = self.clock()
        if not rotated and now < self._next_check:
            return False
        self._next_check = now + self.interval_s
        self.check()
        return True

    def check(self) -> None:
        """Check every directory now; each notice goes to the log of the arm whose file it
        names (else the directory's first log)."""
        for budget, members in self._groups:
            notices = budget.check({m.open_path for m in members if m.open_path is not None})
            for notice in notices:
                name = Path(notice[1]).name
                owner = next((m for m in members if name.startswith(m.arm + "-")), members[0])
                owner.removed.append(notice)
            self._update_used(budget, members)

    def _update_used(self, budget: DirectoryBudget, members: list[McapLog]) -> None:
        used = budget.closed_bytes + sum(m.open_bytes for m in members)
        for m in members:
            m.bytes_used = used

    def refresh(self, free_every_s: float = 1.0) -> None:
        """Bring each log's ``bytes_used`` up to date (cheap: no directory listing) and, at
        most every ``free_every_s``, its ``bytes_free`` (one statvfs per directory)."""
        now = self.clock()
        free_due = now >= self._next_free
        if free_due:
            self._next_free = now + free_every_s
        for budget, members in self._groups:
            self._update_used(budget, members)
            if free_due:
                try:
                    free = shutil.disk_usage(budget.directory).free
                except OSError:                # not there (yet)
                    free = None
                for m in members:
                    m.bytes_free = free
