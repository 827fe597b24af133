"""The gated policy's delay line: a free sample waits for a contact before it may train.

A contact's onset builds up under the gate's bound before the gate sees it, so the samples
just before a detected contact may already be in contact. Every free sample waits
``release_delay_s`` here; when the gate finds a contact, the waiting samples from
``onset_margin_s`` before its onset on are dropped, the older ones go on waiting.
"""

from __future__ import annotations

from collections import deque
from typing import Callable, NamedTuple

import numpy as np

from wrenchd.service.pipeline.config import PolicyConfig


class DelayLine:
    """Samples ``(t [s], window (W, 12), step-1 torque (6,), measured torque (6,))`` waiting,
    in preallocated arrays (a slice from the oldest to the newest): dropping a contact's
    onset (seconds of samples at 1 kHz) is moving an index, not freeing thousands of arrays
    one by one, which stalled the estimates behind it for milliseconds.

    Args:
        policy: ``release_delay_s`` and ``onset_margin_s``.
        history: how many estimated samples' times are kept to find a contact's onset time.
        capacity: samples the arrays hold at first (they grow as needed).
    """

    def __init__(self, policy: PolicyConfig, history: int = 8192, capacity: int = 1024) -> None:
        self.policy = policy
        self.times: deque[float] = deque(maxlen=history)   # times of the last estimated samples
        self.estimated = 0                                  # index of the next estimated sample
        self._capacity = capacity
        self._t = np.empty(capacity)
        self._rows: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # window, step 1,
        self._head = self._tail = 0                         # measured; allocated at the first

    def estimated_at(self, t: float) -> int:
        """Note an estimated sample at ``t`` [s]; its index."""
        index = self.estimated
        self.estimated += 1
        self.times.append(t)
        return index

    @property
    def last_t(self) -> float | None:
        """Time [s] of the latest estimated sample (None before the first)."""
        return self.times[-1] if self.times else None

    @property
    def waiting(self) -> int:
        """Samples waiting now."""
        return self._tail - self._head

    def waiting_times(self) -> np.ndarray:
        """Times [s] of the samples waiting, oldest first (a copy)."""
        return self._t[self._head:self._tail].copy()

    def clear(self) -> None:
        """Forget the waiting samples (a gap or a new timeline: the line spans neither)."""
        self._head = self._tail                 # never back to 0: see release()

    def push(self, t: float, window: np.ndarray, step1: np.ndarray, measured: np.ndarray) -> None:
        """Queue one sample (its arrays are copied)."""
        if self._rows is None:
            self._rows = tuple(np.empty((self._capacity, *np.shape(a)), np.asarray(a).dtype)
                               for a in (window, step1, measured))
        if self._tail == self._capacity:
            self._make_room()
        i = self._tail
        self._t[i] = t
        win, s1, meas = self._rows
        win[i] = window
        s1[i] = step1
        meas[i] = measured
        self._tail = i + 1

    def _make_room(self) -> None:
        """Move the waiting samples to the front of new arrays (twice as large when they
        fill more than half); the old ones are left as they are, for the released views."""
        head, n = self._head, self._tail - self._head
        if n > self._capacity // 2:
            self._capacity *= 2
        arrays = (self._t, *self._rows)
        fresh = [np.empty((self._capacity, *a.shape[1:]), a.dtype) for a in arrays]
        for new, old in zip(fresh, arrays):
            new[:n] = old[head:head + n]
        self._t, self._rows = fresh[0], tuple(fresh[1:])
        self._head, self._tail = 0, n

    def release(self, t: float) -> Released | None:
        """The samples that have waited ``release_delay_s`` by ``t`` [s], oldest first, or
        None. Views of the line's arrays, and they stay valid: the line only writes past its
        newest sample, into arrays of its own when it moves (``_make_room``), so a released
        slot is never written again."""
        head, tail, delay = self._head, self._tail, self.policy.release_delay_s
        if head == tail or not t - self._t[head] >= delay:
            return None
        if tail - head == 1 or not t - self._t[head + 1] >= delay:
            k = 1                                          # the usual case: one in, one out
        else:                                              # times increase: a leading run
            k = int(np.count_nonzero(t - self._t[head:tail] >= delay))
        end = head + k
        self._head = end
        win, s1, meas = self._rows
        return Released(self._t[head:end], win[head:end], s1[head:end], meas[head:end])

    def drop_onset(self, contact_started: int) -> int:
        """Drop the waiting samples that may belong to the contact the gate is in: from
        ``onset_margin_s`` before its onset (the index of the sample it began at) on, all of
        them when the onset is unknown or no longer in the history. The number dropped."""
        head, tail = self._head, self._tail
        if head == tail:
            return 0
        first = self.estimated - len(self.times)            # index of the oldest time kept
        if contact_started < first:
            self._tail = head
            return tail - head
        return self.drop_since(self.times[contact_started - first] - self.policy.onset_margin_s)

    def drop_since(self, t: float) -> int:
        """Drop the waiting samples from ``t`` [s] on; the number dropped."""
        head, tail = self._head, self._tail
        self._tail = head + int(np.searchsorted(self._t[head:tail], t, side="left"))
        return tail - self._tail


class Released(NamedTuple):
    """Samples released together: ``t`` (N,) [s], ``window`` (N, W, 12), ``step1`` and
    ``measured`` (N, 6) torques."""

    t: np.ndarray
    window: np.ndarray
    step1: np.ndarray
    measured: np.ndarray


def offer_rows(backend, ready: Released | None,
               on_offer: Callable[[np.ndarray], None] | None) -> int:
    """Hand released samples to the adaptation ``backend`` in one call; the number offered."""
    if ready is None:
        return 0
    backend.offer(ready.window, ready.step1, ready.measured, ready.t)
    if on_offer is not None:
        on_offer(ready.t)
    return len(ready.t)
