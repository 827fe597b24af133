"""The daemon's adaptation worker: one background process fine-tuning every arm's ``Corr``.

Training never runs in a zenoh callback nor in the thread that estimates: it runs here, in a
separate process (``spawn``), at a lower priority (``nice``), on one torch thread, and with a
duty cycle of at most ``max_cpu_fraction`` of its wall time, so the estimation threads keep
their latency. The pipelines send batches of gated samples and drift notices
(:class:`ProcessAdaptation`); the worker sends back round results (accepted ones with their
weights) and errors. An exception in a round is reported and the last good model keeps
serving; if the process dies, the daemon reports it and goes on estimating with the last
model. The worker exits by itself when the daemon dies (``kill -9`` included): it watches its
parent process. How it stops on the daemon's word: :class:`WorkerProcess`.

Accepted versions are checkpointed as ``{models_dir}/{arm}/corr-v{N:04d}.pt`` (the
estimator's safe checkpoint format), so any version can be loaded again (``corr_checkpoint``
in the arm's settings); :class:`Checkpoints` says which may be removed.

Clocks: the worker schedules rounds on its own clock (seconds since it started), which is what
a round result's ``t`` holds; the pipeline stamps the ``round`` and ``model`` events with the
arm's sample time at which it applies the result (:meth:`ArmPipeline.apply`), so every event
of an arm is on the robot's clock.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import signal
import sys
import threading
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np

from wrenchd.models.adaptation import AdaptationConfig, RoundResult
from wrenchd.models.adaptation.host import SETUP_CALLS
from wrenchd.models.estimator.compiled import ENV as NUMBA_ENV

_BATCH_S = 0.2          # pipelines send their samples at least this often [s]
_POLL_S = 0.02          # and look for round results at most this often [s]: polling the
                        # queue costs a select() call, too much to pay on every sample


#: how long :meth:`WorkerProcess.close` waits for the worker to end before killing it [s]
CLOSE_TIMEOUT_S = 2.0
#: how long a stopped worker waits for its queued results to reach the pipe [s]
FLUSH_TIMEOUT_S = 0.5


def _main(inbox: mp.Queue, outbox: mp.Queue, configs: dict[str, dict[str, Any]],
          normalisations: dict[str, dict[str, np.ndarray]], models_dir: str | None,
          max_cpu_fraction: float, cpus: list[int] | None = None,
          checkpoints: Checkpoints | None = None) -> None:
    """The worker process: :func:`_run` until stopped (or orphaned), then an immediate exit
    that waits neither for undelivered results nor for the interpreter's teardown."""
    _run(inbox, outbox, configs, normalisations, models_dir, max_cpu_fraction, cpus,
         checkpoints)
    # Hand over what was queued, whole: an exit in the middle of a message would leave half of
    # it in the pipe, and the daemon, which reads while it waits, would wait for the rest for
    # ever. Only a daemon that no longer reads makes this wait last its full bound.
    outbox.close()
    feeder = threading.Thread(target=outbox.join_thread, daemon=True)
    feeder.start()
    feeder.join(FLUSH_TIMEOUT_S)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(0)


class Checkpoints:
    """Which of an arm's saved Corr versions the worker may remove.

    With ``keep_checkpoints`` set, each save removes the arm's older versions but the newest
    ``keep``, the one the pipeline serves (it says which once it has swapped,
    :class:`ProcessAdaptation`), those it has not swapped to yet, and the arm's configured
    ``corr_checkpoint``.

    Args:
        keep: the newest versions kept per arm (None: every one).
        pinned: per arm, a checkpoint never removed (its configured ``corr_checkpoint``).
    """

    PATTERN = "corr-v*.pt"

    def __init__(self, keep: int | None = None, pinned: dict[str, str] | None = None) -> None:
        self.keep, self.pinned = keep, dict(pinned or {})
        self._pending: dict[str, list[tuple[int, str]]] = {}   # saved, not yet served
        self._serving: dict[str, str | None] = {}

    def saved(self, arm: str, version: int, path: Path) -> None:
        self._pending.setdefault(arm, []).append((version, str(path)))

    def served(self, arm: str, version: int | None) -> None:
        """The pipeline swapped to ``version`` (None: to a fresh, unsaved Corr)."""
        if version is None:
            self._serving[arm] = None
            return
        pending = self._pending.get(arm, [])
        for i, (v, path) in enumerate(pending):        # results are applied in order
            if v == version:
                self._serving[arm] = path
                del pending[:i + 1]
                return

    def prune(self, arm: str, directory: Path) -> list[tuple[str, int]]:
        """Remove the arm's checkpoints beyond the newest ``keep`` but the protected ones."""
        if self.keep is None:
            return []
        from wrenchd.models.estimator.checkpoint import prune_checkpoints

        protect = {p for _, p in self._pending.get(arm, [])}
        protect |= {p for p in (self._serving.get(arm), self.pinned.get(arm)) if p}
        return prune_checkpoints(directory, self.PATTERN, self.keep, protect)


def _run(inbox: mp.Queue, outbox: mp.Queue, configs: dict[str, dict[str, Any]],
         normalisations: dict[str, dict[str, np.ndarray]], models_dir: str | None,
         max_cpu_fraction: float, cpus: list[int] | None = None,
         checkpoints: Checkpoints | None = None) -> None:
    """Worker process main loop; returns when stopped or when the daemon is gone."""
    if cpus is not None:
        os.sched_setaffinity(0, cpus)
    # this process never streams: the kernels it builds travel to the daemon, which compiles
    # its own, so numba (about 100 MB of LLVM) stays out of it
    os.environ[NUMBA_ENV] = "0"
    checkpoints = checkpoints or Checkpoints()
    from wrenchd.models.estimator.checkpoint import save_checkpoint
    from wrenchd.models.adaptation.host import AdapterHost
    from wrenchd.service.runtime.scheduling import normal_scheduling, one_compute_thread

    one_compute_thread()          # a spawned process: NumPy's BLAS would start one per core
    # Ctrl-C in a terminal reaches the whole process group: the daemon stops this worker with
    # a "stop" message (and it exits by itself if the daemon dies), so it ignores the signals
    # instead of dying mid-round with a traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    normal_scheduling()           # never in the daemon's real-time class, whatever it inherited
    try:
        os.nice(10)
    except OSError:
        pass
    parent = os.getppid()
    host = AdapterHost({arm: AdaptationConfig(**cfg) for arm, cfg in configs.items()},
                       normalisations)
    t0 = time.monotonic()
    busy_until = 0.0
    while True:
        try:
            # the duty cycle's pause is spent waiting here: a message ends it at once
            timeout = max(0.02, busy_until - time.monotonic())
            message = inbox.get(timeout=timeout)
            messages = [message]
            while True:
                try:
                    messages.append(inbox.get_nowait())
                except queue.Empty:
                    break
        except queue.Empty:
            messages = []
        if os.getppid() != parent:          # the daemon died (kill -9): do not linger
            return
        if any(kind == "stop" for kind, _, _ in messages):
            return                          # before the samples queued with it
        now = time.monotonic() - t0
        for kind, arm, payload in messages:
            if kind == "serving":           # the pipeline swapped to a version
                checkpoints.served(arm, payload)
                continue
            if kind == "reset":             # the pipeline serves a fresh Corr
                checkpoints.served(arm, None)
            host.call(arm, kind, now, payload)
        if time.monotonic() < busy_until:
            continue
        for arm in host.arms:
            start = time.monotonic()
            try:
                result = host.call(arm, "tick", time.monotonic() - t0)
            except Exception:  # noqa: BLE001 - reported; the last good model keeps serving
                outbox.put(("error", arm, traceback.format_exc(limit=5)))
                continue
            if result is None:
                continue
            if result.accepted and models_dir is not None:
                try:
                    path = Path(models_dir) / arm / f"corr-v{result.version:04d}.pt"
                    path.parent.mkdir(parents=True, exist_ok=True)
                    save_checkpoint(path, host.adapters[arm].corr,
                                    data={"source": "wrenchd lifelong adaptation", "arm": arm},
                                    validation=result.summary())
                    checkpoints.saved(arm, result.version, path)
                except OSError as exc:
                    outbox.put(("error", arm, f"cannot checkpoint version {result.version}: "
                                              f"{exc}"))
                try:
                    checkpoints.prune(arm, Path(models_dir) / arm)
                except OSError as exc:
                    outbox.put(("error", arm, f"cannot remove an old checkpoint: {exc}"))
            outbox.put(("round", arm, result))
            spent = time.monotonic() - start
            busy_until = max(busy_until, time.monotonic()
                             + spent * (1.0 / max_cpu_fraction - 1.0))


class WorkerProcess:
    """The process and its queues; one per daemon.

    The daemon sends ``stop`` (:meth:`stop`), which the loop sees at its next look at the inbox
    (it waits there, the duty cycle's pauses included, so a message wakes it at once; a round
    takes milliseconds); the stop goes before any message queued with it. A result the worker
    queued must not hold it up for long, nor be cut in half: the worker gives its queue's
    feeder thread at most ``FLUSH_TIMEOUT_S`` to write whole messages (the daemon reads them
    while it waits, :meth:`close`; a round's result, its weights, can fill the pipe), flushes
    its output and ends with ``os._exit(0)``: its state is in memory or already in its
    checkpoints, and the interpreter's teardown has nothing left to save. The daemon kills a
    worker that has not ended within its bound, saying so.
    """

    def __init__(self, configs: dict[str, AdaptationConfig], models_dir: str | None,
                 max_cpu_fraction: float = 0.5,
                 normalisations: dict[str, dict[str, np.ndarray]] | None = None,
                 cpus: list[int] | None = None, keep_checkpoints: int | None = None,
                 pinned_checkpoints: dict[str, str] | None = None) -> None:
        ctx = mp.get_context("spawn")
        self.inbox: mp.Queue = ctx.Queue()
        self.outbox: mp.Queue = ctx.Queue()
        self.process = ctx.Process(
            target=_main, name="wrenchd-adaptation", daemon=True,
            args=(self.inbox, self.outbox, {a: c.model_dump() for a, c in configs.items()},
                  normalisations or {}, models_dir, max_cpu_fraction, cpus,
                  Checkpoints(keep_checkpoints, pinned_checkpoints)))
        self.process.start()
        self._results: dict[str, list[tuple[str, Any]]] = {arm: [] for arm in configs}
        self._stop_sent = False

    def send(self, kind: str, arm: str, payload: Any = None) -> None:
        if self.process.is_alive():
            self.inbox.put((kind, arm, payload))

    def poll(self, arm: str) -> list[tuple[str, Any]]:
        """Results for ``arm`` received so far (other arms' are kept for them)."""
        self._drain()
        out, self._results[arm] = self._results.get(arm, []), []
        return out

    @property
    def alive(self) -> bool:
        return self.process.is_alive()

    def stop(self) -> None:
        """Ask the worker to end (it does within a round's time); :meth:`close`
        waits for it. The daemon asks early and waits last, so the worker's exit overlaps
        the rest of its close sequence."""
        if self._stop_sent:
            return
        self._stop_sent = True
        try:
            self.inbox.put(("stop", "", None))
        except (OSError, ValueError):
            pass

    def close(self, timeout: float = CLOSE_TIMEOUT_S) -> bool:
        """Stop the worker and wait up to ``timeout`` seconds for it to end, reading what it
        still sends meanwhile (a result left in a full pipe would keep it from exiting); one
        still running then is killed. Returns True when it had to be killed."""
        self.stop()
        deadline = time.monotonic() + timeout
        while self.process.is_alive() and time.monotonic() < deadline:
            self._drain()        # a live worker writes whole messages (see its exit path)
            self.process.join(timeout=min(_POLL_S, max(0.0, deadline - time.monotonic())))
        killed = self.process.is_alive()
        if killed:
            self.process.kill()
            self.process.join(timeout=2.0)
        for q in (self.inbox, self.outbox):
            q.cancel_join_thread()
            q.close()
        return killed

    def _drain(self) -> None:
        """Read the results waiting in the outbox (kept for :meth:`poll`)."""
        while True:
            try:
                kind, who, payload = self.outbox.get_nowait()
            except (queue.Empty, EOFError, OSError, ValueError):
                return
            self._results.setdefault(who, []).append((kind, payload))


class _Rows:
    """Rows (float32 unless told) appended a few at a time into storage that grows by
    doubling, so that handing them over costs one copy, not a concatenation of hundreds of
    small arrays on the estimation thread (~0.7 ms every ``_BATCH_S``, a sample's whole
    latency budget)."""

    def __init__(self, dtype=np.float32) -> None:
        self._data: np.ndarray | None = None
        self._n = 0
        self._dtype = dtype

    def append(self, rows) -> None:
        rows = np.asarray(rows, self._dtype)
        k = len(rows)
        if self._data is None or self._n + k > len(self._data):
            grown = np.empty((max(256, 2 * (self._n + k)), *rows.shape[1:]), self._dtype)
            if self._data is not None:
                grown[:self._n] = self._data[:self._n]
            self._data = grown
        self._data[self._n:self._n + k] = rows
        self._n += k

    def __len__(self) -> int:
        return self._n

    def take(self) -> np.ndarray:
        """The rows appended since the last take (a copy); empties the buffer."""
        out = (self._data[:self._n].copy() if self._data is not None
               else np.empty(0, self._dtype))
        self._n = 0
        return out


class ProcessAdaptation:
    """:class:`~wrenchd.service.pipeline.adaptation.AdaptationBackend` of one arm, backed by the worker process."""

    def __init__(self, worker: WorkerProcess, arm: str) -> None:
        self.worker, self.arm = worker, arm
        # windows, step-1 and measured torques, sample times (float64: stamps since 1970)
        self._batch = (_Rows(), _Rows(), _Rows(), _Rows(np.float64))
        self._sent_at = self._polled_at = time.monotonic()
        self.errors: list[str] = []
        self._dead_reported = False

    def offer(self, windows, step1, measured, t=None) -> None:
        if t is None:                       # unknown times: never carried over
            t = np.full(len(step1), np.nan)
        for rows, part in zip(self._batch, (windows, step1, measured, t)):
            rows.append(part)

    def _send_batch(self) -> None:
        if len(self._batch[0]):
            self.worker.send("samples", self.arm, tuple(rows.take() for rows in self._batch))
        self._sent_at = time.monotonic()

    def drift(self, t: float) -> None:
        self._send_batch()
        self.worker.send("drift", self.arm, float(t))     # the sample time of the detection

    def setup_change(self, t: float, kind: str = "pressure") -> None:
        self._send_batch()                  # the samples before it first
        self.worker.send(SETUP_CALLS[kind], self.arm, float(t))

    def reset(self, t: float) -> None:
        for rows in self._batch:
            rows.take()
        self.worker.send("reset", self.arm)

    def tick(self, t: float) -> list[RoundResult]:
        now = time.monotonic()
        if now - self._polled_at < _POLL_S:
            return []
        self._polled_at = now
        if now - self._sent_at >= _BATCH_S:
            self._send_batch()
            if not self.worker.alive and not self._dead_reported:
                self._dead_reported = True
                self.errors.append("adaptation worker process is not running")
        results = []
        for kind, payload in self.worker.poll(self.arm):
            if kind == "round":
                results.append(payload)
                if payload.accepted and payload.state_dict is not None:
                    # the pipeline swaps to it now (ArmPipeline.apply): its checkpoint is
                    # the one served, which the worker keeps
                    self.worker.send("serving", self.arm, payload.version)
            else:
                self.errors.append(str(payload))
        return results

    def close(self) -> None:
        for rows in self._batch:
            rows.take()
