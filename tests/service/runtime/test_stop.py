"""A clean stop: SIGTERM to ``wrenchd serve`` while it estimates and adapts ends it, every
child process ending by itself (none killed, no stage waiting out its bound) and the MCAP log
finished.

The daemon runs as a real subprocess with an external robot (a joint-state stream published
here over zenoh at 200 Hz, calibration 2 s so that adaptation rounds run and send their
results while the stop comes) and with the embedded simulated robot. The stop time (from
``send_signal`` to ``wait`` returning) is printed, not held to a speed: how fast a stop is
is measured alone by ``service/bench/stop_signals.py``; here it is bounded only so that a
hang fails (the daemon's own watchdog would end it with exit 3 after its bound).

A child that does not stop when asked is killed by the daemon, which says so on stderr
(``killed it``); the last test makes the adaptation worker unresponsive (SIGSTOP) to check that
this is said.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from wrenchd.adapters.mcap_log import TOPIC_EVENTS
from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.messages import encode_joint_state
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session

from tests.support import (
    children_of,
    communicate_within,
    free_port,
    read_mcap,
    readline_within,
    wait_for,
    write_config,
)

HANG_S = 20.0               # SIGTERM to exit, beyond which the stop hung [s]
STREAM_S = 10.0             # joint states streamed before the stop [s]: rounds run from ~5 s
RATE_HZ = 200.0
KILLED = "killed it"        # what the daemon says of a child it had to kill (stderr)


def _sigterm_seconds(proc: subprocess.Popen) -> float:
    """Seconds from SIGTERM to ``proc``'s exit (waiting at most 30 s; the caller's checks and
    its ``finally`` deal with one still running)."""
    start = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=30.0)
    except subprocess.TimeoutExpired:
        pass
    return time.monotonic() - start


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a process that has not ended (a zombie has ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state not in ("Z", "X")


def _line_with(proc: subprocess.Popen, text: str, timeout: float, what: str) -> None:
    """Read ``proc``'s stdout up to a line containing ``text`` (other lines, warnings, are
    skipped), within ``timeout`` seconds in all."""
    deadline = time.monotonic() + timeout
    while text not in readline_within(proc, max(0.1, deadline - time.monotonic()), what):
        pass


def _nice(pid: int) -> int:
    """The nice value of ``pid`` (the adaptation worker runs at 10, the log writer at 0)."""
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


class _Publisher:
    """Joint states of a simulated scenario published in real time on ``key`` from a thread
    of this process, until stopped."""

    def __init__(self, endpoint: str, key: str, seconds: float) -> None:
        self.js = run_scenario("free-space-seal", seconds, 3).joint_states
        self.session = open_session(ZenohConfig(connect=[endpoint]))
        self.pub = self.session.declare_publisher(key)
        self.sent = 0
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _run(self) -> None:
        js, start = self.js, time.monotonic()
        for i in range(len(js)):
            delay = start + js.t[i] - time.monotonic()
            if delay > 0 and self._stop.wait(delay):
                return
            if self._stop.is_set():
                return
            self.pub.put(encode_joint_state("json", round(js.t[i] * 1e9), js.names,
                                            js.position[i], js.velocity[i], js.effort[i]))
            self.sent += 1

    def close(self) -> None:
        self._stop.set()
        self.thread.join(timeout=5.0)
        self.pub.undeclare()
        self.session.close()


def _serve_and_stop(tmp: Path, robot: str) -> tuple[float, str, dict[int, tuple[str, int]],
                                                     Path]:
    """One daemon run: start, stream (or let the simulated robot stream) while it adapts,
    SIGTERM. Returns (seconds from the signal to its exit, its stdout + stderr, its children
    before the signal by pid with their command lines and nice values, its log
    directory)."""
    tmp.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    logs = tmp / "logs"
    config = write_config(tmp / "wrenchd.toml", endpoint, "json", logs)
    # rounds from the first hundred free-motion samples on, every half second
    config.write_text(config.read_text() + "[arms.pipeline.adaptation]\n"
                      "min_train_samples = 100\ninterval_s = 0.5\n")
    if robot == "simulated":
        text = config.read_text().replace('robot = "external"', 'robot = "simulated"')
        config.write_text(text + "\n[simulator]\nscenario = \"free-space-seal\"\nseed = 4\n")
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    publisher = None
    try:
        _line_with(daemon, "listening", 120.0, "the daemon")
        if robot == "external":
            publisher = _Publisher(endpoint, "dvrk/PSM2/measured_js", STREAM_S + 30.0)
            time.sleep(0.5)                      # the subscription reaches the publisher
            publisher.start()
        else:
            _line_with(daemon, "simulated PSM2", 60.0, "the simulated robot")
        time.sleep(STREAM_S)
        children = {pid: (_cmdline(pid), _nice(pid)) for pid in children_of(daemon.pid)}
        elapsed = _sigterm_seconds(daemon)
    finally:
        if publisher is not None:
            publisher.close()
        out, err = communicate_within(daemon, 30.0, "the daemon")
    assert daemon.returncode == 0, err[-2000:]
    return elapsed, out + err, children, logs


def _check_run(tmp: Path, robot: str) -> float:
    elapsed, output, children, logs = _serve_and_stop(tmp, robot)
    assert KILLED not in output, output[-3000:]
    assert "Traceback" not in output, output[-3000:]
    spawned = {pid: nice for pid, (cmd, nice) in children.items()
               if "multiprocessing.spawn" in cmd}
    # the adaptation worker (nice 10) and the log writer (nice 0)
    assert sorted(spawned.values()) == [0, 10], children
    if robot == "simulated":
        assert any("wrenchd robot" in cmd for cmd, _ in children.values()), children
    # the daemon joined them before it exited; the resource tracker (multiprocessing's)
    # ends on the daemon's exit, so it gets a moment
    still = [pid for pid in spawned if _alive(pid)]
    assert not still, f"children alive after the daemon exited: {still}"
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline and any(_alive(p) for p in children):
        time.sleep(0.05)
    assert not any(_alive(p) for p in children), {p: children[p] for p in children
                                                  if _alive(p)}
    files = sorted(logs.glob("PSM2-*.mcap"))
    assert len(files) == 1, files
    session, info = read_session_report(files[0], allow_truncated=False)
    assert not info.truncated
    assert len(session.joint_states) > STREAM_S * RATE_HZ * 0.5
    events = read_mcap(files[0]).get(TOPIC_EVENTS, [])
    assert any(b'"round"' in e for e in events), "no adaptation round ran before the stop"
    return elapsed


@pytest.mark.parametrize("robot", ["external", "simulated"])
def test_sigterm_stops_everything_cleanly(tmp_path, robot):
    elapsed = _check_run(tmp_path / "run0", robot)
    print(f"stop time ({robot}): {elapsed:.2f} s")
    assert elapsed < HANG_S, elapsed


def _start_daemon(tmp: Path) -> subprocess.Popen:
    """``wrenchd serve`` on a free port, JSON wire, its log under ``tmp/logs``."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp / "wrenchd.toml", endpoint, "json", tmp / "logs")
    return subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config", str(config)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_a_worker_that_does_not_stop_is_killed_and_said_so(tmp_path):
    """The daemon's adaptation worker is frozen (SIGSTOP): at SIGTERM the daemon waits its
    bound for it, kills it, says so on stderr, and still finishes its log and exits 0."""
    daemon = _start_daemon(tmp_path)
    try:
        _line_with(daemon, "listening", 120.0, "the daemon")
        # the worker lowers its priority once started
        wait_for(lambda: any(_nice(p) == 10 for p in children_of(daemon.pid)), 60.0,
                 "the adaptation worker (nice 10)")
        workers = [pid for pid in children_of(daemon.pid) if _nice(pid) == 10]
        assert len(workers) == 1, {p: _cmdline(p) for p in children_of(daemon.pid)}
        os.kill(workers[0], signal.SIGSTOP)
        daemon.send_signal(signal.SIGTERM)
    finally:
        _, err = communicate_within(daemon, 30.0, "the daemon")
    assert daemon.returncode == 0, err[-2000:]
    assert f"the adaptation worker (pid {workers[0]})" in err and KILLED in err, err[-2000:]
    assert not _alive(workers[0])
    files = sorted((tmp_path / "logs").glob("PSM2-*.mcap"))
    assert len(files) == 1 and not read_session_report(files[0])[1].truncated


def test_a_daemon_stopped_at_once_leaves_its_final_status(tmp_path):
    """SIGTERM right after the daemon listens, before its first status (1 s in): the log
    still holds one finished file, ending with the final status record."""
    from mcap.reader import make_reader

    from wrenchd.adapters.mcap_log import TOPIC_STATUS

    daemon = _start_daemon(tmp_path)
    try:
        _line_with(daemon, "listening", 120.0, "the daemon")
        daemon.send_signal(signal.SIGTERM)
    finally:
        _, err = communicate_within(daemon, 30.0, "the daemon")
    assert daemon.returncode == 0, err[-2000:]
    files = sorted((tmp_path / "logs").glob("PSM2-*.mcap"))
    assert len(files) == 1
    with open(files[0], "rb") as f:
        records = [m for _, channel, m in make_reader(f).iter_messages()
                   if channel.topic == TOPIC_STATUS]
    assert records
    text = records[-1].data.decode("utf-8", "replace")
    assert '"estimated"' in text and '"arm"' in text, text[:300]


def test_the_simulated_robot_stops_cleanly_before_it_publishes(tmp_path):
    """SIGTERM while ``wrenchd robot`` simulates its first block or waits for a subscriber
    (none comes) ends it, its recording finished (no samples in it)."""
    from mcap.reader import make_reader

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = subprocess.Popen(
        [sys.executable, "-m", "wrenchd", "robot", "--scenario", "trocar-contact", "--arm",
         "PSM2", "--listen", endpoint, "--out-dir", str(tmp_path), "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # the recording is opened, then the block simulated (under a second), then the
        # subscriber awaited (seconds): the signal comes in one of the two
        wait_for(lambda: any(tmp_path.glob("PSM2-*.mcap")), 60.0, "the robot's recording")
        time.sleep(0.3)
        elapsed = _sigterm_seconds(robot)
    finally:
        out, err = communicate_within(robot, 30.0, "the robot")
    assert robot.returncode == 0, err[-2000:]
    assert "stopped after 0 samples" in out, out
    print(f"robot stop time: {elapsed:.2f} s")
    assert elapsed < HANG_S, elapsed
    with open(next(tmp_path.glob("PSM2-*.mcap")), "rb") as f:
        assert make_reader(f).get_summary() is not None       # finished: summary and footer
