"""ROS 2 over zenoh as ``rmw_zenoh`` puts it on the wire: key expressions, liveliness tokens,
publisher GIDs and the attachment of every published sample (pure functions, no session).

The daemon talks to a dVRK running rmw_zenoh as a ROS 2 node would (a node, a subscription
and a publisher that ROS tools see in their graph); these functions build what that takes.

Source: ``docs/design.md`` of the ros2/rmw_zenoh repository (the zenoh 1.x design, with the
key-less attachment), sections "Topic and Service name mapping to Zenoh key expressions",
"Graph Cache" and "Publishers". What the document leaves to the code comes from the same
repository's ``rmw_zenoh_cpp/src/detail``: ``liveliness_utils.cpp`` (GIDs, the QoS part of a
token), ``qos.cpp`` (the default QoS) and ``rmw_publisher_data.cpp`` (sequence numbers, the
source timestamp, no zenoh encoding). Worked examples: ``docs/formats-and-keys.md``, "ROS 2
over rmw_zenoh".

* **Topic key** (:func:`topic_key`): ``<domain_id>/<topic without its leading slash>/<DDS
  type name>/<type hash>``; the type hash is REP-2011's RIHS01 (:func:`type_hash`).
* **Liveliness tokens** (:func:`node_token`, :func:`endpoint_token`): under ``@ros2_lv``, a
  verbatim chunk (``**`` does not match it), with ``/`` in names written as ``%``.
* **GID** (:func:`gid_of`): 16 bytes, the XXH3-128 of the entity's liveliness token.
* **Attachment** (:func:`encode_attachment`, :class:`Stamper`; 33 bytes, little-endian):
  sequence number, source timestamp [ns since the UNIX epoch], the GID's length and the GID.
"""

from __future__ import annotations

import re
import struct
import time
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import xxhash

from wrenchd.adapters.ros2_msgs import jazzy_typestore
from wrenchd.models.errors import ConfigError, DataError

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
GID_SIZE = 16
#: sequence number, source timestamp [ns], GID length, GID
_ATTACHMENT = struct.Struct("<qqB16s")
ATTACHMENT_SIZE = _ATTACHMENT.size
#: ROS names (``design.ros2.org/articles/topic_and_service_names.html``): tokens of letters,
#: digits and underscores, not starting with a digit
_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_TOPIC = re.compile(rf"^(/{_TOKEN})+$")
_NAMESPACE = re.compile(rf"^/$|^(/{_TOKEN})+$")
_NODE = re.compile(rf"^{_TOKEN}$")
_TYPE = re.compile(rf"^({_TOKEN})/msg/({_TOKEN})$")
#: rmw/types.h enumerators the QoS part of a token writes
_RELIABLE, _BEST_EFFORT = 1, 2
_TRANSIENT_LOCAL, _VOLATILE = 1, 2
_KEEP_LAST, _KEEP_ALL = 1, 2
_DEFAULT_DEPTH = 42


@dataclass(frozen=True)
class Qos:
    """The QoS a token advertises (zenoh itself has no incompatible QoS). The default is
    ``rclcpp::QoS(10)``'s: reliable, volatile, keep the last 10.

    The token names only what differs from rmw_zenoh's default QoS (``qos.cpp``): reliable,
    volatile, keep the last 42, infinite deadline, lifespan and lease, automatic liveliness.
    """

    reliable: bool = True
    transient_local: bool = False
    keep_all: bool = False
    depth: int = 10

    def key(self) -> str:
        """``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:
        <liveliness>,<lease s>,<ns>``, each field empty where it is rmw_zenoh's default (the
        deadline, lifespan and liveliness fields always are here)."""
        reliability = "" if self.reliable else str(_BEST_EFFORT)
        durability = str(_TRANSIENT_LOCAL) if self.transient_local else ""
        history = str(_KEEP_ALL) if self.keep_all else ""
        depth = "" if self.depth == _DEFAULT_DEPTH else str(self.depth)
        return f"{reliability}:{durability}:{history},{depth}:,:,:,,"


def check_topic(topic: str) -> str:
    """A fully qualified ROS topic name (``/PSM1/measured_js``), or ConfigError."""
    if not _TOPIC.match(topic):
        raise ConfigError(f"not a fully qualified ROS topic name: {topic!r} (expected e.g. "
                          f"'/PSM1/measured_js')")
    return topic


def check_node(name: str, namespace: str) -> None:
    if not _NODE.match(name):
        raise ConfigError(f"not a ROS node name: {name!r}")
    if not _NAMESPACE.match(namespace):
        raise ConfigError(f"not a ROS namespace: {namespace!r} (expected '/' or e.g. '/lab')")


def mangle(name: str) -> str:
    """A ROS name as one key chunk: every ``/`` becomes ``%``."""
    return name.replace("/", "%")


def dds_type_name(typename: str) -> str:
    """``sensor_msgs/msg/JointState`` -> ``sensor_msgs::msg::dds_::JointState_``."""
    found = _TYPE.match(typename)
    if not found:
        raise ConfigError(f"not a ROS message type name: {typename!r}")
    return f"{found.group(1)}::msg::dds_::{found.group(2)}_"


@lru_cache(maxsize=None)
def type_hash(typename: str) -> str:
    """The RIHS01 type hash (REP-2011) of a ROS 2 Jazzy message type, e.g.
    ``RIHS01_a13ee3a3...`` for ``sensor_msgs/msg/JointState``."""
    store = jazzy_typestore()
    if typename not in store.types:
        raise ConfigError(f"unknown ROS 2 message type {typename!r}")
    return store.hash_rihs01(typename)


def topic_key(domain_id: int, topic: str, typename: str) -> str:
    """The key expression of ``topic`` (``/PSM1/measured_js``) carrying ``typename``:
    ``<domain_id>/<topic without its leading slash>/<DDS type name>/<type hash>``, e.g.
    ``0/PSM1/measured_js/sensor_msgs::msg::dds_::JointState_/RIHS01_a13ee3a3...``."""
    return (f"{int(domain_id)}/{check_topic(topic)[1:]}/{dds_type_name(typename)}/"
            f"{type_hash(typename)}")


def node_token(domain_id: int, zid: str, node_id: int, node: str, namespace: str = "/",
               enclave: str = "/") -> str:
    """The liveliness token of a node:
    ``@ros2_lv/<domain>/<zid>/<node_id>/<node_id>/NN/<enclave>/<namespace>/<node>``, where
    ``/`` in the enclave and namespace becomes ``%`` (an unset enclave or the root namespace
    is ``%``)."""
    check_node(node, namespace)
    return (f"{ADMIN_SPACE}/{int(domain_id)}/{zid}/{node_id}/{node_id}/{NODE}/"
            f"{mangle(enclave)}/{mangle(namespace)}/{node}")


def endpoint_token(kind: str, domain_id: int, zid: str, node_id: int, entity_id: int,
                   node: str, topic: str, typename: str, namespace: str = "/",
                   enclave: str = "/", qos: Qos = Qos()) -> str:
    """The liveliness token of a publisher (``MP``) or subscription (``MS``) of ``node``:
    ``@ros2_lv/<domain>/<zid>/<node_id>/<entity_id>/<kind>/<enclave>/<namespace>/<node>/
    <topic>/<DDS type name>/<type hash>/<qos>``, where ``/`` in the enclave, namespace and
    topic becomes ``%`` (an unset enclave or the root namespace is ``%``) and ``<qos>`` is
    :meth:`Qos.key`."""
    if kind not in (PUBLISHER, SUBSCRIPTION):
        raise ValueError(f"kind must be {PUBLISHER!r} or {SUBSCRIPTION!r}, got {kind!r}")
    check_node(node, namespace)
    return (f"{ADMIN_SPACE}/{int(domain_id)}/{zid}/{node_id}/{entity_id}/{kind}/"
            f"{mangle(enclave)}/{mangle(namespace)}/{node}/{mangle(check_topic(topic))}/"
            f"{dds_type_name(typename)}/{type_hash(typename)}/{qos.key()}")


def gid_of(token: str) -> bytes:
    """An entity's 16-byte GID: the XXH3-128 of its liveliness token, the low 64 bits first,
    each half little-endian (how rmw_zenoh's ``liveliness_utils.cpp`` copies the hash into
    the GID), computed with the ``xxhash`` package."""
    return xxhash.xxh3_128_intdigest(token.encode()).to_bytes(GID_SIZE, "little")


class Attachment(NamedTuple):
    sequence_number: int
    source_timestamp_ns: int
    gid: bytes


def encode_attachment(sequence_number: int, source_timestamp_ns: int, gid: bytes) -> bytes:
    """The 33 attachment bytes of one published sample: sequence number (int64), source
    timestamp [ns since the UNIX epoch] (int64), the GID's length (one byte, 16) and the GID
    (16 bytes), little-endian."""
    if len(gid) != GID_SIZE:
        raise ValueError(f"a GID has {GID_SIZE} bytes, got {len(gid)}")
    return _ATTACHMENT.pack(sequence_number, source_timestamp_ns, GID_SIZE, bytes(gid))


def decode_attachment(raw: bytes) -> Attachment:
    """The sequence number, source timestamp and GID of an attachment; DataError if it is not
    one."""
    raw = bytes(raw)
    if len(raw) != ATTACHMENT_SIZE:
        raise DataError(f"an rmw_zenoh attachment has {ATTACHMENT_SIZE} bytes, got {len(raw)}")
    seq, stamp, size, gid = _ATTACHMENT.unpack(raw)
    if size != GID_SIZE:
        raise DataError(f"attachment GID length {size}, expected {GID_SIZE}")
    return Attachment(seq, stamp, gid)


class Endpoint(NamedTuple):
    """A publisher's or subscription's key expression, liveliness token and GID."""

    key: str
    token: str
    gid: bytes


def endpoint(kind: str, domain_id: int, zid: str, node_id: int, entity_id: int, node: str,
             topic: str, typename: str, namespace: str = "/") -> Endpoint:
    """Everything a ROS endpoint on ``topic`` declares."""
    token = endpoint_token(kind, domain_id, zid, node_id, entity_id, node, topic, typename,
                           namespace)
    return Endpoint(topic_key(domain_id, topic, typename), token, gid_of(token))


class Stamper:
    """The attachments of one publisher's samples: sequence numbers from 1, each sample stamped
    with the system time at publication (as rmw_zenoh's ``rmw_publisher_data.cpp`` does; it
    sets no zenoh encoding)."""

    def __init__(self, gid: bytes) -> None:
        if len(gid) != GID_SIZE:
            raise ValueError(f"a GID has {GID_SIZE} bytes, got {len(gid)}")
        self.gid = bytes(gid)
        self.sequence_number = 0

    def next(self) -> bytes:
        self.sequence_number += 1
        return _ATTACHMENT.pack(self.sequence_number, time.time_ns(), GID_SIZE, self.gid)
