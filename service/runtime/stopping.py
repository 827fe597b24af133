"""SIGINT and SIGTERM as a request to stop: a flag, a wake-up, and a bounded stop.

A signal handler runs on the main thread between two bytecodes, wherever that thread is,
including inside the code that is stopping: a handler that takes a lock (``Event.set`` takes
its condition's), logs, allocates or writes can deadlock against the code it interrupted. So
the handler here does one thing, store ``True`` in a plain attribute; the wake-up is the
interpreter's own (``signal.set_wakeup_fd``: its C-level handler writes the signal number to a
non-blocking pipe, async-signal-safe), which ends a :meth:`StopSignals.wait` at once. Any
number of signals at any spacing only store ``True`` again.

Long loops ask :func:`check` between units of work (a batch of samples, a session); it raises
:class:`Stopped`, which the command line turns into exit status 128 + the signal's number.

A stop that does not finish is bounded (:meth:`StopSignals.bound`, :data:`EXIT_STOP_HUNG`).

Usage::

    >>> import signal
    >>> with StopSignals() as stop:
    ...     stop.requested
    ...     signal.raise_signal(signal.SIGTERM)   # a stop request, not the default exit
    ...     stop.wait(1.0)
    False
    True
"""

from __future__ import annotations

import os
import select
import signal
import sys
import threading
import time

#: exit status of a stop that did not finish within its bound
EXIT_STOP_HUNG = 3
#: how long a stop may take before the watchdog ends the process [s]
STOP_BOUND_S = 5.0
SIGNALS = (signal.SIGINT, signal.SIGTERM)

_active: StopSignals | None = None


class Stopped(BaseException):
    """Raised by :func:`check` once a stop was requested. A ``BaseException``, as
    ``KeyboardInterrupt`` is: ``except Exception`` blocks let it through."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class StopSignals:
    """SIGINT/SIGTERM handled as a stop request while the context is entered (main thread
    only; elsewhere, or nested inside another, it is the one already active)."""

    def __init__(self) -> None:
        self.requested = False          # the handler's only write
        self.signum = 0                 # the first signal's number, read after the fact
        self._pipe: tuple[int, int] | None = None
        self._old_handlers: dict = {}
        self._old_fd = -1
        self._outer: StopSignals | None = None
        self._watchdog: threading.Thread | None = None
        self._done = threading.Event()
        self.stage = "the stop to begin"

    def _handler(self, signum, _frame) -> None:
        # Signal context: no lock, no allocation, no I/O (two stores of objects that exist:
        # True and the signal's small int). The pipe write is the interpreter's.
        if not self.requested:
            self.signum = signum
        self.requested = True

    def __enter__(self) -> StopSignals:
        global _active
        if _active is not None or threading.current_thread() is not threading.main_thread():
            self._outer = _active
            return _active if _active is not None else self
        r, w = os.pipe()
        os.set_blocking(r, False)
        os.set_blocking(w, False)
        self._pipe = (r, w)
        self._old_fd = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        self._old_handlers = {s: signal.signal(s, self._handler) for s in SIGNALS}
        _active = self
        return self

    def __exit__(self, *exc) -> None:
        global _active
        if self._pipe is None:
            return
        for s, handler in self._old_handlers.items():
            signal.signal(s, handler)
        signal.set_wakeup_fd(self._old_fd)
        self._done.set()
        for fd in self._pipe:
            os.close(fd)
        self._pipe = None
        _active = None

    def wait(self, timeout: float) -> bool:
        """Whether a stop was requested, waiting up to ``timeout`` seconds for one."""
        if self.requested or self._pipe is None:
            if not self.requested and timeout > 0:
                time.sleep(timeout)
            return self.requested
        try:
            select.select([self._pipe[0]], [], [], timeout)
            while os.read(self._pipe[0], 512):
                pass
        except (BlockingIOError, InterruptedError):
            pass
        return self.requested

    def first_signal(self) -> int:
        """The number of the signal that asked to stop (SIGINT if it cannot be told)."""
        return self.signum or int(signal.SIGINT)

    def bound(self, bound_s: float = STOP_BOUND_S) -> None:
        """Arm the watchdog (once, when the stop begins): a thread that, if this context has
        not been left ``bound_s`` seconds from now, prints which stage the stop waits for
        (:func:`stage`) and ends the process with :data:`EXIT_STOP_HUNG`. The daemon's log
        files are safe: their writer process finishes them by itself when the daemon is
        gone."""
        if self._watchdog is not None:
            return
        self._watchdog = threading.Thread(target=self._watch, args=(bound_s,),
                                          name="wrenchd-stop-watchdog", daemon=True)
        self._watchdog.start()

    def _watch(self, bound_s: float) -> None:
        if self._done.wait(bound_s):
            return
        try:
            sys.stderr.write(f"wrenchd: error: the stop did not finish within {bound_s:g} s "
                             f"(waiting for {self.stage}); exiting without it\n")
            sys.stderr.flush()
        finally:
            os._exit(EXIT_STOP_HUNG)


def active() -> StopSignals | None:
    """The stop request of the running command, if one is handled."""
    return _active


def requested() -> bool:
    """Whether a stop was requested (False where none is handled)."""
    return _active is not None and _active.requested


def check() -> None:
    """Raise :class:`Stopped` if a stop was requested, arming its bound."""
    stop = _active
    if stop is not None and stop.requested:
        stop.bound()
        raise Stopped(stop.first_signal())


def stage(what: str) -> None:
    """Name what the stop waits for now (said if the stop exceeds its bound)."""
    if _active is not None:
        _active.stage = what
