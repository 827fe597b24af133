"""The Foxglove live view in this process: a real SDK server, a real WebSocket client.

Estimates fed at 1 kHz sample stamps come out decimated to ``rate_hz``, plus one gate
message at every change of the verdict; events arrive as ``foxglove.Log``, the status as JSON;
a failing call is counted and said once, never raised; a port in use is an AdapterError; the
shipped layout only names topics and fields the view publishes.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from wrenchd.adapters.foxglove_live import (GATE_SCHEMA, TOPICS, WRENCH_SCHEMA, FoxgloveConfig,
                                            LiveView)
from wrenchd.models.errors import AdapterError
from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.pipeline import Estimate, Event
from tests.adapters.foxglove_client import FoxgloveClient
from tests.support import wait_for

LAYOUT = Path(__file__).resolve().parents[2] / "deploy" / "foxglove" / "wrenchd-layout.json"


def _estimate(i: int, stamp_ns: int, wrench: np.ndarray, free: bool) -> Estimate:
    z = np.zeros(6)
    return Estimate(index=i, stamp_ns=stamp_ns, t=stamp_ns / 1e9, position=z, velocity=z,
                    effort=z, wrench=wrench, predicted_torque=z,
                    external_torque=wrench[::-1].copy(), free=free, score=0.5 + i % 7,
                    model_version=3, restarted=False)


@pytest.fixture
def view():
    v = LiveView(FoxgloveConfig(port=0, rate_hz=100.0))
    yield v
    v.close()


def test_estimates_are_decimated_and_gate_changes_shown(view):
    arm = view.arm("PSM9", "psm_base")
    topics = {k: t.format(arm="PSM9") for k, t in TOPICS.items()}
    client = FoxgloveClient(view.url)
    try:
        client.wait_for_channels(set(topics.values()), 10.0)
        assert client.channels[topics["wrench"]]["schemaName"] == "wrenchd.Wrench"
        assert client.channels[topics["external_torque"]]["schemaName"] == "foxglove.JointStates"
        assert client.channels[topics["events"]]["schemaName"] == "foxglove.Log"
        client.subscribe(list(topics.values()))
        wait_for(lambda: arm._wrench.has_sinks() and arm._events.has_sinks()
                 and arm._status.has_sinks(), 10.0, "the subscriptions to reach the server")

        rng = np.random.default_rng(7)
        wrenches = rng.normal(0.0, 3.0, (1000, 6))
        t0 = 1_700_000_000_000_000_000
        for i in range(1000):                   # 1 s at 1 kHz; contact from 0.333 to 0.666 s
            arm.estimate(_estimate(i, t0 + i * 1_000_000, wrenches[i], not 333 <= i < 666))
        arm.events([Event(0.5, "contact_start", {"arm": "PSM9"}),
                    Event(0.6, "error", {"reason": "decode", "n": np.int64(2)})])
        arm.status({"arm": "PSM9", "model": {"version": 3}, "rate_hz": np.float64(999.5),
                    "counters": {"estimated": 1000}})

        def count(topic):
            return len(client.payloads(topics[topic]))

        client.collect_until(lambda c: count("wrench") >= 100 and count("gate") >= 102
                             and count("external_torque") >= 100 and count("events") >= 2
                             and count("status") >= 1, 15.0, "every message")
        client.drain(0.5)                        # anything beyond would be too much
    finally:
        client.close()
    assert arm.failures == 0

    shown = [json.loads(f.payload) for f in client.payloads(topics["wrench"])]
    assert len(shown) == 100                    # samples 0, 10, ..., 990: one per 10 ms
    stamps = [m["timestamp"]["sec"] * 1_000_000_000 + m["timestamp"]["nsec"] for m in shown]
    assert stamps == [t0 + k * 10_000_000 for k in range(100)]
    for k, m in enumerate(shown):               # JSON round trip of float64: exact
        w = wrenches[10 * k]
        assert [m["force"][a] for a in "xyz"] + [m["torque"][a] for a in "xyz"] == w.tolist()
        assert m["frame_id"] == "psm_base"
    log_times = [f.log_time_ns for f in client.frames]
    assert all(b >= a for a, b in zip(log_times, log_times[1:]))

    gates = [json.loads(f.payload) for f in client.payloads(topics["gate"])]
    assert len(gates) == 102                    # 100 decimated + entering and leaving contact
    changes = [g for g in gates if g["timestamp"]["nsec"] % 10_000_000 != 0]
    assert [(g["state"], g["contact"], g["timestamp"]["nsec"] // 1_000_000) for g in changes] \
        == [("contact", True, 333), ("free", False, 666)]
    assert all(g["model_version"] == 3 and math.isfinite(g["score"]) for g in gates)
    assert set(GATE_SCHEMA["properties"]) == set(gates[0])
    assert set(WRENCH_SCHEMA["properties"]) == set(shown[0])

    torques = client.payloads(topics["external_torque"])
    assert len(torques) == 100
    assert all(name.encode() in torques[0].payload for name in JOINT_NAMES)

    logs = [f.payload for f in client.payloads(topics["events"])]
    assert b"contact_start" in logs[0] and b"wrenchd.PSM9" in logs[0]
    assert b"error" in logs[1] and b'"n":2' in logs[1]
    status = json.loads(client.payloads(topics["status"])[0].payload)
    assert status["rate_hz"] == 999.5 and status["counters"]["estimated"] == 1000


def test_a_failing_call_is_counted_and_said_once(view, capsys):
    arm = view.arm("PSM8")
    arm.estimate(object())                              # not an Estimate: must not raise
    arm.estimate(object())
    assert arm.failures == 2
    err = capsys.readouterr().err
    assert err.count("Foxglove live view of PSM8 failed") == 1


def test_a_port_in_use_is_an_adapter_error(view):
    with pytest.raises(AdapterError, match=f"127.0.0.1:{view.port}"):
        LiveView(FoxgloveConfig(port=view.port))


def test_config_refuses_bad_values():
    with pytest.raises(ValueError, match="port"):
        FoxgloveConfig(port=70000)
    with pytest.raises(ValueError, match="rate_hz"):
        FoxgloveConfig(rate_hz=0.0)
    with pytest.raises(AdapterError, match="port"):
        LiveView(FoxgloveConfig())


def _leaves(node) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert set(node) >= {"first", "second", "direction"}, node
    assert node["direction"] in ("row", "column")
    return _leaves(node["first"]) + _leaves(node["second"])


def test_the_shipped_layout_names_what_the_view_publishes():
    layout = json.loads(LAYOUT.read_text())
    assert set(layout) >= {"configById", "layout", "globalVariables", "userNodes"}
    panels = layout["configById"]
    assert sorted(_leaves(layout["layout"])) == sorted(panels)
    topics = {t.format(arm="PSM1"): k for k, t in TOPICS.items()}
    json_fields = {"wrench": WRENCH_SCHEMA, "gate": GATE_SCHEMA}
    paths = []
    for pid, cfg in panels.items():
        kind = pid.split("!")[0]
        assert kind in {"Plot", "Indicator", "Gauge", "RawMessages", "Log"}, pid
        paths += [p["value"] for p in cfg.get("paths", [])]
        paths += [cfg[k] for k in ("path", "topicPath", "topicToRender") if k in cfg]
    assert paths
    seen = set()
    for path in paths:
        m = re.fullmatch(r"(/PSM1/wrenchd/[a-z_]+)((?:\.[a-z_]+(?:\[\d\])?)*)", path)
        assert m, path
        kind = topics[m.group(1)]                 # KeyError: a topic the view does not have
        seen.add(kind)
        fields = [f.split("[")[0] for f in m.group(2).split(".")[1:]]
        if kind in json_fields and fields:
            node = json_fields[kind]
            for f in fields:
                node = node["properties"][f]       # KeyError: a field the schema lacks
        elif kind == "external_torque":
            assert fields == ["joints", "effort"], path
    assert seen == set(TOPICS)                     # every channel has a panel
    plotted = {p["value"] for p in panels["Plot!force"]["paths"]}
    assert plotted == {f"/PSM1/wrenchd/wrench.force.{a}" for a in "xyz"}
