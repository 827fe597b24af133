"""The MCAP session format: topics, JSON Schemas and the session metadata record.

Sessions are MCAP files of JSON messages with JSON Schemas, readable by Foxglove Studio;
:mod:`wrenchd.adapters.mcap_session_writer` writes them and
:mod:`wrenchd.adapters.mcap_session_reader` reads them.

Layout (every message has ``log_time == publish_time == round(t * 1e9)`` ns, sim time from 0):

- ``/psm/measured_js`` (``sensor_msgs/JointState``-like): header, name, position, velocity,
  effort, six joints each.
- ``/psm/truth/wrench`` and, where the scenario has a sensor, ``/psm/truth/sensor_wrench``
  (``geometry_msgs/WrenchStamped``-like, frame ``psm_base``): true and sensed tip wrench.
- ``/psm/truth/torques``: in_contact, true joint position / velocity / acceleration, internal
  and external joint torque, and the per-effect torques under ``effects``.
- Metadata record ``wrenchd.session``: ``{"format": "wrenchd.session/1", "json": <metadata>}``.

Chunks are zstd-compressed and self-contained, so a file whose writer was killed still yields
every complete chunk (:func:`~wrenchd.adapters.mcap_session_reader.read_session_report`).
Output bytes depend only on the session: no wall-clock time is written and the header's
library string is fixed.
"""

from __future__ import annotations

from typing import Any

TOPIC_JOINT_STATES = "/psm/measured_js"
TOPIC_WRENCH = "/psm/truth/wrench"
TOPIC_SENSOR_WRENCH = "/psm/truth/sensor_wrench"
TOPIC_TORQUES = "/psm/truth/torques"
SESSION_METADATA_NAME = "wrenchd.session"
SESSION_FORMAT = "wrenchd.session/1"
NS_PER_S = 1_000_000_000

_VECTOR6 = {"type": "array", "items": {"type": "number"}, "minItems": 6, "maxItems": 6}
_HEADER = {
    "type": "object",
    "properties": {
        "stamp": {
            "type": "object",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nanosec": {"type": "integer", "minimum": 0, "maximum": NS_PER_S - 1},
            },
            "required": ["sec", "nanosec"],
        },
        "frame_id": {"type": "string"},
    },
    "required": ["stamp", "frame_id"],
}
_XYZ = {
    "type": "object",
    "properties": {axis: {"type": "number"} for axis in "xyz"},
    "required": ["x", "y", "z"],
}
_DRAFT = "https://json-schema.org/draft/2020-12/schema"

JOINT_STATE_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT,
    "title": "sensor_msgs/JointState",
    "description": "Measured PSM joint states: rad, rad, m, rad, rad, rad; "
                   "efforts N m (joint 3: N).",
    "type": "object",
    "properties": {
        "header": _HEADER,
        "name": {"type": "array", "items": {"type": "string"}, "minItems": 6, "maxItems": 6},
        "position": _VECTOR6,
        "velocity": _VECTOR6,
        "effort": _VECTOR6,
    },
    "required": ["header", "name", "position", "velocity", "effort"],
}
WRENCH_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT,
    "title": "geometry_msgs/WrenchStamped",
    "description": "Tip wrench about the tip in base-frame axes: N and N m.",
    "type": "object",
    "properties": {
        "header": _HEADER,
        "wrench": {
            "type": "object",
            "properties": {"force": _XYZ, "torque": _XYZ},
            "required": ["force", "torque"],
        },
    },
    "required": ["header", "wrench"],
}
TORQUES_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT,
    "title": "wrenchd/JointTorqueTruth",
    "description": "Simulator ground truth per joint: true motion; internal, external and "
                   "per-effect torque (N m, joint 3: N).",
    "type": "object",
    "properties": {
        "header": _HEADER,
        "in_contact": {"type": "boolean"},
        **dict.fromkeys(("position", "velocity", "acceleration", "internal", "external"), _VECTOR6),
        "effects": {"type": "object", "additionalProperties": _VECTOR6},
    },
    "required": ["header", "in_contact", "position", "velocity", "acceleration",
                 "internal", "external", "effects"],
}
TOPIC_SCHEMAS: dict[str, dict[str, Any]] = {
    TOPIC_JOINT_STATES: JOINT_STATE_SCHEMA,
    TOPIC_WRENCH: WRENCH_SCHEMA,
    TOPIC_SENSOR_WRENCH: WRENCH_SCHEMA,
    TOPIC_TORQUES: TORQUES_SCHEMA,
}
