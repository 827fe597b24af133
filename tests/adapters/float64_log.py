"""Daemon logs in the ROS 2 layout wrenchd wrote before its estimates became float32: the
same bag, with ``wrenchd_msgs/msg/Estimate`` defined as float64 ``wrench``
(``geometry_msgs/Wrench``), ``score``, ``predicted[6]`` and ``external[6]``, so that tests
check today's readers on them. The definition is the one those files store, byte for byte."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import orjson
from mcap.well_known import MessageEncoding, Profile, SchemaEncoding
from mcap.writer import CompressionType, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.messages import encode_joint_state
from wrenchd.models.series import GroundTruth, Session

ESTIMATE_FLOAT64 = (
    "# One sample's estimate (wrenchd daemon / replay).\n"
    "# wrench: tip wrench [N, N m], force in the base axes, torque about the tip.\n"
    "std_msgs/Header header\n"
    "geometry_msgs/Wrench wrench\n"
    "bool free             # the gate's verdict: free motion, no contact\n"
    "float64 score         # the gate's score (capped at 1e9)\n"
    "int64 model_version   # version of the correction net that estimated\n"
    "bool restarted        # the estimator's state restarted at this sample\n"
    "float64[6] predicted  # predicted joint torques [N m; N on the insertion joint]\n"
    "float64[6] external   # measured minus predicted joint torques [N m; N]\n")
_RULE = "\n" + "=" * 80 + "\n"
#: the complete ``ros2msg`` schema of the float64 layout, as its files store it
DEFINITION_FLOAT64 = (ESTIMATE_FLOAT64
                      + _RULE + "MSG: geometry_msgs/Wrench\n" + ros2.MSG_TEXT[ros2.WRENCH]
                      + _RULE + "MSG: geometry_msgs/Vector3\n" + ros2.MSG_TEXT[ros2.VECTOR3]
                      + _RULE + "MSG: std_msgs/Header\n" + ros2.MSG_TEXT[ros2.HEADER]
                      + _RULE + "MSG: builtin_interfaces/Time\n" + ros2.MSG_TEXT[ros2.TIME])


def _store():
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(DEFINITION_FLOAT64, ros2.ESTIMATE))
    return store


def estimate_float64(store, stamp_ns: int, wrench, free: bool, score: float, version: int,
                     restarted: bool, predicted, external) -> bytes:
    """One float64-layout estimate (CDR), as the former ``estimate_record`` made it."""
    types = store.types
    vector = types[ros2.VECTOR3]
    sec, nanosec = divmod(stamp_ns, ros2.NS_PER_S)
    f = np.asarray(wrench, dtype=np.float64).tolist()
    msg = types[ros2.ESTIMATE](
        header=types[ros2.HEADER](stamp=types[ros2.TIME](sec=sec, nanosec=nanosec),
                                  frame_id="psm_base"),
        wrench=types[ros2.WRENCH](force=vector(x=f[0], y=f[1], z=f[2]),
                                  torque=vector(x=f[3], y=f[4], z=f[5])),
        free=bool(free), score=float(score), model_version=int(version),
        restarted=bool(restarted), predicted=np.asarray(predicted, dtype=np.float64),
        external=np.asarray(external, dtype=np.float64))
    return bytes(store.serialize_cdr(msg, ros2.ESTIMATE))


def write_float64_daemon_log(path: Path, session: Session, estimates: GroundTruth) -> None:
    """A daemon log of ``session`` in the float64 layout: every joint state (CDR, float64),
    an estimate per sample with its values from ``estimates`` (a simulator's truth: the
    external wrench and torques, the internal torque as ``predicted``), a status and an event
    now and then, a chunk per second."""
    store = _store()
    with open(path, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile=Profile.ROS2, library="wrenchd.adapters.mcap_log/2")
        writer.add_metadata("wrenchd.session", {"format": "wrenchd.session/1", "json": json.dumps(
            {"source": "wrenchd daemon", "arm": "PSM1"})})
        ids = {}
        for topic, typename in (("/psm/measured_js", ros2.JOINT_STATE),
                                ("/wrenchd/estimate", ros2.ESTIMATE),
                                ("/wrenchd/events", ros2.EVENT), ("/wrenchd/status", ros2.STATUS)):
            definition = (DEFINITION_FLOAT64 if typename == ros2.ESTIMATE
                          else ros2.full_definition(typename))
            schema = writer.register_schema(typename, SchemaEncoding.ROS2, definition.encode())
            ids[topic] = writer.register_channel(topic, MessageEncoding.CDR, schema,
                                                 {"offered_qos_profiles": ros2.OFFERED_QOS})
        js = session.joint_states
        for i in range(len(js)):
            ns = int(round(js.t[i] * 1e9))
            writer.add_message(ids["/psm/measured_js"], ns, encode_joint_state(
                "cdr", ns, js.names, js.position[i], js.velocity[i], js.effort[i]), ns)
            writer.add_message(ids["/wrenchd/estimate"], ns, estimate_float64(
                store, ns, estimates.external_wrench[i], not estimates.in_contact[i], 0.1 * i,
                3, i == 0, estimates.internal_torque[i], estimates.external_torque[i]), ns)
            if i % 200 == 100:
                event = orjson.dumps({"t": float(js.t[i]), "kind": "gap", "gap_s": 0.02})
                writer.add_message(ids["/wrenchd/events"], ns, ros2.serialize(ros2.from_fields(
                    ros2.EVENT, {"stamp": {"sec": ns // ros2.NS_PER_S,
                                           "nanosec": ns % ros2.NS_PER_S},
                                 "kind": "gap", "json": event.decode()})), ns)
            if i % 200 == 199:                      # the daemon's log flushes every second
                writer.flush()
        writer.finish()
