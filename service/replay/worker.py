"""Replay's adaptation in a worker process, in simulated time, deterministic.

Inline adaptation (:class:`wrenchd.service.pipeline.adaptation.InlineAdaptation`) runs each round at the sample
where it falls due, and the pipeline waits for it: the rounds, not the estimates, then set
the pace of a replay. :class:`WorkerAdaptation` runs the very same :class:`Adapter` in a
forked process, on the second core, while the pipeline goes on estimating; as in the daemon,
where the worker's result arrives some time after the round began, a round's result is used
from ``result_delay_s`` of *simulated* time after the sample it fell due at.

Deterministic: the pipeline sends the worker, in order, exactly the calls the inline backend
would make (``offer``, ``drift``, ``setup_change``, ``tick``, ``reset``), in chunks of
:data:`CHUNK_S` of sample time (the offered rows stacked in one float32 array with their
sample times beside; per other call its kind, time
and the number of rows offered before it); the worker replays them on its Adapter and
answers with each round as soon as it is done (stamped with its simulated time) and, per
chunk, how far it has come. The pipeline applies a round at the first sample at or after ``t + result_delay_s``,
waiting for the worker if it is not that far yet. The outcome depends only on the session,
the config and ``result_delay_s``, never on how fast either process runs.
"""

from __future__ import annotations

import multiprocessing as mp
import threading
import time
import traceback
from dataclasses import replace
from typing import Any, Callable

import numpy as np

from wrenchd.models.series import N_JOINTS
from wrenchd.models.adaptation import AdaptationConfig, RoundResult
from wrenchd.models.adaptation.host import SETUP_CALLS
from wrenchd.service.runtime import stopping

CHUNK_S = 0.25          # the pipeline sends its calls at least every this much sample time [s]
ARM = "replay"          # the one arm of a replay worker


def _serve(conn, config: dict[str, Any], normalisation: dict[str, np.ndarray] | None) -> None:
    """Worker main: replay the pipeline's calls on the shared adaptation host, in sample time;
    answer rounds and progress."""
    from wrenchd.models.adaptation.host import AdapterHost
    from wrenchd.models.estimator.corr_finetune import use_compiled_kernels

    # the rounds' element-wise arithmetic compiled, loaded beside the first rows (the
    # calibration minute, when no round is due): until it is ready NumPy serves, bit for bit
    threading.Thread(target=use_compiled_kernels, name="wrenchd-finetune-kernels",
                     daemon=True).start()
    host = AdapterHost({ARM: AdaptationConfig(**config)}, {ARM: normalisation})
    try:
        while True:
            chunk = conn.recv()
            if chunk is None:
                return
            rows, stamps, kinds, times, counts, tail = chunk
            done = -np.inf
            a = n = 0               # rows[a:a + n]: offered, not added yet
            for kind, t, count in zip(kinds, times, counts):
                n += count
                if kind == "tick" and host.idle_tick(ARM, t):
                    done = t        # nothing due: its rows go in with the next call's
                    continue
                if n:               # the rows offered before this call, in one add
                    host.call(ARM, "rows", t, (rows[a:a + n], stamps[a:a + n]))
                    a, n = a + n, 0
                result = host.call(ARM, kind, t, t)      # a set-up change's time is its own
                if kind == "tick":
                    done = t
                    if result is not None:   # at once: the pipeline may be waiting for it
                        conn.send(("round", done, [result]))
            if n + tail:
                host.call(ARM, "rows", done, (rows[a:a + n + tail], stamps[a:a + n + tail]))
            conn.send(("chunk", done, []))
    except Exception:  # noqa: BLE001 - reported to the pipeline, which raises it
        conn.send(("error", traceback.format_exc(limit=8), []))
    except KeyboardInterrupt:
        return


class WorkerAdaptation:
    """:class:`~wrenchd.service.pipeline.adaptation.AdaptationBackend` for replay with the Adapter in a forked
    process (see the module docstring).

    Args:
        config: the adaptation settings.
        normalisation: the ``Corr`` normalisation (from the step-1 model).
        result_delay_s: simulated time between a round falling due and its net serving [s].
    """

    def __init__(self, config: AdaptationConfig,
                 normalisation: dict[str, np.ndarray] | None = None,
                 result_delay_s: float = 1.0) -> None:
        if result_delay_s < 0:
            raise ValueError("result_delay_s must be >= 0")
        self.config, self.normalisation = config, normalisation
        self.result_delay_s = float(result_delay_s)
        # fork: the child starts at once with the parent's modules (a spawned one would spend
        # seconds importing torch); it runs NumPy and single-threaded torch only.
        ctx = mp.get_context("fork")
        self._conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve, name="wrenchd-replay-adaptation",
                                   args=(child, config.model_dump(), normalisation),
                                   daemon=True)
        self.process.start()
        child.close()
        k = config.window * 12
        self._window_cols = k                   # row layout: window, step-1, measured
        # the offered arrays of this chunk, kept as given (the pipeline never changes an
        # array it has offered) and packed into one float32 array when the chunk is sent
        self._offered: tuple[list[np.ndarray], ...] = ([], [], [], [])   # ..., sample times
        self._n_rows = 0                        # rows offered in this chunk
        self._pending = 0                       # of which offered since the last call
        self._kinds: list[str] = []
        self._times: list[float] = []
        self._counts: list[int] = []
        self._chunk_t0: float | None = None
        self._done = -np.inf                # the worker has replayed every tick up to here
        self._in_flight = 0                 # chunks sent, not answered
        self._ready: list[RoundResult] = []  # rounds received, not yet applied
        self._reset_t = -np.inf             # rounds due before the last reset are void
        self.errors: list[str] = []
        self.rounds_waited = 0              # times the pipeline had to wait for the worker
        self.blocked_s = 0.0                # wall time it sat blocked on the worker's answer [s]
        #: called while waiting for the worker, until it returns False: work of the replay's
        #: that does not depend on the adaptation (it must not change any outcome)
        self.idle_work: Callable[[], bool] | None = None

    # -- the pipeline's calls -----------------------------------------------------------
    def offer(self, windows, step1, measured, t=None) -> None:
        n = len(step1)
        if t is None:                       # unknown times: never carried over
            t = np.full(n, np.nan)
        w, s, m, stamps = self._offered
        w.append(windows)
        s.append(step1)
        m.append(measured)
        stamps.append(t)
        self._n_rows += n
        self._pending += n

    def _packed_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """This chunk's offered rows, ``[window, step-1, measured]`` per row, cast to float32
        as :meth:`Adapter.add` casts (element by element: the same numbers as row by row),
        and their sample times (float64)."""
        w, s, m, t = self._offered
        k, n = self._window_cols, self._n_rows
        rows = np.empty((n, k + 2 * N_JOINTS), dtype=np.float32)
        stamps = np.concatenate(t).astype(np.float64) if n else np.empty(0)
        if n:
            rows[:, :k] = np.concatenate(w).reshape(n, k)
            rows[:, k:k + N_JOINTS] = np.concatenate(s)
            rows[:, k + N_JOINTS:] = np.concatenate(m)
        for part in self._offered:
            part.clear()
        return rows, stamps

    def _call(self, kind: str, t: float) -> None:
        self._kinds.append(kind)
        self._times.append(t)
        self._counts.append(self._pending)
        self._pending = 0

    def drift(self, t: float) -> None:
        self._call("drift", t)

    def setup_change(self, t: float, kind: str = "pressure") -> None:
        self._call(SETUP_CALLS[kind], t)

    def reset(self, t: float) -> None:
        self._call("reset", t)
        self._reset_t = t
        self._ready = [r for r in self._ready if r.t > t]     # nothing from before the reset

    def tick(self, t: float) -> list[RoundResult]:
        self._call("tick", t)
        if self._chunk_t0 is None:
            self._chunk_t0 = t
        if t - self._chunk_t0 >= CHUNK_S:
            self._send()
            self._receive(block=False)      # a poll costs a syscall: once per chunk
        need = t - self.result_delay_s      # every round due up to here must be known
        if self._done < need and (self._in_flight or self._kinds or self._n_rows):
            self.rounds_waited += 1
            self._send()
            idle = self.idle_work
            while self._done < need and self._in_flight:
                if idle is not None and not self._conn.poll():
                    if idle():
                        continue
                    idle = None
                blocked = time.perf_counter()
                self._receive(block=True)
                self.blocked_s += time.perf_counter() - blocked
        if not self._ready or self._ready[0].t > need:
            return []
        out = [r for r in self._ready if r.t <= need]
        # applied now: their events carry this time
        self._ready = [r for r in self._ready if r.t > need]
        return [replace(r, t=t) for r in out]

    def close(self) -> None:
        try:
            self._conn.send(None)
        except (OSError, ValueError):
            pass
        # on a stop request the round under way is not waited for (its result is not kept)
        self.process.join(timeout=0.2 if stopping.requested() else 5.0)
        if self.process.is_alive():
            self.process.kill()
            self.process.join(timeout=2.0)
        self._conn.close()

    # -- plumbing -----------------------------------------------------------------------
    def _send(self) -> None:
        if self._kinds or self._n_rows:
            self._conn.send((*self._packed_rows(), self._kinds, self._times, self._counts,
                             self._pending))
            self._n_rows = self._pending = 0
            self._kinds, self._times, self._counts = [], [], []
            self._in_flight += 1
        self._chunk_t0 = None

    def _receive(self, block: bool) -> None:
        while self._in_flight and (block or self._conn.poll()):
            kind, value, results = self._conn.recv()
            if kind == "chunk":             # the end of a chunk; "round": one round's result
                self._in_flight -= 1
            elif kind == "error":
                raise RuntimeError(f"replay adaptation worker failed:\n{value}")
            if value > self._done:
                self._done = value
            self._ready.extend(r for r in results if r.t > self._reset_t)
            block = False

