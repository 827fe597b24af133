"""The daemon's plumbing between threads: the sample ring, the console, JSON of events."""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from typing import Any

import numpy as np
import orjson

#: the interpreter's thread switch interval while the daemon runs [s]: the estimation
#: thread gets the GIL back within this of a zenoh callback
SWITCH_INTERVAL_S = 2e-4


class SampleRing:
    """Bounded FIFO between the zenoh callback and the estimation thread; drops the oldest.

    ``wake`` is set on every put; rings of one daemon share it (one estimation thread).
    """

    def __init__(self, capacity: int, wake: threading.Event | None = None) -> None:
        self._items: deque[tuple[int, bytes]] = deque()
        self._capacity = capacity
        self._lock = threading.Lock()
        self.wake = wake if wake is not None else threading.Event()
        self.dropped = 0
        self.last_put_s = -math.inf         # time.monotonic() of the latest put

    @property
    def pending(self) -> int:
        """Items queued now (no lock: a glance, not a count to act on exactly)."""
        return len(self._items)

    def put(self, item: tuple[int, bytes]) -> None:
        with self._lock:
            if len(self._items) >= self._capacity:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.last_put_s = time.monotonic()
        self.wake.set()

    def drain(self) -> list[tuple[int, bytes]]:
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items


#: a ring whose latest sample is older than this is not waited for by :func:`gather` [s]
STREAMING_S = 0.02


def gather(rings: list[SampleRing], wake: threading.Event, window_s: float,
           stop: threading.Event | None = None, streaming_s: float = STREAMING_S) -> bool:
    """Wait up to ``window_s`` [s] until every streaming ring (one whose latest sample came
    within ``streaming_s``) has a sample queued, so that the estimation thread's next pass
    steps those arms together (step 1's cost is per pass, not per arm). Returns at once when
    fewer than two rings stream, and early on ``stop``. ``wake`` is the rings' shared event
    (set by every put), cleared here as the estimation thread clears it.

    Returns:
        True when every streaming ring has a sample queued (or fewer than two stream), False
        when the window ran out or ``stop`` was set first.
    """
    now = time.monotonic()
    streaming = [ring for ring in rings if now - ring.last_put_s < streaming_s]
    if len(streaming) < 2:
        return True
    deadline = now + window_s
    while not all(ring.pending for ring in streaming):
        left = deadline - time.monotonic()
        if left <= 0.0 or (stop is not None and stop.is_set()):
            return False
        wake.wait(left)
        wake.clear()
    return True


def event_bytes(body: dict[str, Any]) -> bytes:
    """JSON of an event or status: NumPy values natively, a non-finite number as ``null``,
    anything else as its text."""
    return orjson.dumps(body, default=str,
                        option=orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS)


def percentiles(values) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p99": None, "max": None}
    a = np.fromiter(values, dtype=float)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
            "max": float(a.max())}


class Console:
    """Status lines printed by their own thread from a bounded queue: a slow or paused
    terminal (Ctrl-S), a stuck journal or an unread pipe must never block estimation; lines
    beyond ``capacity`` waiting are dropped (counted)."""

    def __init__(self, capacity: int = 200) -> None:
        self._queue: queue.Queue[str | None] = queue.Queue(maxsize=capacity)
        self.dropped = 0
        self.thread = threading.Thread(target=self._run, name="wrenchd-console", daemon=True)
        self.thread.start()

    def say(self, line: str) -> None:
        try:
            self._queue.put_nowait(line)
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while (line := self._queue.get()) is not None:
            try:
                print(line, flush=True)
            except (OSError, ValueError):         # stdout closed: nothing to tell anyone
                pass

    def close(self, timeout_s: float = 2.0) -> None:
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            pass
        self.thread.join(timeout=timeout_s)
