"""The daemon's intake of joint states through one zenoh channel, without Python callbacks.

With callbacks (:class:`~wrenchd.service.runtime.plumbing.SampleRing`), every sample of every
arm runs a Python function on a zenoh thread: it takes the GIL from the estimation thread,
which then waits for it back. With :class:`ChannelIntake` the samples queue inside zenoh (a
bounded ring of its own, in Rust, no GIL) under one subscriber for all the arms, and the
estimation thread takes whatever has arrived when it is ready: one wake-up per pass, no
thread hops per sample.

One subscriber needs one key expression for every arm's ``measured_js``:
:func:`key_pattern` keeps what the keys share and puts ``*`` (or ``$*`` within a chunk) where
they differ (``dvrk/PSM1/measured_js`` and ``dvrk/PSM2/measured_js``:
``dvrk/PSM$*/measured_js``). A sample on a matching key that no arm serves is counted and
dropped (``foreign``).

The estimation thread blocks in the channel's ``recv``, which has no timeout: a tick, an empty
put that only this session sees (``Locality.SESSION_LOCAL``) on the first arm's key, marked
with its own encoding, wakes it for housekeeping, notices and the stop.

What the callback ring counts exactly, the channel cannot: zenoh's ring drops its oldest
sample silently when full. A pass that finds ``capacity`` samples waiting is counted
(``full``): samples were most likely lost there, how many is unknown.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence

from wrenchd.adapters.zenoh_io import local_publisher, ring_subscriber, sample_mark
from wrenchd.models.errors import ConfigError

#: the encoding that marks a tick (never a joint state)
TICK_ENCODING = "wrenchd/tick"


def key_pattern(keys: Sequence[str]) -> str | None:
    """One key expression matching every key of ``keys``, as narrow as chunk-wise
    wildcards make it; None when the keys have different numbers of chunks (or a differing
    chunk is a verbatim ``@`` chunk, which no wildcard matches)."""
    if not keys:
        raise ConfigError("key_pattern needs at least one key")
    split = [k.split("/") for k in keys]
    if len({len(s) for s in split}) != 1:
        return None
    out = []
    for chunks in zip(*split):
        if len(set(chunks)) == 1:
            out.append(chunks[0])
            continue
        if any(c.startswith("@") for c in chunks):
            return None
        prefix = os.path.commonprefix(list(chunks))
        suffix = os.path.commonprefix([c[len(prefix):][::-1] for c in chunks])[::-1]
        if not prefix and not suffix:
            out.append("*")
        else:                                       # '$*' may be empty: PSM$* matches PSM
            out.append(f"{prefix}$*{suffix}")
    return "/".join(out)


def channel_fits(keys: Sequence[str]) -> bool:
    """Whether one :class:`ChannelIntake` can serve arms with these keys: exact keys (samples
    are handed to the arm whose key they carry) that one key expression fits."""
    return not any("*" in key for key in keys) and key_pattern(keys) is not None


class ChannelIntake:
    """One subscriber (a zenoh ring channel) for the joint states of several arms.

    Args:
        session: the daemon's zenoh session.
        keys: each arm's ``measured_js`` key, in arm order.
        capacity: samples the channel holds (all arms together); beyond, zenoh drops the
            oldest.
    Raises:
        ConfigError: keys that no single expression matches (:func:`key_pattern`), or a key
            that is itself a pattern (``*``: samples are handed to arms by their exact key).
    """

    def __init__(self, session, keys: Sequence[str], capacity: int) -> None:
        if not channel_fits(keys):
            raise ConfigError(f"the channel intake needs exact keys that one key expression "
                              f"fits, got {list(keys)}; use [ring] intake = \"callback\"")
        pattern = key_pattern(keys)
        self.pattern, self.capacity = pattern, capacity
        self.index = {key: i for i, key in enumerate(keys)}
        self.full = 0                # passes that found the channel full (samples lost)
        self.foreign = 0             # samples on a matching key that no arm serves
        self._sub = ring_subscriber(session, pattern, capacity)
        self._tick = local_publisher(session, keys[0], TICK_ENCODING)
        self._closed = False

    def take(self) -> list[list[tuple[int, bytes, str | None]]] | None:
        """Block until something arrives (a sample or a tick), then take everything waiting:
        per arm, in arrival order, ``(taken at [ns] perf_counter, payload, encoding mark)``.
        None once the subscriber is gone."""
        queued: list[list[tuple[int, bytes, str | None]]] = [[] for _ in self.index]
        try:
            sample = self._sub.recv()
        except Exception:  # noqa: BLE001 - the channel closed under us: nothing more comes
            return None
        now = time.perf_counter_ns()
        index, n = self.index, 0
        while sample is not None:
            n += 1
            mark = sample_mark(sample)
            if mark != TICK_ENCODING:
                i = index.get(str(sample.key_expr))
                if i is None:
                    self.foreign += 1
                else:
                    queued[i].append((now, sample.payload.to_bytes(), mark))
            sample = self._sub.try_recv()
        if n >= self.capacity:
            self.full += 1
        return queued

    def tick(self) -> None:
        """Wake the thread blocked in :meth:`take` (an empty pass)."""
        if not self._closed:
            try:
                self._tick.put(b"")
            except Exception:  # noqa: BLE001 - a session being closed
                pass

    def close(self) -> None:
        """Undeclare (after the thread that takes has stopped: a ``recv`` in progress holds
        the channel)."""
        if self._closed:
            return
        self._closed = True
        for entity in (self._sub, self._tick):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - closing must go on
                pass
