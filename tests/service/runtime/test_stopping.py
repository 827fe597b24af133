"""Stop signals: a handler that cannot deadlock, and real processes stopped by bursts of them.

How fast a stop is, is measured by ``python -m wrenchd.service.bench.stop_signals``; these
tests only bound it generously, to tell a stop from a hang.
"""

from __future__ import annotations

import doctest
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tests.support import free_port
from wrenchd.service.runtime import stopping

HANG_S = 20.0      # a process still running this long after the signals has hung


def test_doctest():
    assert doctest.testmod(stopping).failed == 0


# The handler is re-entered at every line that runs beneath it, by a trace function: a
# deterministic stand-in for a second signal arriving at each point of the first's handling.
# With a handler that takes a lock (Event.set, as the daemon's did), the nested call blocks on
# the lock its outer call holds, forever; the flag handler returns.
_REENTER = textwrap.dedent("""
    import signal, sys, threading
    from wrenchd.service.runtime.stopping import StopSignals, check, Stopped

    kind = sys.argv[1]

    with StopSignals() as stop:
        if kind == "event":                       # a handler that takes a lock: it hangs
            event = threading.Event()
            def handler(signum, frame):
                event.set()
            signal.signal(signal.SIGINT, handler)
        else:
            handler = stop._handler

        def reenter_at(call, k):
            # calls call(); at the k-th line run beneath it (outside this script), calls the
            # handler once more; returns whether that line was reached
            seen = [0, False]
            def trace(frame, why, arg):
                if frame.f_code.co_filename == "<string>":
                    return trace
                if why == "line" and not seen[1]:
                    if seen[0] == k:
                        seen[1] = True
                        handler(signal.SIGTERM, frame)    # the second signal, here
                    seen[0] += 1
                return trace
            sys.settrace(trace)
            try:
                call()
            finally:
                sys.settrace(None)
            return seen[1]

        def every_line(call):
            k = 0
            while reenter_at(call, k):
                k += 1
            return k

        lines = every_line(lambda: handler(signal.SIGINT, None))
        # and the stop path itself, re-entered at each of its lines in turn
        lines += every_line(lambda: stop.wait(0.0))
        lines += every_line(lambda: stop.bound(60.0))
        try:
            check()
        except Stopped as exc:
            print("stopped", exc, "re-entered at", lines, "lines")
    """)


@pytest.mark.parametrize("kind, hangs", [("flag", False), ("event", True)])
def test_handler_reentered_at_every_line(kind, hangs):
    proc = subprocess.Popen([sys.executable, "-c", _REENTER, kind], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        out, err = proc.communicate(timeout=10.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        assert hangs, "the flag handler deadlocked when re-entered"
        return
    assert not hangs, f"the lock-taking handler was expected to deadlock: {out} {err}"
    assert proc.returncode == 0, err
    assert out.startswith("stopped SIG"), out
    assert int(out.split()[4]) >= 5, out        # the trace reached the code beneath


def test_a_stop_past_its_bound_says_what_it_waited_for():
    code = textwrap.dedent("""
        import os, signal, time
        from wrenchd.service.runtime import stopping
        with stopping.StopSignals() as stop:
            os.kill(os.getpid(), signal.SIGTERM)
            stop.wait(1.0)
            stop.bound(0.3)
            stopping.stage("a child that never ends")
            time.sleep(30)
        """)
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=HANG_S)
    assert proc.returncode == stopping.EXIT_STOP_HUNG
    assert "waiting for a child that never ends" in proc.stderr
    assert time.monotonic() - t0 < 15.0


def _burst(pid: int, group: bool, gap_s: float, n: int = 2) -> float:
    """Send SIGINT then SIGTERM (and more, alternating) ``gap_s`` apart; the first's time."""
    kill = os.killpg if group else os.kill
    sent = time.monotonic()
    for k in range(n):
        if k:
            until = time.perf_counter() + gap_s
            while time.perf_counter() < until:
                pass
        kill(pid, signal.SIGINT if k % 2 == 0 else signal.SIGTERM)
    return sent


def _finished(path: Path) -> bool:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        return make_reader(f).get_summary() is not None


@pytest.mark.parametrize("n, gap_s, group", [(2, 0.0, True), (6, 50e-6, False)])
def test_serve_stops_cleanly_under_a_burst(tmp_path, n, gap_s, group):
    env = dict(os.environ, WRENCHD_LOG__DIRECTORY=str(tmp_path),
               WRENCHD_ZENOH__LISTEN=json.dumps([f"tcp/127.0.0.1:{free_port()}"]))
    proc = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--duration", "120"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        for line in proc.stdout:
            if " Hz " in line:                     # serving: the first status line
                break
        sent = _burst(proc.pid, group, gap_s, n)
        out, _ = proc.communicate(timeout=HANG_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 0, out
    assert time.monotonic() - sent < HANG_S
    assert "PSM1 stopped:" in out
    logs = sorted(tmp_path.rglob("*.mcap"))
    assert logs and all(_finished(p) for p in logs), [p.name for p in logs]
    if not group:                                   # the robot was not signalled: asked by
        assert "wrenchd robot: stopped" in out      # the daemon, and ended


def test_robot_stops_under_a_burst(tmp_path):
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "wrenchd", "robot", "--scenario", "trocar-contact",
         "--duration", "120", "--listen", f"tcp/127.0.0.1:{port}", "--out-dir", str(tmp_path),
         "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(3.0)                         # simulating or waiting for its subscriber
    _burst(proc.pid, False, 20e-6, 4)
    out, _ = proc.communicate(timeout=HANG_S)
    assert proc.returncode == 0, out
    assert "wrenchd robot: stopped" in out
    assert all(_finished(p) for p in tmp_path.glob("*.mcap"))


def test_replay_stops_between_batches_with_the_signal_in_its_status(tmp_path):
    out_file = tmp_path / "replay.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "wrenchd", "replay", "sim:trocar-contact:600:3", "-o",
         str(out_file)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # signalled once it says it is estimating: simulating the session comes before, and a
        # fast machine estimates all of it in a few seconds
        said = proc.stderr.readline()
        _burst(proc.pid, False, 0.0, 3)
        out, err = proc.communicate(timeout=HANG_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert "wrenchd replay: estimating 120000 samples" in said, said
    assert proc.returncode == 128 + signal.SIGINT, (out, err)
    assert "stopped by SIGINT" in err
    assert "Traceback" not in err
    assert not out_file.exists()            # no partial result
