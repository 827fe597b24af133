"""The zenoh network failing under a running daemon, with real processes on loopback.

* **Router restart**: a zenoh router (a Python process opening a session in ``router`` mode;
  the zenoh wheel has no ``zenohd``), the daemon (``wrenchd serve``, zenoh client of the
  router, external robot), the simulated robot (``wrenchd robot``, client) and this test's
  subscriber (client). The router is killed with SIGKILL mid-stream and restarted on the
  same port: every client re-connects on its own (``ZenohConfig.retry_period_*``), the
  daemon's subscriber, publishers, queryable and liveliness token come back, wrenches flow
  again, the outage is one ``gap`` event, and the daemon never stopped.
* **Peer publisher restart**: the daemon in peer mode connects to the robot's listening
  endpoint (like a ``zenoh-bridge-ros2dds`` on the dVRK PC); the robot process is killed with
  SIGKILL and a new one started on the same endpoint. Its clock starts again from zero: the
  daemon refuses ``resync_after`` samples as ``time_backwards``, then follows the new
  timeline (``clock_reset``) and estimates on.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from wrenchd.adapters.messages import decode_wrench
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, TOPIC_EVENTS
from tests.support import ROUTER, free_port, read_mcap, readline_within, stop_within, wait_for

KEYS = {k: f"dvrk/PSM2/{v}" for k, v in (("wrench", "wrenchd/measured_cf"),
                                         ("events", "wrenchd/events"),
                                         ("status", "wrenchd/status"),
                                         ("alive", "wrenchd/alive"))}
#: wrenches must flow again within this long after the router (or robot) is back [s], or
#: the daemon did not recover: a hang bound, not a speed (the resume time is printed)
RESUME_S = 15.0

def start_router(endpoint: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", ROUTER, endpoint], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    assert readline_within(proc, 30.0, "the router").strip() == "ready"
    return proc


def spawn_robot(tmp_path: Path, name: str, seed: int, *zenoh_args: str) -> subprocess.Popen:
    """``wrenchd robot`` (PSM2, trocar, JSON; at most 15 s, stopped earlier with SIGINT)."""
    return subprocess.Popen(
        [sys.executable, "-m", "wrenchd", "robot", "--scenario", "trocar", "--seed",
         str(seed), "--arm", "PSM2", "--duration", "15", *zenoh_args,
         "--out-dir", str(tmp_path / name), "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def publishing(robot: subprocess.Popen, name: str) -> None:
    """Returns once the robot publishes (it waits up to 5 s for a subscriber first)."""
    assert "publishing" in readline_within(robot, 90.0, name)


def start_robot(tmp_path: Path, name: str, seed: int, *zenoh_args: str) -> subprocess.Popen:
    robot = spawn_robot(tmp_path, name, seed, *zenoh_args)
    publishing(robot, name)
    return robot


def spawn_daemon(tmp_path: Path, zenoh_toml: str) -> subprocess.Popen:
    config = tmp_path / "wrenchd.toml"
    config.write_text(f"""
robot = "external"
[zenoh]
{zenoh_toml}
[log]
directory = "{tmp_path / 'logs'}"
[[arms]]
name = "PSM2"
encoding = "json"
[arms.pipeline]
calibration_s = 2.0
[arms.pipeline.adaptation]
min_train_samples = 200                  # rounds (and swaps) within the first seconds
""")
    return subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                             str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def serving(daemon: subprocess.Popen) -> None:
    """Returns once the daemon has declared its subscriber and publishers."""
    assert KEYS["wrench"] in readline_within(daemon, 120.0, "the daemon")


class Listener:
    """This test's zenoh session: wrenches (with arrival times) and events of PSM2."""

    def __init__(self, config: ZenohConfig) -> None:
        self.session = open_session(config)
        self.wrenches: list[tuple[float, int]] = []          # (arrival [s], stamp [ns])
        self.events: list[dict] = []
        self.subs = [
            self.session.declare_subscriber(KEYS["wrench"], lambda s: self.wrenches.append(
                (time.monotonic(), decode_wrench("json", s.payload.to_bytes())[0]))),
            self.session.declare_subscriber(KEYS["events"], lambda s: self.events.append(
                json.loads(s.payload.to_bytes())))]

    def status(self) -> dict:
        replies = list(self.session.get(KEYS["status"], timeout=5.0))
        assert replies and replies[0].ok is not None, "the status queryable did not answer"
        return json.loads(replies[0].ok.payload.to_bytes())

    def alive(self) -> bool:
        return any(r.ok is not None for r in self.session.liveliness().get(KEYS["alive"],
                                                                           timeout=5.0))

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()
        self.session.close()


def stop(proc: subprocess.Popen | None, sig=signal.SIGKILL) -> None:
    if proc is not None and proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate(timeout=10)


def log_stamps(path: Path, topic: str) -> list[int]:
    """The stamps [ns] of ``topic``'s messages in a daemon's MCAP log (its log times)."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return [m.log_time for _, ch, m in make_reader(f).iter_messages() if ch.topic == topic]


def resumed_after(listener: Listener, t0: float, n_before: int) -> float:
    """Seconds from ``t0`` to the first wrench after the first ``n_before`` ones."""
    wait_for(lambda: len(listener.wrenches) >= n_before + 200, RESUME_S,
             "200 wrenches after the restart")
    return listener.wrenches[n_before][0] - t0


def assert_swaps_validated(events: list[dict]) -> int:
    """Every swap the daemon published carries a validation that went down; their number."""
    swaps = [e for e in events if e["kind"] == "model"]
    for e in swaps:
        assert e["val_after"] < e["val_before"], e
    print(f"{len(swaps)} model swaps published, each with val_after < val_before")
    return len(swaps)


def test_router_killed_and_restarted_mid_stream(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    client = f'mode = "client"\nconnect = ["{endpoint}"]'
    router = start_router(endpoint)
    daemon = robot = listener = None
    try:
        daemon = spawn_daemon(tmp_path, client)             # both start at once (seconds each)
        robot = spawn_robot(tmp_path, "robot", 2, "--mode", "client", "--connect", endpoint)
        listener = Listener(ZenohConfig(mode="client", connect=[endpoint]))
        serving(daemon)
        publishing(robot, "robot")
        wait_for(lambda: len(listener.wrenches) >= 300, 30.0, "wrenches before the fault")

        events_before = len(listener.events)
        router.kill()                                        # SIGKILL: no goodbye to anyone
        router.wait(timeout=10)
        killed = len(listener.wrenches)
        time.sleep(1.0)
        down = len(listener.wrenches)
        t_restart = time.monotonic()
        router = start_router(endpoint)                      # same port
        resume_s = resumed_after(listener, t_restart, down)
        print(f"router restart: wrenches again {resume_s:.2f} s after the new router started")

        # adaptation goes on, on samples that came after the restart: a round whose training
        # set is larger than any before the fault (the buffers hold 9 000 rows, far more than
        # this test streams). Not a swap: a round swaps only if its candidate validates
        # better, which no fixed wait guarantees (60 s were not enough once, under load)
        trained = [e["n_train"] for e in listener.events[:events_before]
                   if e["kind"] == "round"] or [0]
        wait_for(lambda: any(e["kind"] == "round" and e["n_train"] > max(trained)
                             for e in listener.events[:]), 60.0,
                 "a round training on samples from after the router restart")
        assert daemon.poll() is None                         # the daemon never stopped
        assert listener.alive()                              # its liveliness token is back
        status = listener.status()                           # and its queryable answers
        out, err = stop_within(robot, 60.0, "the robot", signal.SIGINT)   # a clean stop: its count
        assert robot.returncode == 0, err
        published = int(out.strip().splitlines()[-1].split("after ")[1].split()[0])
        time.sleep(1.0)                                      # the last wrenches arrive
        final = listener.status()
        received = len(listener.wrenches)
    finally:
        if listener is not None:
            listener.close()
        stop(robot)
        if daemon is not None:
            stop(daemon, signal.SIGINT)
        if router.poll() is None:
            router.stdin.close()
            router.wait(timeout=10)
    assert daemon.returncode == 0
    c = final["counters"]
    assert status["counters"]["estimated"] > down
    assert c["errors"] == 0 and c["dropped"] == 0
    # the outage (robot publishing into the void) is one gap; the LSTM restarted after it.
    # Its event is read from the daemon's log: it is published on the first sample after the
    # restart, which can beat this subscriber's re-declaration on the new router (CI saw that)
    logs = sorted((tmp_path / "logs").glob("PSM2-*.mcap"))
    logged = [e for log in logs for e in map(json.loads, read_mcap(log)[TOPIC_EVENTS])]
    gaps = [e for e in logged if e["kind"] == "gap"]
    assert c["gaps"] == 1 and len(gaps) == 1 and gaps[0]["gap_s"] > 1.0
    # what the daemon estimated is everything but the outage: the samples its gap spans
    # (the robot stamps one every 5 ms), however long the restart took on a loaded machine
    lost = published - c["estimated"]
    assert lost > 0 and lost == round(gaps[0]["gap_s"] * 200) - 1, (lost, gaps[0])
    # and it reached this subscriber, in order, nothing twice, nothing the daemon did not log,
    # but for what was on its way when the router died, what the daemon published after the
    # restart before this subscriber's route to it was back (the two clients re-connect on
    # their own), and what zenoh dropped on the way to this subscriber when it fell behind
    # (zenoh's default for a put drops, never blocks, under congestion): told apart by their
    # stamps against the daemon's log. How many depends on this process's speed, not the
    # daemon's (0-6 on a quiet 2-core machine, 13-130 beside a test suite; a bound of 50 once
    # failed CI): a bound of two seconds of stream tells a stalled route from a queue's worth.
    stamps = np.array([w[1] for w in listener.wrenches[:received]])
    assert np.all(np.diff(stamps) > 0)
    estimated_ns = np.array(sorted(ns for log in logs for ns in log_stamps(log, TOPIC_ESTIMATE)))
    assert len(estimated_ns) == c["estimated"]
    assert np.setdiff1d(stamps, estimated_ns).size == 0
    resumed = int(np.argmax(np.diff(estimated_ns))) + 1      # the first estimate after the outage
    missed = np.setdiff1d(estimated_ns, stamps)
    before = int(np.sum(missed < estimated_ns[resumed]))
    print(f"wrenches not received: {before} before the outage, {len(missed) - before} after it")
    assert len(missed) < 2.0 * 200, len(missed)
    # with the router dead, only wrenches already on their way arrived
    assert np.all(stamps[killed:down] < estimated_ns[resumed])
    assert assert_swaps_validated(listener.events) >= 1      # adaptation went on
    # the daemon saw its router go and come back: both are in its log (the first was
    # published to nobody), and its status counts the loss
    assert final["zenoh"]["link_losses"] == 1 and final["zenoh"]["routers"] == 1, final["zenoh"]
    links = [e for e in logged if e["kind"] == "zenoh_link"]
    assert [(e["routers"], e["lost"]) for e in links] == [(0, True), (1, False)], links


def test_peer_publisher_killed_and_restarted(tmp_path):
    robot_ep = f"tcp/127.0.0.1:{free_port()}"
    daemon_ep = f"tcp/127.0.0.1:{free_port()}"
    peer = f'mode = "peer"\nlisten = ["{daemon_ep}"]\nconnect = ["{robot_ep}"]'
    daemon = robot = listener = None
    try:
        daemon = spawn_daemon(tmp_path, peer)                # may open before its robot listens
        robot = spawn_robot(tmp_path, "robot1", 2, "--mode", "peer", "--listen", robot_ep)
        serving(daemon)
        listener = Listener(ZenohConfig(connect=[daemon_ep]))
        publishing(robot, "robot1")
        wait_for(lambda: len(listener.wrenches) >= 300, 30.0, "wrenches before the fault")

        robot.kill()                                         # the publisher dies
        robot.communicate(timeout=10)
        time.sleep(0.5)
        down = len(listener.wrenches)
        last_stamp = listener.wrenches[-1][1]
        robot = start_robot(tmp_path, "robot2", 3, "--mode", "peer", "--listen", robot_ep)
        t_publishing = time.monotonic()                      # it saw the daemon subscribed
        resume_s = resumed_after(listener, t_publishing, down)
        print(f"publisher restart: wrenches again {resume_s:.2f} s after it published")
        assert daemon.poll() is None
        status = listener.status()
        _, err = stop_within(robot, 60.0, "the robot", signal.SIGINT)
        assert robot.returncode == 0, err
    finally:
        if listener is not None:
            listener.close()
        stop(robot)
        if daemon is not None:
            stop(daemon, signal.SIGINT)
    assert daemon.returncode == 0
    c = status["counters"]
    # the new robot's clock starts at 0: refused until the daemon accepts its new timeline
    resync = 40                                              # ValidationConfig.resync_after
    assert c["error_kinds"] == {"time_backwards": resync}, c
    resets = [e for e in listener.events if e["kind"] == "clock_reset"]
    assert len(resets) == 1 and resets[0]["last_ns"] == last_stamp
    after = [w[1] for w in listener.wrenches[down:]]
    assert after[0] < last_stamp and np.all(np.diff(after) > 0)
    assert c["dropped"] == 0
    assert_swaps_validated(listener.events)
