"""The daemon end to end: three real processes on loopback zenoh, in JSON and in ROS 2 CDR.

A ``wrenchd robot`` process publishes joint states, a ``wrenchd serve`` process estimates, and
this test process subscribes to the wrenches and events, queries the status, checks the
liveliness token, injects bad payloads, stops the daemon with SIGINT and reads its MCAP log.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, TOPIC_EVENTS
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.messages import decode_wrench, encode_joint_state, encode_setup_change
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from tests.support import (communicate_within, expect_line, free_port, read_mcap, stop_within,
                           wait_for, write_config)


@pytest.mark.parametrize("encoding", ["json", "cdr"])
def test_daemon_end_to_end(tmp_path, encoding):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    # wrenches express (the default) in JSON, batched by zenoh in CDR: every one arrives
    config = write_config(tmp_path / "wrenchd.toml", endpoint, encoding, tmp_path / "logs",
                          express=encoding == "json")
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    robot = None
    session = None
    wrenches: list[tuple[int, str, np.ndarray, dict]] = []
    events: list[dict] = []
    try:
        expect_line(daemon, "dvrk/PSM2/measured_js", 120.0, "the daemon")
        session = open_session(ZenohConfig(connect=[endpoint]))
        sub_w = session.declare_subscriber(
            "dvrk/PSM2/wrenchd/measured_cf",
            lambda s: wrenches.append(decode_wrench(encoding, s.payload.to_bytes())))
        sub_e = session.declare_subscriber("dvrk/PSM2/wrenchd/events",
                                           lambda s: events.append(json.loads(
                                               s.payload.to_bytes())))
        # the liveliness token says the daemon is up
        alive = list(session.liveliness().get("dvrk/PSM2/wrenchd/alive", timeout=5.0))
        assert any(r.ok is not None for r in alive)
        robot = subprocess.Popen(
            [sys.executable, "-m", "wrenchd", "robot", "--scenario", "trocar", "--seed", "2",
             "--arm", "PSM2", "--duration", "4", "--encoding", encoding, "--connect", endpoint,
             "--out-dir", str(tmp_path / "robot"), "--quiet"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out, err = communicate_within(robot, 120.0, "the robot")
        assert robot.returncode == 0, err
        published = int(out.strip().splitlines()[-1].split("after ")[1].split()[0])
        wait_for(lambda: len(wrenches) >= published, 10.0, "every wrench")
        # bad input from an unknown publisher: refused with an error event, never a crash
        pub = session.declare_publisher("dvrk/PSM2/measured_js")
        pub.put(b"\x00garbage{")
        if encoding == "json":      # a JSON encoder refuses NaN; a foreign publisher may not
            bad = (b'{"header":{"stamp":{"sec":1000,"nanosec":0},"frame_id":""},"name":[],'
                   b'"position":[0,0,0.1,0,0,0],"velocity":[NaN,0,0,0,0,0],'
                   b'"effort":[0,0,0,0,0,0]}')
        else:
            bad = encode_joint_state(encoding, 10**12, ["a"] * 6, [0.0] * 6,
                                     [float("nan")] * 6, [0.0] * 6)
        pub.put(bad)
        pub.undeclare()
        # a set-up change notice (JSON whatever the arm's encoding), and a malformed one
        setup = session.declare_publisher("dvrk/PSM2/setup")
        setup.put(encode_setup_change(None, 20.0, "pressure up"))
        setup.put(b'{"pressure": 20}')
        setup.undeclare()
        wait_for(lambda: sum(e["kind"] == "error" for e in events) >= 3
                 and any(e["kind"] == "setup_change" for e in events), 10.0, "error events")
        replies = list(session.get("dvrk/PSM2/wrenchd/status", timeout=5.0))
        status = json.loads(replies[0].ok.payload.to_bytes())
        sub_w.undeclare()
        sub_e.undeclare()
    finally:
        if session is not None:
            session.close()
        if robot is not None and robot.poll() is None:
            robot.kill()
        d_out, d_err = stop_within(daemon, 60.0, "the daemon", signal.SIGINT)
    assert daemon.returncode == 0, d_err

    # one wrench per published joint state, in order, finite
    assert len(wrenches) == published
    stamps = np.array([w[0] for w in wrenches])
    assert np.all(np.diff(stamps) > 0)
    assert all(np.isfinite(w[2]).all() for w in wrenches)
    if encoding == "json":
        assert all("free" in w[3] and "model_version" in w[3] for w in wrenches)
    # the status answers with the counters, and says which scheduling class the kernel gives
    # the sample path (the real-time class where this process may use it, by default)
    assert status["counters"]["estimated"] == published
    rt = status["realtime_priority"]
    assert status["scheduling"] == ({"class": "SCHED_FIFO", "priority": rt} if rt is not None
                                    else {"class": "SCHED_OTHER", "priority": 0}), status
    assert status["counters"]["errors"] == 3
    assert status["counters"]["error_kinds"] == {"decode": 1, "invalid": 1, "setup": 1}
    assert status["counters"]["setup_changes"] == 1
    assert status["counters"]["setup_dropped"] == 0
    assert status["setup"]["pressure_mmhg"] == 20.0
    assert status["counters"]["dropped"] == 0
    assert status["latency_us"]["p99"] is not None
    assert status["encoding"] == encoding
    kinds = [e.get("error") for e in events if e["kind"] == "error"]
    assert sorted(kinds) == ["decode", "invalid", "setup"]
    change = next(e for e in events if e["kind"] == "setup_change")
    # "now": the last estimated sample's time
    assert change["t"] == pytest.approx(wrenches[-1][0] / 1e9)
    assert change["pressure_mmhg"] == 20.0 and change["note"] == "pressure up"
    assert change["carry_over"] is True
    # the MCAP log: a finished file holding every input, estimate and the error events,
    # readable as a session (replayable)
    logs = sorted((tmp_path / "logs").glob("PSM2-*.mcap"))
    assert len(logs) == 1
    session_log, info = read_session_report(logs[0])
    assert not info.truncated
    assert len(session_log.joint_states) == published
    # every input logged with the values the robot sent (CDR stored as received; the
    # robot's own file keeps its values' mantissas rounded, to 1e-9 relative)
    sent, _ = read_session_report(next((tmp_path / "robot").glob("*.mcap")))
    np.testing.assert_array_equal(session_log.joint_states.t, sent.joint_states.t[:published])
    for field in ("position", "velocity", "effort"):
        np.testing.assert_allclose(getattr(session_log.joint_states, field),
                                   getattr(sent.joint_states, field)[:published],
                                   rtol=1e-9, atol=1e-12)
    topics = read_mcap(logs[0])
    assert len(topics[TOPIC_ESTIMATE]) == published
    assert len(topics[TOPIC_JOINT_STATES]) == published
    logged_events = [json.loads(m) for m in topics[TOPIC_EVENTS]]
    assert sorted(e["error"] for e in logged_events if e["kind"] == "error") == [
        "decode", "invalid", "setup"]
    # a replay of the log can announce what the daemon was told
    from wrenchd.service.replay.source import announced_changes, load_session, logged_setup_changes

    told = [(change["t"], {"arm": "PSM2", "pressure_mmhg": 20.0, "note": "pressure up",
                           "carry_over": True})]
    assert logged_setup_changes(str(logs[0])) == told
    assert announced_changes(load_session(str(logs[0]))) == told
    estimate = json.loads(topics[TOPIC_ESTIMATE][-1])
    last = wrenches[-1][2]
    np.testing.assert_allclose(estimate["force"], last[:3], rtol=2.0**-24, atol=1e-12)  # float32
    assert "stopped" in d_out
