"""``wrenchd serve --foxglove-port``: the daemon as a real subprocess (the embedded simulated
PSM), watched by a real Foxglove WebSocket client.

The client reads ``serverInfo`` and ``advertise``, subscribes to the wrench, gate and status
channels and checks what arrives: wrenches decode, are finite and come at most at the
configured rate with increasing stamps; the gate says free or contact; the status counts
estimates. The ``[foxglove]`` section of the settings file and the command-line flag combine.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from wrenchd.adapters.foxglove_live import TOPICS
from wrenchd.models.errors import ConfigError
from wrenchd.service.runtime.settings import load_settings
from tests.adapters.foxglove_client import FoxgloveClient
from tests.support import expect_line, free_port, stop_within

RATE_HZ = 50.0               # the live view's rate in the test's settings (the robot: 200 Hz)


def _config(tmp_path):
    path = tmp_path / "wrenchd.toml"
    path.write_text(f"""
[zenoh]
listen = ["tcp/127.0.0.1:{free_port()}"]
[log]
directory = "{tmp_path / 'logs'}"
[foxglove]
host = "127.0.0.1"
rate_hz = {RATE_HZ}
""")
    return path


def test_settings_take_a_foxglove_section(tmp_path):
    settings = load_settings(_config(tmp_path), foxglove={"port": 9876})
    assert (settings.foxglove.host, settings.foxglove.port, settings.foxglove.rate_hz) \
        == ("127.0.0.1", 9876, RATE_HZ)
    assert load_settings().foxglove.port is None          # off unless asked for
    bad = tmp_path / "bad.toml"
    bad.write_text("[foxglove]\nport = 70000\n")
    with pytest.raises(ConfigError, match="foxglove.port"):
        load_settings(bad)


def test_serve_streams_the_live_view_to_a_foxglove_client(tmp_path):
    port = free_port()
    # --duration bounds the run should the test fail to stop it; it stops it once it has seen
    # enough (the simulated robot alone takes 5-15 s to start on a loaded machine)
    daemon = subprocess.Popen(
        [sys.executable, "-m", "wrenchd", "serve", "--config", str(_config(tmp_path)),
         "--duration", "60", "--foxglove-port", str(port)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    topics = {k: t.format(arm="PSM1") for k, t in TOPICS.items()}
    client = None
    try:
        expect_line(daemon, "listening on", 120.0, "the daemon")
        line = expect_line(daemon, "Foxglove live view on", 10.0, "the daemon")
        assert f"ws://127.0.0.1:{port}" in line
        client = FoxgloveClient(f"ws://127.0.0.1:{port}")
        client.wait_for_channels(set(topics.values()), 10.0)
        assert client.server_info["name"] == "wrenchd"
        wrench_channel = client.channels[topics["wrench"]]
        assert (wrench_channel["encoding"], wrench_channel["schemaName"],
                wrench_channel["schemaEncoding"]) == ("json", "wrenchd.Wrench", "jsonschema")
        assert set(json.loads(wrench_channel["schema"])["properties"]) \
            == {"timestamp", "frame_id", "force", "torque"}
        client.subscribe([topics["wrench"], topics["gate"], topics["status"]])

        def estimating_status(c):
            return any(json.loads(f.payload)["counters"]["estimated"] > 0
                       for f in c.payloads(topics["status"]))

        client.collect_until(lambda c: len(c.payloads(topics["wrench"])) >= 100
                             and estimating_status(c), 60.0,
                             "100 wrenches and a status of an estimating arm")
    finally:
        if client is not None:
            client.close()
        out, err = stop_within(daemon, 30.0, "the daemon")
    assert daemon.returncode == 0, err[-2000:]
    assert "PSM1 stopped:" in out

    wrenches = [json.loads(f.payload) for f in client.payloads(topics["wrench"])]
    for m in wrenches:
        values = [m["force"][a] for a in "xyz"] + [m["torque"][a] for a in "xyz"]
        assert len(values) == 6 and all(isinstance(v, float) and math.isfinite(v)
                                        for v in values), m
        assert m["frame_id"] == "psm_base"
    stamps = [m["timestamp"]["sec"] * 1_000_000_000 + m["timestamp"]["nsec"] for m in wrenches]
    steps = [b - a for a, b in zip(stamps, stamps[1:])]
    # increasing, and decimated: never closer than 1/rate_hz in sample time
    assert min(steps) >= 1e9 / RATE_HZ, min(steps)
    # ... and not thinned more than needed: the robot's 5 ms samples, shown every 20 ms
    assert sorted(steps)[len(steps) // 2] == pytest.approx(1e9 / RATE_HZ, rel=0.05)
    log_times = [f.log_time_ns for f in client.payloads(topics["wrench"])]
    assert all(b >= a for a, b in zip(log_times, log_times[1:]))

    gates = [json.loads(f.payload) for f in client.payloads(topics["gate"])]
    assert gates and all(g["state"] in ("free", "contact") and g["contact"] == (g["state"] ==
                                                                                "contact")
                         and isinstance(g["model_version"], int) for g in gates)
    status = json.loads(client.payloads(topics["status"])[-1].payload)
    assert status["arm"] == "PSM1" and status["counters"]["estimated"] > 0


def test_the_daemon_imports_the_sdk_only_for_a_live_view():
    code = ("import sys; import wrenchd.service.runtime.daemon, wrenchd.service.cli.serve; "
            "print('foxglove' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False"
