"""The gated policy's delay line: a free sample waits for a contact before it may train.

A contact's onset builds up under the gate's bound before the gate sees it, so the samples
just before a detected contact may already be in contact. Every free sample waits
``release_delay_s`` here; when the gate finds a contact, the waiting samples from
``onset_margin_s`` before its onset on are dropped, the older ones go on waiting.
"""

from __future__ import annotations

from collections import deque
from typing import Callable

import numpy as np

from wrenchd.service.pipeline.config import PolicyConfig


class DelayLine:
    """Samples ``(t [s], window (W, 12), step-1 torque (6,), measured torque (6,))`` waiting.

    Args:
        policy: ``release_delay_s`` and ``onset_margin_s``.
        history: how many estimated samples' times are kept to find a contact's onset time.
    """

    def __init__(self, policy: PolicyConfig, history: int = 8192) -> None:
        self.policy = policy
        self.pending: deque[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = deque()
        self.times: deque[float] = deque(maxlen=history)   # times of the last estimated samples
        self.estimated = 0                                  # index of the next estimated sample

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

    def clear(self) -> None:
        """Forget the waiting samples (a gap or a new timeline: the line spans neither)."""
        self.pending.clear()

    def push(self, t: float, window: np.ndarray, step1: np.ndarray, measured: np.ndarray) -> None:
        self.pending.append((t, window, step1, measured.copy()))

    def release(self, t: float) -> list[tuple[float, np.ndarray, np.ndarray, np.ndarray]]:
        """The samples that have waited ``release_delay_s`` by ``t`` [s], oldest first."""
        delay, pending, ready = self.policy.release_delay_s, self.pending, []
        while pending and t - pending[0][0] >= delay:
            ready.append(pending.popleft())
        return ready

    def drop_onset(self, contact_started: int) -> int:
        """Drop the waiting samples that may belong to the contact the gate is in: from
        ``onset_margin_s`` before its onset (the index of the sample it began at) on, all of
        them when the onset is unknown or no longer in the history. The number dropped."""
        pending = self.pending
        if not pending:
            return 0
        first = self.estimated - len(self.times)            # index of the oldest time kept
        if contact_started < first:
            cutoff = -np.inf
        else:
            cutoff = self.times[contact_started - first] - self.policy.onset_margin_s
        n = len(pending)
        while pending and pending[-1][0] >= cutoff:
            pending.pop()
        return n - len(pending)


def offer_rows(backend, ready: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]],
               on_offer: Callable[[np.ndarray], None] | None) -> int:
    """Hand released samples to the adaptation ``backend`` in one call; the number offered."""
    if len(ready) == 1:                  # the usual case: one in, one out; no copies
        t_ready, window, step1, measured = ready[0]
        stamps = np.array([t_ready])
        backend.offer(window[None], step1[None], measured[None], stamps)
    elif ready:
        stamps = np.array([r[0] for r in ready])
        backend.offer(np.stack([r[1] for r in ready]), np.stack([r[2] for r in ready]),
                      np.stack([r[3] for r in ready]), stamps)
    else:
        return 0
    if on_offer is not None:
        on_offer(stamps)
    return len(ready)
