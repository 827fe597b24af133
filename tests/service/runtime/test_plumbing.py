"""The estimation thread's gathering of the arms' samples (``[ring] gather_us``), with real
threads putting into real rings."""

import threading
import time

from wrenchd.service.runtime.plumbing import SampleRing, gather


def rings(n):
    wake = threading.Event()
    return [SampleRing(16, wake) for _ in range(n)], wake


def put_later(ring, delay_s):
    timer = threading.Timer(delay_s, ring.put, args=((time.perf_counter_ns(), b"x"),))
    timer.start()
    return timer


def test_waits_for_the_other_streaming_arms_sample():
    (a, b, c), wake = rings(3)
    for ring in (a, b, c):                       # all three stream
        ring.put((0, b"x"))
        ring.drain()
    a.put((0, b"x"))
    timer = put_later(b, 0.02)
    timer2 = put_later(c, 0.03)
    start = time.monotonic()
    assert gather([a, b, c], wake, window_s=5.0)
    waited = time.monotonic() - start
    timer.join()
    timer2.join()
    assert 0.02 <= waited < 2.5, waited          # until the last one came, not the window
    assert a.pending == b.pending == c.pending == 1


def test_gives_up_after_the_window_and_does_not_wait_for_silent_arms():
    (a, b), wake = rings(2)
    a.put((0, b"x"))
    b.put((0, b"x"))
    b.drain()                                    # b streams but has nothing queued
    start = time.monotonic()
    assert not gather([a, b], wake, window_s=0.01)
    assert time.monotonic() - start >= 0.01
    (a, b), wake = rings(2)                      # b never streamed: not waited for
    a.put((0, b"x"))
    start = time.monotonic()
    assert gather([a, b], wake, window_s=5.0)
    assert time.monotonic() - start < 2.5
    b.put((0, b"x"))
    b.drain()                                    # b streamed, but longer ago than streaming_s
    time.sleep(0.03)
    start = time.monotonic()
    assert gather([a, b], wake, window_s=5.0, streaming_s=0.02)
    assert time.monotonic() - start < 2.5


def test_a_stop_ends_the_wait():
    (a, b), wake = rings(2)
    a.put((0, b"x"))
    b.put((0, b"x"))
    b.drain()
    stop = threading.Event()
    threading.Timer(0.02, lambda: (stop.set(), wake.set())).start()
    start = time.monotonic()
    assert not gather([a, b], wake, window_s=10.0, stop=stop)
    assert time.monotonic() - start < 5.0
