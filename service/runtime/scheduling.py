"""One compute thread per process for the service's hot paths.

NumPy's BLAS (OpenBLAS) starts a thread per core unless ``OMP_NUM_THREADS`` says otherwise,
and NumPy is imported before any command could set that variable. The daemon, its
adaptation worker and replay each run their own small matrix products on a machine whose
cores they share with each other: BLAS threads of their own busy-wait against them (a
replay runs about 3x slower with them). :func:`one_compute_thread` limits BLAS through
threadpoolctl, whatever was imported first, and torch to one intra-op thread.

:func:`realtime` and :func:`normal_scheduling` move threads in and out of the kernel's
real-time class (``SCHED_FIFO``): the daemon's ``[cpus] realtime_priority`` setting puts the
threads a sample passes through ahead of everything else that runs on the machine.
"""

from __future__ import annotations

import os
from contextlib import contextmanager

from wrenchd.models.errors import ConfigError

#: The real-time priority ``auto`` takes: low in the 1-99 range, under a robot controller's own.
AUTO_REALTIME_PRIORITY = 10


#: Linux scheduling policies by number, as the status names them.
POLICY_NAMES = {os.SCHED_OTHER: "SCHED_OTHER", os.SCHED_FIFO: "SCHED_FIFO",
                os.SCHED_RR: "SCHED_RR", os.SCHED_BATCH: "SCHED_BATCH",
                os.SCHED_IDLE: "SCHED_IDLE"}


def thread_scheduling(tid: int) -> dict[str, object]:
    """The scheduling class the kernel gives thread ``tid`` now: ``{"class": "SCHED_FIFO",
    "priority": 10}`` (priority 0 in the normal class), or ``{"class": None}`` for a thread
    that is gone."""
    try:
        policy = os.sched_getscheduler(tid)
        priority = os.sched_getparam(tid).sched_priority
    except OSError:
        return {"class": None, "priority": None}
    return {"class": POLICY_NAMES.get(policy & 0xFF, str(policy)), "priority": priority}


def one_compute_thread() -> None:
    """Limit NumPy's BLAS and torch to one thread in this process."""
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(1)
    threadpool_limits(1)


def idle_priority() -> None:
    """Run the calling thread only where a core would otherwise idle: Linux's ``SCHED_IDLE``
    (any other thread that wakes takes its core at once), or the lowest nice value where
    that class is missing. Work that nobody waits for yet (a replay's step 1 ahead of its
    pipeline) then uses the time the other threads leave, never theirs. Best effort: a
    thread that may not change class stays as it was."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        try:
            os.setpriority(os.PRIO_PROCESS, 0, 19)      # on Linux: this thread alone
        except (AttributeError, OSError):
            pass


def realtime(priority: int, tid: int = 0) -> None:
    """Run thread ``tid`` (0: the calling thread, and the threads and processes it starts from
    now on) under ``SCHED_FIFO`` at ``priority`` (1-99). Raises :class:`ConfigError` saying what
    to do where this process may not (it needs ``CAP_SYS_NICE`` or an ``rtprio`` limit)."""
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError as exc:
        raise ConfigError(
            f"cpus.realtime_priority = {priority}: this process may not use real-time "
            f"scheduling ({exc.strerror}); give it CAP_SYS_NICE or an rtprio limit of at "
            f"least {priority} (ulimit -r, /etc/security/limits.conf), or leave the setting "
            f"unset") from None


def realtime_below(priority: int, tid: int = 0) -> None:
    """Thread ``tid`` (0: the calling thread) one step under ``priority`` in the real-time
    class: the threads that take the GIL beside a real-time sample path, which a normal-class
    thread preempted while holding it would hold up, but which must never preempt it."""
    realtime(max(1, priority - 1), tid)


def enter_realtime(setting: int | str) -> int | None:
    """Put the calling thread (and what it starts from now on) in the real-time class as a
    ``realtime_priority`` ``setting`` says: ``off``, none; ``auto``, at
    :data:`AUTO_REALTIME_PRIORITY` where this process may, else none; a priority, that one or
    :class:`ConfigError`. Returns the priority taken, or None."""
    if setting == "off":
        return None
    priority = AUTO_REALTIME_PRIORITY if setting == "auto" else int(setting)
    try:
        realtime(priority)
    except ConfigError:
        if setting != "auto":
            raise
        return None
    return priority


def normal_scheduling(tid: int = 0) -> None:
    """Put thread ``tid`` (0: the calling thread) back in the normal class (always allowed)."""
    if os.sched_getscheduler(tid) != os.SCHED_OTHER:
        os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))


@contextmanager
def normal_class():
    """The calling thread in the normal class for the block, back in its own class after.

    A process inherits the class of the thread that starts it: one started from a real-time
    thread would run its whole interpreter start-up (~0.5 s of imports) ahead of the sample
    path before it could leave the class itself.
    """
    policy = os.sched_getscheduler(0)
    param = os.sched_getparam(0)
    normal_scheduling()
    try:
        yield
    finally:
        if policy != os.SCHED_OTHER:
            os.sched_setscheduler(0, policy, param)
