"""ROS 2 messages of wrenchd's MCAP files: definitions, type store, CDR and channels.

The daemon's log (:mod:`wrenchd.adapters.mcap_log`), simulated sessions
(:mod:`wrenchd.adapters.mcap_session`) and replay outputs are MCAP files laid out as ROS 2's
rosbag2 MCAP storage writes them, so that ``ros2 bag info`` / ``ros2 bag play``, Foxglove,
``rosbags`` and the mcap library's ROS 2 decoder open them without wrenchd: profile ``ros2``,
every message CDR (message encoding ``cdr``), every schema the type's complete message
definition (schema encoding ``ros2msg``, laid out as :func:`full_definition` says, after
rosbag2's ``docs/message_definition_encoding.md``). Profile and encoding names are mcap's own
(:mod:`mcap.well_known`).

Types: the standard ``sensor_msgs/msg/JointState`` and ``geometry_msgs/msg/WrenchStamped`` and
the project's own package ``wrenchd_msgs`` (:data:`MSG_TEXT`). CDR (de)serialisation is the
``rosbags`` type store's: ROS 2 Humble's definitions plus ``wrenchd_msgs``, registered from the
texts below. This module owns the type stores every adapter uses (:func:`typestore`, and
:func:`jazzy_typestore` for REP-2011 type hashes) and the conversions between nanosecond stamps
and ``builtin_interfaces/msg/Time`` (:data:`NS_PER_S`, :func:`split_ns`, :func:`stamp`,
:func:`header`, :func:`time_ns`).

A file whose stored definition of a type differs from :data:`MSG_TEXT`'s is decoded with the
definition stored in it (:func:`deserialize`).
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping
from typing import Any

import numpy as np
from mcap.well_known import MessageEncoding, SchemaEncoding

from wrenchd.models.errors import DataError

#: nanoseconds per second: every stamp in wrenchd is integer nanoseconds
NS_PER_S = 1_000_000_000

TIME = "builtin_interfaces/msg/Time"
HEADER = "std_msgs/msg/Header"
JOINT_STATE = "sensor_msgs/msg/JointState"
VECTOR3 = "geometry_msgs/msg/Vector3"
WRENCH = "geometry_msgs/msg/Wrench"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
ESTIMATE = "wrenchd_msgs/msg/Estimate"
EVENT = "wrenchd_msgs/msg/Event"
STATUS = "wrenchd_msgs/msg/Status"
JOINT_TORQUE_TRUTH = "wrenchd_msgs/msg/JointTorqueTruth"
TORQUE_EFFECT = "wrenchd_msgs/msg/TorqueEffect"

#: The .msg text of every type the files use. The standard ones carry the fields of their
#: ROS 2 packages (comments left out; tests compare them with the type store's Humble types).
MSG_TEXT: dict[str, str] = {
    TIME: "int32 sec\nuint32 nanosec\n",
    HEADER: "builtin_interfaces/Time stamp\nstring frame_id\n",
    JOINT_STATE: ("std_msgs/Header header\nstring[] name\nfloat64[] position\n"
                  "float64[] velocity\nfloat64[] effort\n"),
    VECTOR3: "float64 x\nfloat64 y\nfloat64 z\n",
    WRENCH: "geometry_msgs/Vector3 force\ngeometry_msgs/Vector3 torque\n",
    WRENCH_STAMPED: "std_msgs/Header header\ngeometry_msgs/Wrench wrench\n",
    ESTIMATE: (
        "# One sample's estimate (wrenchd daemon / replay), in float32 to keep logs small.\n"
        "# The predicted joint torques are not stored: they are effort - external, with the\n"
        "# effort of the sensor_msgs/JointState logged with the same stamp.\n"
        "std_msgs/Header header\n"
        "float32[3] force      # tip force [N] in the base axes\n"
        "float32[3] torque     # tip torque [N m] about the tip\n"
        "bool free             # the gate's verdict: free motion, no contact\n"
        "float32 score         # the gate's score (capped at 1e9)\n"
        "int64 model_version   # version of the correction net that estimated\n"
        "bool restarted        # the estimator's state restarted at this sample\n"
        "float32[6] external   # measured minus predicted joint torques [N m; N on the "
        "insertion joint]\n"),
    EVENT: (
        "# Something that happened: error, gap, contact_start, contact_end, drift, round,\n"
        "# model, setup_change, log_error, ...\n"
        "builtin_interfaces/Time stamp\n"
        "string kind\n"
        "string json  # the event as JSON: t [s], kind and its details\n"),
    STATUS: (
        "# The daemon's status snapshot (the answer of its status queryable).\n"
        "builtin_interfaces/Time stamp\n"
        "string json\n"),
    TORQUE_EFFECT: "string name\nfloat64[6] torque  # [N m; N on the insertion joint]\n",
    JOINT_TORQUE_TRUTH: (
        "# Simulator ground truth per joint [rad, m; N m, N on the insertion joint].\n"
        "std_msgs/Header header\n"
        "bool in_contact\n"
        "float64[6] position\n"
        "float64[6] velocity\n"
        "float64[6] acceleration\n"
        "float64[6] internal\n"
        "float64[6] external\n"
        "wrenchd_msgs/TorqueEffect[] effects  # the torque of each modelled effect\n"),
}
OWN_TYPES = (ESTIMATE, EVENT, STATUS, TORQUE_EFFECT, JOINT_TORQUE_TRUTH)

#: QoS a channel says it was offered with, as rosbag2 (Humble) records it: reliable,
#: volatile, automatic liveliness, infinite durations (rosbag2's channel metadata key
#: ``offered_qos_profiles``, YAML); ``ros2 bag play`` publishes with it.
_INFINITE = "\n    sec: 9223372036\n    nsec: 854775807"
OFFERED_QOS = ("- history: 3\n  depth: 0\n  reliability: 1\n  durability: 2\n"
               f"  deadline:{_INFINITE}\n  lifespan:{_INFINITE}\n  liveliness: 1\n"
               f"  liveliness_lease_duration:{_INFINITE}\n"
               "  avoid_ros_namespace_conventions: false")

_PRIMITIVES = frozenset(("bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16",
                         "uint16", "int32", "uint32", "int64", "uint64", "string", "wstring"))
_FIELD_TYPE = re.compile(r"^\s*([A-Za-z0-9_/]+)(?:\[[^\]]*\])?\s+\w", re.MULTILINE)
_DTYPES = {"bool": np.bool_, "byte": np.uint8, "char": np.uint8, "float32": np.float32,
           "float64": np.float64, "int8": np.int8, "uint8": np.uint8, "int16": np.int16,
           "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32, "int64": np.int64,
           "uint64": np.uint64}
_CDR_LE = b"\x00\x01"        # the encapsulation header of little-endian CDR


def _referenced(name: str, package: str) -> str:
    """A field's type as rosbag2 names the dependency: as written, with the package added
    where it has none."""
    return name if "/" in name else f"{package}/{name}"


def _full_name(referenced: str) -> str:
    parts = referenced.split("/")
    return f"{parts[0]}/msg/{parts[-1]}"


def dependencies(typename: str) -> list[str]:
    """The types ``typename``'s text names directly, as it names them, in name order."""
    package = typename.split("/")[0]
    text = re.sub(r"#.*", "", MSG_TEXT[typename])
    return sorted({_referenced(t, package) for t in _FIELD_TYPE.findall(text)
                   if t not in _PRIMITIVES})


@functools.cache
def full_definition(typename: str) -> str:
    """The complete ``ros2msg`` definition of ``typename``, as rosbag2 writes it (rosbag2's
    ``docs/message_definition_encoding.md``).

    The type's .msg text, then for each type it depends on (depth first, each once, in name
    order, as rosbag2's ``LocalMessageDefinitionSource`` walks them) a line of 80 ``=``, a line
    ``MSG: pkg/Type`` and that type's text. The ``MSG:`` line names the type as the fields
    reference it, ``pkg/Type`` (a field type without package is completed with the referring
    type's package), as rosbag2 writes it: Foxglove's parser (``@foxglove/rosmsg``) matches the
    two names literally and fails on ``pkg/msg/Type`` lines below ``pkg/Type`` fields.
    """
    seen: set[str] = set()

    def walk(name: str) -> str:
        out = MSG_TEXT[name]
        for dep in dependencies(name):
            if dep not in seen:
                seen.add(dep)
                out += "\n" + "=" * 80 + "\nMSG: " + dep + "\n" + walk(_full_name(dep))
        return out

    return walk(typename)


@functools.cache
def typestore():
    """The ``rosbags`` type store: ROS 2 Humble's types and ``wrenchd_msgs`` (built once, ~0.3 s):
    what every CDR message wrenchd reads or writes is (de)serialised with."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict = {}
    for name in OWN_TYPES:
        types.update(get_types_from_msg(MSG_TEXT[name], name))
    store.register(types)
    return store


@functools.cache
def jazzy_typestore():
    """ROS 2 Jazzy's types (built once): the definitions REP-2011 type hashes (RIHS01) are
    computed from, as rmw_zenoh's keys carry them (Humble has no type hashes)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def message_class(typename: str):
    """The ``rosbags`` dataclass of ``typename``."""
    return typestore().types[typename]


def split_ns(stamp_ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of ``stamp_ns`` [ns], as ``builtin_interfaces/msg/Time`` holds it."""
    return divmod(int(stamp_ns), NS_PER_S)


def stamp(stamp_ns: int):
    """``builtin_interfaces/msg/Time`` of ``stamp_ns`` [ns] (0 <= stamp < 2**31 s)."""
    sec, nanosec = split_ns(stamp_ns)
    return message_class(TIME)(sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame_id: str):
    """``std_msgs/msg/Header``."""
    return message_class(HEADER)(stamp=stamp(stamp_ns), frame_id=frame_id)


def time_ns(time_msg, where: str = "header.stamp") -> int:
    """Nanoseconds of a ``builtin_interfaces/msg/Time`` (``where`` names it in the error).

    Raises:
        DataError: ``sec`` is negative or ``nanosec`` is not in [0, 1e9).
    """
    sec, nanosec = int(time_msg.sec), int(time_msg.nanosec)
    if sec < 0:
        raise DataError(f"{where}.sec out of range [0, 2^31): {sec}")
    if not 0 <= nanosec < NS_PER_S:
        raise DataError(f"{where}.nanosec out of range: {nanosec}")
    return sec * NS_PER_S + nanosec


def serialize(message) -> bytes:
    """Little-endian CDR of a ``rosbags`` message (its type is the one it was made as)."""
    return bytes(typestore().serialize_cdr(message, message.__msgtype__))


@functools.lru_cache(maxsize=16)
def _file_typestore(typename: str, definition: str):
    """A type store holding ``typename`` as ``definition`` (a file's ``ros2msg`` schema) says,
    and the types that definition carries with it."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    try:
        store.register(get_types_from_msg(definition, typename))
    except Exception as exc:  # noqa: BLE001 - rosbags raises its own parse and type errors
        raise DataError(f"cannot read the definition of {typename}: "
                        f"{type(exc).__name__}: {exc}") from None
    return store


def deserialize(data: bytes, typename: str, definition: str | bytes | None = None):
    """The ``typename`` message in ``data`` (CDR).

    ``definition``: the ``ros2msg`` schema the file stores with the message. A file written
    with another definition of the type than today's (an earlier version's) is decoded with
    its own; None or today's: :data:`MSG_TEXT`'s.

    Raises:
        DataError: ``data`` is not a CDR ``typename``, or ``definition`` is not one.
    """
    if isinstance(definition, (bytes, bytearray, memoryview)):
        definition = bytes(definition).decode(errors="replace")
    ours = definition is None or (typename in MSG_TEXT
                                  and definition == full_definition(typename))
    store = typestore() if ours else _file_typestore(typename, definition)
    try:
        return store.deserialize_cdr(bytes(data), typename)
    except Exception as exc:  # noqa: BLE001 - rosbags raises struct/index/unicode errors
        raise DataError(f"not a CDR {typename}: {type(exc).__name__}: {exc}") from None


def is_cdr(payload: bytes) -> bool:
    """True when ``payload`` starts with little-endian CDR's encapsulation header (JSON text
    starts with ``{`` or white space)."""
    return bytes(payload[:2]) == _CDR_LE


def _value(kind, spec, value, where: str):
    from rosbags.interfaces import Nodetype

    if kind == Nodetype.NAME:
        if value is None:
            value = {}
        if not isinstance(value, Mapping):
            raise DataError(f"{where} must be an object, got {value!r}")
        return from_fields(spec, value, where + ".")
    if kind == Nodetype.BASE:
        base = spec[0]
        if value is None:
            return "" if base in ("string", "wstring") else _DTYPES[base](0).item()
        if base in ("string", "wstring"):
            return str(value)
        return _DTYPES[base](value).item()
    (sub_kind, sub_spec), length = spec                     # ARRAY or SEQUENCE
    if sub_kind == Nodetype.BASE and sub_spec[0] in _DTYPES:
        if value is None:
            return np.zeros(length if kind == Nodetype.ARRAY else 0, dtype=_DTYPES[sub_spec[0]])
        arr = np.asarray(value, dtype=_DTYPES[sub_spec[0]])
        if arr.ndim != 1 or (kind == Nodetype.ARRAY and len(arr) != length):
            raise DataError(f"{where} must be {length or 'a list of'} numbers, got {value!r}")
        return arr
    items = list(value or ())
    if kind == Nodetype.ARRAY:
        items += [None] * (length - len(items))
    return [_value(sub_kind, sub_spec, item, f"{where}[{i}]") for i, item in enumerate(items)]


def from_fields(typename: str, fields: Mapping[str, Any], where: str = "") -> Any:
    """A ``typename`` message from a JSON-like object of its fields; fields left out take
    ROS's defaults (zero, false, empty).

    Raises:
        DataError: an unknown field, or a value of the wrong shape.
    """
    _, defs = typestore().fielddefs[typename]
    names = [name for name, _ in defs]
    unknown = set(fields) - set(names)
    if unknown:
        raise DataError(f"{typename} has no field(s) {sorted(unknown)}")
    values = {name: _value(kind, spec, fields.get(name), f"{where}{name}")
              for name, (kind, spec) in defs}
    return message_class(typename)(**values)


def to_fields(message) -> Any:
    """A ``rosbags`` message as JSON-like Python values (objects, lists, numbers, strings)."""
    if hasattr(message, "__msgtype__"):
        return {name: to_fields(getattr(message, name))
                for name in message.__dataclass_fields__ if name != "__msgtype__"}
    if isinstance(message, np.ndarray):
        return message.tolist()
    if isinstance(message, list):
        return [to_fields(v) for v in message]
    return message


class Ros2Channels:
    """Registers ROS 2 channels on an mcap :class:`~mcap.writer.Writer` (one schema per type).

    The writer must have been started with profile ``mcap.well_known.Profile.ROS2``.
    """

    def __init__(self, writer) -> None:
        self.writer = writer
        self._schemas: dict[str, int] = {}
        self.ids: dict[str, int] = {}

    def add(self, topic: str, typename: str) -> int:
        """The channel id of ``topic`` carrying ``typename`` (registered on first use)."""
        if topic not in self.ids:
            if typename not in self._schemas:
                self._schemas[typename] = self.writer.register_schema(
                    typename, SchemaEncoding.ROS2, full_definition(typename).encode())
            self.ids[topic] = self.writer.register_channel(
                topic, MessageEncoding.CDR, self._schemas[typename],
                {"offered_qos_profiles": OFFERED_QOS})
        return self.ids[topic]
