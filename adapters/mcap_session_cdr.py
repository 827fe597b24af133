"""The session's messages in ROS 2 CDR: blocks of samples to messages, messages to fields.

The writer (:mod:`wrenchd.adapters.mcap_session_writer`) makes one message per topic and
sample with the functions ``*_messages``; the reader
(:mod:`wrenchd.adapters.mcap_session_reader`) turns each message back into the tuple of
fields its JSON counterpart gives (:data:`FIELDS`), so both formats share its checks.
Types: :data:`wrenchd.adapters.mcap_session.TOPIC_TYPES`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.mcap_session import (
    TOPIC_JOINT_STATES,
    TOPIC_SENSOR_WRENCH,
    TOPIC_TORQUES,
    TOPIC_TYPES,
    TOPIC_WRENCH,
)


def headers(stamps_ns: Sequence[int], frame_id: str) -> list:
    """One ``std_msgs/msg/Header`` per stamp [ns]."""
    return [ros2.header(s, frame_id) for s in stamps_ns]


def joint_state_messages(heads: list, names: Sequence[str], position: np.ndarray,
                         velocity: np.ndarray, effort: np.ndarray) -> list[bytes]:
    """``sensor_msgs/msg/JointState`` per row of the (n, 6) arrays."""
    make = ros2.message_class(ros2.JOINT_STATE)
    names = list(names)
    return [ros2.serialize(make(header=h, name=names, position=p, velocity=v, effort=e))
            for h, p, v, e in zip(heads, position, velocity, effort, strict=True)]


def wrench_messages(heads: list, wrench: np.ndarray) -> list[bytes]:
    """``geometry_msgs/msg/WrenchStamped`` per row of the (n, 6) wrench [N, N m]."""
    make, body = ros2.message_class(ros2.WRENCH_STAMPED), ros2.message_class(ros2.WRENCH)
    vector = ros2.message_class(ros2.VECTOR3)
    return [ros2.serialize(make(header=h, wrench=body(force=vector(x=w[0], y=w[1], z=w[2]),
                                                      torque=vector(x=w[3], y=w[4], z=w[5]))))
            for h, w in zip(heads, wrench.tolist(), strict=True)]


def torque_messages(heads: list, in_contact: np.ndarray, motion: Sequence[np.ndarray],
                    effects: Mapping[str, np.ndarray]) -> list[bytes]:
    """``wrenchd_msgs/msg/JointTorqueTruth`` per sample; ``motion``: the (n, 6) position,
    velocity, acceleration, internal and external torque."""
    make, effect = (ros2.message_class(ros2.JOINT_TORQUE_TRUTH),
                    ros2.message_class(ros2.TORQUE_EFFECT))
    names = list(effects)
    columns = list(effects.values())
    out = []
    for i, (h, contact) in enumerate(zip(heads, in_contact.tolist(), strict=True)):
        q, dq, ddq, internal, external = (m[i] for m in motion)
        out.append(ros2.serialize(make(
            header=h, in_contact=bool(contact), position=q, velocity=dq, acceleration=ddq,
            internal=internal, external=external,
            effects=[effect(name=name, torque=col[i]) for name, col in zip(names, columns)])))
    return out


# -- reading -----------------------------------------------------------------------------
def _js_fields(m) -> tuple:
    return ros2.time_ns(m.header.stamp), list(m.name), m.position, m.velocity, m.effort


def _wrench_fields(m) -> tuple:
    f, t = m.wrench.force, m.wrench.torque
    return ros2.time_ns(m.header.stamp), np.array([f.x, f.y, f.z, t.x, t.y, t.z])


def _torque_fields(m) -> tuple:
    return (ros2.time_ns(m.header.stamp), bool(m.in_contact), m.position, m.velocity,
            m.acceleration, m.internal, m.external, {e.name: e.torque for e in m.effects})


#: per topic: the fields of a decoded message, in the order of the JSON reader's tuples
FIELDS: dict[str, Callable[[object], tuple]] = {
    TOPIC_JOINT_STATES: _js_fields,
    TOPIC_WRENCH: _wrench_fields,
    TOPIC_SENSOR_WRENCH: _wrench_fields,
    TOPIC_TORQUES: _torque_fields,
}


def decode(topic: str, data: bytes) -> object:
    """The ``rosbags`` message of ``topic`` in ``data``.

    Raises:
        DataError: ``data`` is not a CDR message of the topic's type.
    """
    return ros2.deserialize(data, TOPIC_TYPES[topic])

