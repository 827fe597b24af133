"""The daemon's MCAP logs, written by a process of their own.

Formatting and writing a sample's two records (input and estimate) costs far more CPU than
appending them to a list; in the daemon's process all of it would run under its GIL, which
the estimating thread waits for. :class:`LogWriterProcess` keeps only an append per record
there: a sender thread hands the queued records over every ``interval_s`` [s] as one pickled
batch of plain values (bytes, or the name of a formatter in
:data:`wrenchd.adapters.mcap_log.FORMATTERS` with its arguments as lists, which pickle much
faster than NumPy arrays), and the writer process makes them into ROS 2 messages (CDR; a
joint state, event or status handed over as JSON is converted there) and writes the arm's
:class:`~wrenchd.adapters.mcap_log.McapLog` (flushed every ``flush_interval_s``, rotated,
never fatal). It also keeps each log directory under its disk budget
(:class:`~wrenchd.adapters.log_budget.LogBudgets`: after a rotation and every
``budget_check_s``).

Crash safety: if the daemon dies (even ``kill -9``), the writer reads the end of its pipe,
writes what it received, finishes every file (summary and footer) and exits. Like the
adaptation worker, it ignores SIGINT and SIGTERM (Ctrl-C reaches the whole process group; it
stops on the daemon's word), leaves the daemon's real-time class and runs on the worker's CPUs.
The daemon's :class:`McapLog` objects stay its view of the logs (:class:`LogWriterProcess`).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import signal
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

from wrenchd.adapters.log_budget import LogBudgets
from wrenchd.adapters.mcap_log import LogConfig, McapLog, Payload, format_record
from wrenchd.service.runtime.scheduling import normal_class, normal_scheduling

#: how long close() waits for the writer to finish its files [s]
CLOSE_TIMEOUT_S = 30.0
#: how long close() then waits for the writer process to end [s]
EXIT_TIMEOUT_S = 5.0


def _state(log: McapLog) -> tuple:
    """What the writer reports of ``log`` (its budget notices handed over once)."""
    notices = list(log.removed)
    log.removed.clear()
    return (str(log.path) if log.path else None, [str(p) for p in log.paths], log.written,
            log.lost, log.problem, notices, log.bytes_used, log.bytes_free)


def _writer_main(specs: list[tuple[str, dict[str, Any], dict[str, Any]]], inbox, outbox,
                 interval_s: float, cpus: list[int] | None) -> None:
    """The writer process: batches in, records formatted and written, states out."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    normal_scheduling()                       # never in the daemon's real-time class
    if cpus is not None:
        os.sched_setaffinity(0, cpus)
    logs = [McapLog(arm, LogConfig(**config), metadata=metadata)
            for arm, config, metadata in specs]
    budgets = LogBudgets(logs)
    errors = 0
    last_report = 0.0
    try:
        while True:
            batch = None
            if inbox.poll(interval_s):
                try:
                    batch = pickle.loads(inbox.recv_bytes())
                except EOFError:              # the daemon is gone: finish the files
                    break
                if batch is None:             # close()
                    break
                for index, topic, stamp_ns, payload in batch:
                    log = logs[index]
                    try:
                        data = format_record(payload)
                    except Exception:  # noqa: BLE001 - a record that cannot be made is lost
                        errors += 1
                        log.lost += 1
                        continue
                    log.write(topic, stamp_ns, data)
            rotated = False
            for log in logs:
                rotated |= log.tick()
            budgets.tick(rotated)              # after a rotation, else every budget_check_s
            now = time.monotonic()
            if now - last_report >= interval_s:
                last_report = now
                budgets.refresh()
                outbox.send(("state", [_state(log) for log in logs], errors))
    finally:
        for log in logs:
            log.close()
        try:
            outbox.send(("closed", [_state(log) for log in logs], errors))
            outbox.close()
        except OSError:
            pass


class LogWriterProcess:
    """Moves MCAP formatting and writing out of the daemon's process.

    The writer reports each log's path, paths, written and lost counts, problem, the budget's
    notices (files removed, removals that failed) and the directory's bytes used and free back
    every ``interval_s``, and the sender thread copies them onto the daemon's :class:`McapLog`
    objects (records the daemon could not hand over, queue full or writer gone, are added to
    ``lost``). A writer that died is reported as a log problem and started again after
    ``retry_s`` (its new file starts a new part of the session).

    Args:
        logs: the daemon's logs (their arm, config and metadata start the writer's own;
            the objects then mirror the writer's state).
        interval_s: hand-over period [s] (also how often the states come back).
        capacity: records waiting in the daemon at most; beyond, a record is counted lost.
        cpus: CPUs of the writer process (None: any).
    """

    def __init__(self, logs: list[McapLog], interval_s: float = 0.02,
                 capacity: int = 200_000, cpus: list[int] | None = None) -> None:
        self.logs = list(logs)
        self.interval_s, self.capacity, self.cpus = interval_s, capacity, cpus
        self._index = {id(log): i for i, log in enumerate(self.logs)}
        self._queue: deque[tuple[int, str, int, Payload]] = deque()
        self._local_lost = [0] * len(self.logs)     # never handed over
        self._remote_lost = [0] * len(self.logs)    # lost by the writer (its count)
        self._closing = threading.Event()
        self.errors = 0                             # records the writer could not format
        self.restarts = 0
        self.process: mp.process.BaseProcess | None = None
        self._retry_at = 0.0
        self._start_process()
        self.thread = threading.Thread(target=self._run, name="wrenchd-log", daemon=True)
        self.thread.start()

    # -- the writer process ---------------------------------------------------------------
    def _start_process(self) -> None:
        ctx = mp.get_context("spawn")
        inbox_r, self._inbox = ctx.Pipe(duplex=False)
        self._outbox, outbox_w = ctx.Pipe(duplex=False)
        specs = [(log.arm, log.config.model_dump(), log.metadata) for log in self.logs]
        self.process = ctx.Process(target=_writer_main, name="wrenchd-log", daemon=True,
                                   args=(specs, inbox_r, outbox_w, self.interval_s, self.cpus))
        with normal_class():               # not the real-time class of a thread starting it
            self.process.start()
        inbox_r.close()
        outbox_w.close()
        self._remote_base = [log.written for log in self.logs]   # counts of earlier writers
        self._lost_base = list(self._remote_lost)
        self._paths_base = [list(log.paths) for log in self.logs]

    def _writer_gone(self, why: str) -> None:
        """The writer died: say so, keep counting, start a new one after ``retry_s``."""
        for log in self.logs:
            log.problem = why
        try:
            self._inbox.close()
        except OSError:
            pass
        self._inbox = None
        self._retry_at = time.monotonic() + min(log.config.retry_s for log in self.logs)

    def _absorb(self, states: list[tuple], errors: int) -> None:
        for i, (path, paths, written, lost, problem, notices, used, free) in enumerate(states):
            log = self.logs[i]
            log.path = Path(path) if path else None
            log.paths = self._paths_base[i] + [Path(p) for p in paths]
            log.written = self._remote_base[i] + written
            self._remote_lost[i] = self._lost_base[i] + lost
            log.lost = self._remote_lost[i] + self._local_lost[i]
            log.problem = problem
            for notice in notices:             # the daemon reports them (ArmRuntime)
                if notice[0] == "removed":
                    log.removed_files += 1
                    log.removed_bytes += notice[2]
                log.removed.append(notice)
            log.bytes_used, log.bytes_free = used, free
        self.errors = errors

    def _read_states(self, wait_s: float = 0.0) -> bool:
        """Copy what the writer reported; True once it said it has closed its files."""
        closed = False
        try:
            while self._outbox.poll(wait_s):
                kind, states, errors = self._outbox.recv()
                self._absorb(states, errors)
                if kind == "closed":
                    closed = True
                    break
        except (EOFError, OSError):
            closed = True
        return closed

    # -- the daemon's side ------------------------------------------------------------------
    def put(self, log: McapLog, topic: str, stamp_ns: int, payload: Payload) -> None:
        """Queue one record (cheap: an append). ``payload``: bytes, or ``(formatter name,
        args)`` made into bytes by the writer (:func:`wrenchd.adapters.mcap_log.format_record`)."""
        if not log.config.enabled:
            return
        i = self._index[id(log)]
        if len(self._queue) >= self.capacity:
            self._local_lost[i] += 1
            log.lost += 1
            return
        self._queue.append((i, topic, stamp_ns, payload))

    def _send_queued(self) -> None:
        q = self._queue
        if not q:
            return
        batch = [q.popleft() for _ in range(len(q))]
        if self._inbox is None:
            for i, *_ in batch:
                self._local_lost[i] += 1
            self._refresh_lost()
            return
        try:
            self._inbox.send_bytes(pickle.dumps(batch, protocol=pickle.HIGHEST_PROTOCOL))
        except (OSError, ValueError) as exc:
            for i, *_ in batch:
                self._local_lost[i] += 1
            self._refresh_lost()
            self._writer_gone(f"the log writer process stopped ({exc})")

    def _refresh_lost(self) -> None:
        for i, log in enumerate(self.logs):
            log.lost = self._remote_lost[i] + self._local_lost[i]

    def _run(self) -> None:
        while not self._closing.wait(self.interval_s):
            self._send_queued()
            if self._inbox is not None:
                if self._read_states() and not self._closing.is_set():
                    self._writer_gone("the log writer process stopped "
                                      f"(exit code {self.process.exitcode})")
            elif time.monotonic() >= self._retry_at:
                self.restarts += 1
                self._start_process()
        self._send_queued()

    def close(self) -> bool:
        """Hand over what is queued, let the writer finish every file, stop. Returns True
        when the writer had to be killed (it had not ended within ``EXIT_TIMEOUT_S`` of
        saying its files were finished, or of ``CLOSE_TIMEOUT_S`` without a word)."""
        self._closing.set()
        self.thread.join(timeout=CLOSE_TIMEOUT_S)
        if self._inbox is not None:
            try:
                self._inbox.send_bytes(pickle.dumps(None))
            except (OSError, ValueError):
                pass
            deadline = time.monotonic() + CLOSE_TIMEOUT_S
            while time.monotonic() < deadline and not self._read_states(0.1):
                pass
        killed = False
        if self.process is not None:
            self.process.join(timeout=EXIT_TIMEOUT_S)
            if self.process.is_alive():
                killed = True
                self.process.kill()
                self.process.join(timeout=5.0)
        return killed
