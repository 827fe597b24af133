"""``wrenchd serve`` with its simulated PSM, end to end: the daemon's log and the robot's
recorded session are ROS 2 bags that rosbags opens from the files alone, with joint states,
wrenches and estimates readable, and the log replays."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import orjson
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from tests.support import free_port
from wrenchd.adapters.log_estimates import read_logged_estimates
from wrenchd.service.replay.source import load_session


def _read(path):
    """Every message of a bag by topic, types built from the bag's own definitions."""
    with AnyReader([path], default_typestore=get_typestore(Stores.EMPTY)) as bag:
        out: dict[str, list] = {}
        for connection, _, raw in bag.messages():
            out.setdefault(connection.topic, []).append(bag.deserialize(raw, connection.msgtype))
    return out


def test_serve_writes_ros2_bags_that_rosbags_reads(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    logs = tmp_path / "logs"
    config = tmp_path / "wrenchd.toml"
    config.write_text(f'robot = "simulated"\n[zenoh]\nlisten = ["{endpoint}"]\n'
                      f'[log]\ndirectory = "{logs}"\n')
    run = subprocess.run([sys.executable, "-m", "wrenchd", "serve", "--config", str(config),
                          "--duration", "10"], capture_output=True, text=True, timeout=240)
    assert run.returncode == 0, run.stderr[-3000:]
    (log,) = logs.glob("PSM1-*.mcap")
    (recorded,) = (logs / "robot").glob("PSM1-*.mcap")
    with Reader(log) as bag:
        types = {c.topic: c.msgtype for c in bag.connections}
        counts = {c.topic: c.msgcount for c in bag.connections}
    assert types == {"/psm/measured_js": "sensor_msgs/msg/JointState",
                     "/wrenchd/estimate": "wrenchd_msgs/msg/Estimate",
                     "/wrenchd/events": "wrenchd_msgs/msg/Event",
                     "/wrenchd/status": "wrenchd_msgs/msg/Status"}
    n = counts["/psm/measured_js"]
    assert n > 20 and counts["/wrenchd/estimate"] == n and counts["/wrenchd/status"] >= 1
    daemon, robot = _read(log), _read(recorded)
    # what the daemon estimated from is what the robot recorded, sample by sample
    stamps = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in robot["/psm/measured_js"]}
    logged = daemon["/psm/measured_js"]
    same = [stamps[(m.header.stamp.sec, m.header.stamp.nanosec)] for m in logged]
    np.testing.assert_allclose([m.effort for m in logged], [m.effort for m in same],
                               rtol=2.0**-33, atol=0)    # the session rounds to 32 bits
    est = daemon["/wrenchd/estimate"]
    assert [e.header.stamp for e in est] == [m.header.stamp for m in logged]
    wrench = np.array([[*e.force, *e.torque] for e in est])
    assert wrench.shape == (n, 6) and np.isfinite(wrench).all() and np.abs(wrench).max() > 0
    assert np.array([e.external for e in est]).shape == (n, 6)
    assert all(e.model_version >= 0 for e in est)
    # the predicted torques, not stored, are the logged effort minus the external torques
    logged_est = read_logged_estimates(log)
    assert not logged_est.predicted_stored and len(logged_est) == n
    np.testing.assert_array_equal(logged_est.predicted, np.array([m.effort for m in logged])
                                  - np.array([e.external for e in est], dtype=np.float64))
    assert np.isfinite(logged_est.predicted).all()
    status = orjson.loads(daemon["/wrenchd/status"][-1].json)
    assert status["counters"]["estimated"] <= n
    truth = robot["/psm/truth/wrench"]
    assert len(truth) == len(robot["/psm/measured_js"]) and truth[0].header.frame_id == "psm_base"
    assert len(robot["/psm/truth/torques"][0].effects) > 0
    # and the log is a session that replay loads
    session = load_session(str(log))
    assert len(session.joint_states) == n and session.truth is None
