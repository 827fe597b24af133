"""`wrenchd robot`: the simulated PSM as a real subprocess publishing over real zenoh."""

import json
import signal
import subprocess
import sys
import time

import numpy as np

from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from tests.support import communicate_within, expect_line, free_port, stop_within


def test_robot_streams_joint_states_and_records_them(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "wrenchd", "robot", "--scenario", "trocar", "--arm", "PSM2",
         "--listen", endpoint, "--out-dir", str(tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    received = []
    session = None
    try:
        # wait for the robot's banner, then connect a subscriber to its endpoint
        expect_line(proc, "dvrk/PSM2/measured_js", 120.0, "the robot")
        session = open_session(ZenohConfig(connect=[endpoint]))
        sub = session.declare_subscriber(
            "dvrk/PSM2/measured_js", lambda s: received.append(json.loads(s.payload.to_bytes())))
        time.sleep(2.5)
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        out, err = stop_within(proc, 30.0, "the robot", signal.SIGINT)
    assert proc.returncode == 0, err
    assert "stopped after" in out
    # ~200 Hz for the time we listened, in order, six joints each
    assert len(received) > 300
    stamps = [m["header"]["stamp"]["sec"] + 1e-9 * m["header"]["stamp"]["nanosec"] for m in received]
    assert np.all(np.diff(stamps) > 0)
    assert abs(np.median(np.diff(stamps)) - 0.005) < 1e-9
    assert all(len(m["effort"]) == 6 for m in received)
    # the SIGINT stop finished the MCAP file: complete, and holding what was published
    session_file, info = read_session_report(next(tmp_path.glob("PSM2-trocar-seed0.mcap")))
    assert not info.truncated
    published = int(out.strip().splitlines()[-1].split("after ")[1].split()[0])
    assert len(session_file.joint_states) == published
    assert session_file.truth is not None
    last = received[-1]
    idx = np.argmin(np.abs(session_file.joint_states.t - stamps[-1]))
    np.testing.assert_allclose(session_file.joint_states.effort[idx], last["effort"], rtol=1e-9)


def run_robot_listening(tmp_path, *extra):
    """A 4 s insufflation-change robot (its pressure step at 1.6 s); what arrived on the joint
    state and set-up keys."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "wrenchd", "robot", "--scenario", "insufflation-change",
         "--duration", "4", "--listen", endpoint, "--out-dir", str(tmp_path), "--quiet",
         *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    states, setups = [], []
    session = None
    try:
        session = open_session(ZenohConfig(connect=[endpoint]))
        subs = [session.declare_subscriber("dvrk/PSM1/setup",
                                           lambda s: setups.append(s.payload.to_bytes())),
                session.declare_subscriber("dvrk/PSM1/measured_js",
                                           lambda s: states.append(1))]
        out, err = communicate_within(proc, 60.0, "the robot")
        for sub in subs:
            sub.undeclare()
    finally:
        if session is not None:
            session.close()
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    return states, setups


def test_robot_announces_its_scenarios_set_up_changes(tmp_path):
    from wrenchd.adapters.messages import decode_setup_change

    states, setups = run_robot_listening(tmp_path)
    assert len(states) > 500
    assert len(setups) == 1
    stamp_ns, detail = decode_setup_change(setups[0])
    assert stamp_ns == 1_600_000_000 and detail == {"note": "insufflation_step"}
    states, setups = run_robot_listening(tmp_path, "--no-announce")
    assert len(states) > 500 and setups == []
