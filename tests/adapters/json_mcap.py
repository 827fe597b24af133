"""MCAP files in the JSON format wrenchd wrote before its logs became ROS 2 bags: JSON messages
with JSON Schemas, profile "" (the former ``mcap_session_writer`` and ``mcap_log`` layouts,
numbers with 10 significant digits in sessions), so that tests check today's readers on them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import orjson
from mcap.writer import CompressionType, Writer

from wrenchd.models.series import GroundTruth, Session

_V6 = {"type": "array", "items": {"type": "number"}, "minItems": 6, "maxItems": 6}
_HEADER = {"type": "object", "required": ["stamp", "frame_id"], "properties": {
    "stamp": {"type": "object", "required": ["sec", "nanosec"],
              "properties": {"sec": {"type": "integer"}, "nanosec": {"type": "integer"}}},
    "frame_id": {"type": "string"}}}
SCHEMAS = {
    "/psm/measured_js": {"title": "sensor_msgs/JointState", "type": "object", "properties": {
        "header": _HEADER, "name": {"type": "array", "items": {"type": "string"}},
        "position": _V6, "velocity": _V6, "effort": _V6}},
    "/psm/truth/wrench": {"title": "geometry_msgs/WrenchStamped", "type": "object"},
    "/psm/truth/sensor_wrench": {"title": "geometry_msgs/WrenchStamped", "type": "object"},
    "/psm/truth/torques": {"title": "wrenchd/JointTorqueTruth", "type": "object"},
    "/wrenchd/estimate": {"title": "wrenchd/Estimate", "type": "object"},
    "/wrenchd/events": {"title": "wrenchd/Event", "type": "object"},
    "/wrenchd/status": {"title": "wrenchd/Status", "type": "object"},
}


def _g(values) -> list[float]:
    """10 significant digits, as the former session writer's "%.10g"."""
    return [float("%.10g" % v) for v in np.asarray(values, dtype=float).tolist()]


def _header(ns: int, frame: str) -> dict:
    return {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": frame}


def _wrench(ns: int, w) -> dict:
    w = _g(w)
    return {"header": _header(ns, "psm_base"),
            "wrench": {"force": dict(zip("xyz", w[:3])), "torque": dict(zip("xyz", w[3:]))}}


class _JsonFile:
    def __init__(self, path: Path, library: str) -> None:
        self.file = open(path, "wb")
        self.writer = Writer(self.file, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library=library)
        self.channels: dict[str, int] = {}

    def add(self, topic: str, ns: int, message) -> None:
        if topic not in self.channels:
            schema = SCHEMAS[topic]
            sid = self.writer.register_schema(schema["title"], "jsonschema",
                                              json.dumps(schema).encode())
            self.channels[topic] = self.writer.register_channel(topic, "json", sid)
        data = message if isinstance(message, bytes) else json.dumps(message).encode()
        self.writer.add_message(self.channels[topic], ns, data, ns)

    def close(self) -> None:
        self.writer.finish()
        self.file.close()


def write_json_session(path: Path, session: Session) -> None:
    """``session`` in the former JSON session layout (with its truth, if any)."""
    out = _JsonFile(path, "wrenchd.adapters.mcap_session/1")
    out.writer.add_metadata("wrenchd.session", {"format": "wrenchd.session/1",
                                                "json": json.dumps(session.metadata)})
    js, truth = session.joint_states, session.truth
    for i in range(len(js)):
        ns = int(round(js.t[i] * 1e9))
        out.add("/psm/measured_js", ns, {
            "header": _header(ns, ""), "name": list(js.names), "position": _g(js.position[i]),
            "velocity": _g(js.velocity[i]), "effort": _g(js.effort[i])})
        if truth is None:
            continue
        out.add("/psm/truth/wrench", ns, _wrench(ns, truth.external_wrench[i]))
        if truth.sensor_wrench is not None:
            out.add("/psm/truth/sensor_wrench", ns, _wrench(ns, truth.sensor_wrench[i]))
        out.add("/psm/truth/torques", ns, {
            "header": _header(ns, ""), "in_contact": bool(truth.in_contact[i]),
            "position": _g(truth.position[i]), "velocity": _g(truth.velocity[i]),
            "acceleration": _g(truth.acceleration[i]), "internal": _g(truth.internal_torque[i]),
            "external": _g(truth.external_torque[i]),
            "effects": {k: _g(v[i]) for k, v in truth.effects.items()}})
    out.close()


def write_json_daemon_log(path: Path, session: Session, events: list[tuple[int, dict]] = (),
                          estimates: GroundTruth | None = None) -> None:
    """A daemon log in the former JSON layout: every joint state as a JSON arm received it
    (full precision), an estimate per sample (its values from ``estimates``, a simulator's
    truth, as the log writer of ``wrenchd.adapters.mcap_log`` made them with orjson; zeros
    without), ``events`` as ``(log time [ns], event)``."""
    out = _JsonFile(path, "wrenchd.adapters.mcap_log/1")
    out.writer.add_metadata("wrenchd.session", {"format": "wrenchd.session/1",
                                                "json": json.dumps({"source": "wrenchd daemon"})})
    js = session.joint_states
    pending = sorted(events, key=lambda e: e[0])
    zeros = np.zeros((len(js), 6))
    wrench, predicted, external = ((zeros, zeros, zeros) if estimates is None else
                                   (estimates.external_wrench, estimates.internal_torque,
                                    estimates.external_torque))
    for i in range(len(js)):
        ns = int(round(js.t[i] * 1e9))
        while pending and pending[0][0] <= ns:
            stamp, event = pending.pop(0)
            out.add("/wrenchd/events", stamp, orjson.dumps(event))
        out.add("/psm/measured_js", ns, orjson.dumps({
            "header": _header(ns, ""), "name": list(js.names), "position": js.position[i],
            "velocity": js.velocity[i], "effort": js.effort[i]},
            option=orjson.OPT_SERIALIZE_NUMPY))
        w = wrench[i].tolist()
        out.add("/wrenchd/estimate", ns, orjson.dumps({
            "header": _header(ns, "psm_base"),
            "wrench": {"force": dict(zip("xyz", w[:3])), "torque": dict(zip("xyz", w[3:]))},
            "free": estimates is None or not bool(estimates.in_contact[i]), "score": 0.1 * i,
            "model_version": 3, "restarted": i == 0, "predicted": predicted[i],
            "external": external[i]}, option=orjson.OPT_SERIALIZE_NUMPY))
        if i % 200 == 199:                      # the daemon's log flushes every second
            out.writer.flush()
    out.close()
