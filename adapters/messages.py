"""Wire encodings of joint states and wrenches: JSON mirroring the ROS messages, and ROS 2 CDR.

Both encodings carry ``sensor_msgs/JointState`` and ``geometry_msgs/WrenchStamped``:

* ``json``: an object whose fields mirror the ROS message (``header.stamp.sec``/``nanosec``,
  ``header.frame_id``, ``name``, ``position``, ``velocity``, ``effort``; ``wrench.force.x..z``,
  ``wrench.torque.x..z``), plus, on wrenches, wrenchd's extra fields (free-motion flag, model
  version, ...) under ``"wrenchd"``.
* ``cdr``: the ROS 2 serialisation (little-endian CDR with its 4-byte encapsulation header),
  exactly what a ROS 2 node bridged to zenoh (``zenoh-bridge-ros2dds``, ``rmw_zenoh``)
  publishes, through the ``rosbags`` type store of :mod:`wrenchd.adapters.ros2_msgs` (ROS 2
  Humble definitions; the per-sample joint state and wrench go through
  :mod:`wrenchd.adapters.cdr_wire`, the same bytes in a few ``struct`` calls). CDR has
  no room for extra fields: the gate flag and model version of a CDR arm go to the events and
  status keys and to the MCAP log.

Decoders validate everything a pipeline relies on and raise :class:`DataError` with the reason:
malformed bytes, wrong types, lengths that differ, no samples.
"""

from __future__ import annotations

import json
import math
from typing import Any, Literal

import numpy as np
import orjson

from wrenchd.adapters import cdr_wire
from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.ros2_msgs import NS_PER_S, split_ns
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.series import JointSample

Encoding = Literal["json", "cdr"]
ENCODINGS: tuple[str, ...] = ("json", "cdr")
_SEC_LIMIT = 2 ** 31
JOINT_STATE_TYPE = ros2.JOINT_STATE
WRENCH_TYPE = ros2.WRENCH_STAMPED
_NUMPY = orjson.OPT_SERIALIZE_NUMPY


def stamp_ns_of(t_s: float) -> int:
    """Seconds to integer nanoseconds (rounded)."""
    return int(round(t_s * NS_PER_S))


# -- JSON ---------------------------------------------------------------------------------
_NUMBER_TYPES = frozenset((int, float))
_STR_TYPE = frozenset((str,))           # JSON text parses to exact str, never a subclass


def _vector(message: dict[str, Any], field: str) -> list:
    """The list of numbers under ``field`` (checked; bool and strings are not numbers)."""
    value = message.get(field)
    if not isinstance(value, list):
        raise DataError(f"field {field!r} must be a list of numbers, got {type(value).__name__}")
    if not _NUMBER_TYPES.issuperset(map(type, value)):
        raise DataError(f"field {field!r} must hold only numbers")
    return value


def _arrays(position: list, velocity: list, effort: list) -> tuple[np.ndarray, ...]:
    """float64 arrays of the three vectors; one conversion when their lengths agree."""
    try:
        if len(position) == len(velocity) == len(effort):
            block = np.array((position, velocity, effort), dtype=np.float64)
            return block[0], block[1], block[2]
        return tuple(np.array(v, dtype=np.float64) for v in (position, velocity, effort))
    except OverflowError:
        raise DataError("a joint state field holds a number beyond float64") from None


def _header(message: dict[str, Any]) -> tuple[int, str]:
    header = message.get("header")
    if not isinstance(header, dict):
        raise DataError("missing object 'header'")
    stamp = header.get("stamp")
    if not isinstance(stamp, dict):
        raise DataError("missing object 'header.stamp'")
    sec, nanosec = stamp.get("sec"), stamp.get("nanosec")
    if type(sec) is not int or type(nanosec) is not int:
        raise DataError("header.stamp.sec and .nanosec must be integers")
    if not 0 <= sec < _SEC_LIMIT:                     # ROS builtin_interfaces/Time: int32 sec
        raise DataError(f"header.stamp.sec out of range [0, 2^31): {str(sec)[:24]}")
    if not 0 <= nanosec < NS_PER_S:
        raise DataError(f"header.stamp.nanosec out of range: {nanosec}")
    frame = header.get("frame_id", "")
    if not isinstance(frame, str):
        raise DataError("header.frame_id must be a string")
    return sec * NS_PER_S + nanosec, frame


def _json_object(payload: bytes, what: str) -> dict[str, Any]:
    """Parse ``payload`` as one JSON object, or raise DataError naming ``what`` it should be."""
    try:
        message = orjson.loads(payload)
    except orjson.JSONDecodeError:
        # orjson is strict; the standard parser also takes NaN/Infinity literals (Python
        # publishers write them) and integers beyond 64 bits, so that validation can then
        # name the bad field instead of only saying "not JSON"
        try:
            message = json.loads(payload)
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
            raise DataError(f"not JSON: {exc}") from None
    if not isinstance(message, dict):
        raise DataError(f"a {what} must be a JSON object, got {type(message).__name__}")
    return message


def _decode_json_joint_state(payload: bytes) -> JointSample:
    message = _json_object(payload, "joint state")
    stamp_ns, frame = _header(message)
    names = message.get("name", [])
    if not isinstance(names, list) or not _STR_TYPE.issuperset(map(type, names)):
        raise DataError("field 'name' must be a list of strings")
    return JointSample(stamp_ns, frame, tuple(names), *_arrays(
        _vector(message, "position"), _vector(message, "velocity"), _vector(message, "effort")))


def _finite_floats(values, what: str) -> list[float]:
    """``values`` as Python floats, all finite (a finite sum proves every term finite: one
    call per sample instead of NumPy's test)."""
    f = np.asarray(values, dtype=np.float64).ravel().tolist()
    if not math.isfinite(sum(f)) and not all(map(math.isfinite, f)):
        raise ValueError(f"{what} must be finite to be encoded as JSON")
    return f


def _json_joint_state(stamp_ns: int, frame_id: str, names, position, velocity, effort) -> bytes:
    sec, nanosec = split_ns(stamp_ns)
    return orjson.dumps({"header": {"stamp": {"sec": sec, "nanosec": nanosec},
                                    "frame_id": frame_id},
                         "name": list(names),
                         "position": _finite_floats(position, "position"),
                         "velocity": _finite_floats(velocity, "velocity"),
                         "effort": _finite_floats(effort, "effort")})


def _json_wrench(stamp_ns: int, frame_id: str, wrench: np.ndarray,
                 extra: dict[str, Any] | None) -> bytes:
    sec, nanosec = split_ns(stamp_ns)
    f = _finite_floats(wrench, "a wrench")
    message = {"header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
               "wrench": {"force": {"x": f[0], "y": f[1], "z": f[2]},
                          "torque": {"x": f[3], "y": f[4], "z": f[5]}}}
    if extra:
        message["wrenchd"] = extra
    return orjson.dumps(message, option=_NUMPY)


def _decode_json_wrench(payload: bytes) -> tuple[int, str, np.ndarray, dict[str, Any]]:
    message = _json_object(payload, "wrench")
    stamp_ns, frame = _header(message)
    w = message.get("wrench")
    parts = [w.get(k) if isinstance(w, dict) else None for k in ("force", "torque")]
    if not all(isinstance(p, dict) for p in parts):
        raise DataError("wrench.force and wrench.torque must be objects")
    values = [p.get(a) for p in parts for a in "xyz"]
    if not all(type(v) in (int, float) for v in values):
        raise DataError("wrench.force and wrench.torque x, y, z must be numbers")
    try:
        wrench = np.array(values, dtype=np.float64)
    except OverflowError:
        raise DataError("wrench holds a number beyond float64") from None
    extra = message.get("wrenchd", {})
    if not isinstance(extra, dict):
        raise DataError("field 'wrenchd' must be an object")
    return stamp_ns, frame, wrench, extra


# -- CDR ----------------------------------------------------------------------------------
def _cdr_joint_state(stamp_ns: int, frame_id: str, names, position, velocity, effort) -> bytes:
    fast = cdr_wire.encode_joint_state(stamp_ns, frame_id, names, position, velocity, effort)
    if fast is not None:
        return fast
    return ros2.serialize(ros2.message_class(JOINT_STATE_TYPE)(
        header=ros2.header(stamp_ns, frame_id), name=list(names),
        position=np.asarray(position, dtype=np.float64),
        velocity=np.asarray(velocity, dtype=np.float64),
        effort=np.asarray(effort, dtype=np.float64)))


def _decode_cdr_joint_state(payload: bytes) -> JointSample:
    fast = cdr_wire.decode_joint_state(payload)
    if fast is not None:
        return JointSample(*fast)
    msg = ros2.deserialize(payload, JOINT_STATE_TYPE)
    return JointSample(ros2.time_ns(msg.header.stamp), msg.header.frame_id, tuple(msg.name),
                       np.array(msg.position, dtype=np.float64),
                       np.array(msg.velocity, dtype=np.float64),
                       np.array(msg.effort, dtype=np.float64))


def _cdr_wrench(stamp_ns: int, frame_id: str, wrench: np.ndarray) -> bytes:
    fast = cdr_wire.encode_wrench_stamped(stamp_ns, frame_id, wrench)
    if fast is not None:
        return fast
    vector = ros2.message_class(ros2.VECTOR3)
    f = [float(v) for v in wrench]
    return ros2.serialize(ros2.message_class(WRENCH_TYPE)(
        header=ros2.header(stamp_ns, frame_id), wrench=ros2.message_class(ros2.WRENCH)(
            force=vector(x=f[0], y=f[1], z=f[2]), torque=vector(x=f[3], y=f[4], z=f[5]))))


def _decode_cdr_wrench(payload: bytes) -> tuple[int, str, np.ndarray, dict[str, Any]]:
    msg = ros2.deserialize(payload, WRENCH_TYPE)
    w = msg.wrench
    return (ros2.time_ns(msg.header.stamp), msg.header.frame_id,
            np.array([w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z]), {})


# -- public -------------------------------------------------------------------------------
def check_encoding(encoding: str) -> str:
    if encoding not in ENCODINGS:
        raise ConfigError(f"unknown encoding {encoding!r}; choose one of {list(ENCODINGS)}")
    return encoding


def prepare_encoding(encoding: str) -> None:
    """Build what ``encoding`` needs now (the CDR type store takes ~0.3 s to build), so the
    first message decoded on a hot path does not pay for it."""
    if check_encoding(encoding) == "cdr":
        ros2.typestore()


def encode_joint_state(encoding: str, stamp_ns: int, names, position, velocity, effort,
                       frame_id: str = "") -> bytes:
    """A ``sensor_msgs/JointState`` in ``encoding`` (``json`` or ``cdr``)."""
    if check_encoding(encoding) == "json":
        return _json_joint_state(stamp_ns, frame_id, names, position, velocity, effort)
    return _cdr_joint_state(stamp_ns, frame_id, names, position, velocity, effort)


def decode_joint_state(encoding: str, payload: bytes) -> JointSample:
    """Decode and check a joint state: equal, non-zero lengths (names may be empty).

    Raises:
        DataError: malformed payload, wrong field types, unequal or zero lengths.
    """
    if check_encoding(encoding) == "json":
        msg = _decode_json_joint_state(payload)
    else:
        msg = _decode_cdr_joint_state(payload)
    n = len(msg.position)
    if n == 0 or len(msg.velocity) != n or len(msg.effort) != n:
        raise DataError(f"position, velocity and effort must have one equal, non-zero length; "
                        f"got {len(msg.position)}, {len(msg.velocity)}, {len(msg.effort)}")
    if msg.name and len(msg.name) != n:
        raise DataError(f"{len(msg.name)} names for {n} joints")
    return msg


def encode_wrench(encoding: str, stamp_ns: int, wrench: np.ndarray, frame_id: str = "psm_base",
                  extra: dict[str, Any] | None = None) -> bytes:
    """A ``geometry_msgs/WrenchStamped`` ``[Fx, Fy, Fz, Tx, Ty, Tz]`` [N, N m]; ``extra`` only
    in JSON (CDR has no room for it)."""
    if check_encoding(encoding) == "json":
        return _json_wrench(stamp_ns, frame_id, wrench, extra)
    return _cdr_wrench(stamp_ns, frame_id, wrench)


def decode_wrench(encoding: str, payload: bytes) -> tuple[int, str, np.ndarray, dict[str, Any]]:
    """``(stamp_ns, frame_id, wrench (6,), extra)`` of a WrenchStamped payload."""
    if check_encoding(encoding) == "json":
        return _decode_json_wrench(payload)
    return _decode_cdr_wrench(payload)


def nan_to_none(x: Any) -> Any:
    """``x`` made fit for JSON, which has no NaN: every non-finite float in it (nested in
    dicts, lists and tuples; tuples become lists) becomes ``None``."""
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: nan_to_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [nan_to_none(v) for v in x]
    return x


# -- set-up changes (wrenchd's own message, JSON only) ------------------------------------
#: fields a set-up change may carry besides its stamp
_SETUP_FIELDS = {"kind", "pressure_mmhg", "instrument", "note"}


def encode_setup_change(stamp_ns: int | None = None, pressure_mmhg: float | None = None,
                        note: str | None = None, kind: str | None = None,
                        instrument: str | None = None) -> bytes:
    """A ``setup`` message: the set-up changed at ``stamp_ns`` (None: "now", the arm's latest
    sample), with its ``kind`` (None: left out, read as ``"pressure"``), the insufflation
    pressure [mmHg], the new instrument's name and a note if known."""
    body: dict[str, Any] = {}
    if kind is not None:
        body["kind"] = str(kind)
    if instrument is not None:
        body["instrument"] = str(instrument)
    if stamp_ns is not None:
        sec, nanosec = split_ns(stamp_ns)
        body["stamp"] = {"sec": sec, "nanosec": nanosec}
    if pressure_mmhg is not None:
        body["pressure_mmhg"] = float(pressure_mmhg)
    if note is not None:
        body["note"] = str(note)
    return orjson.dumps(body)


def decode_setup_change(payload: bytes) -> tuple[int | None, dict[str, Any]]:
    """A ``setup`` message -> (stamp [ns] or None, detail): a JSON object with an optional
    ``stamp`` (``sec``, ``nanosec``), ``kind`` (one of
    :data:`~wrenchd.models.adaptation.adapter.SETUP_KINDS`; default ``"pressure"``, or
    ``"instrument"`` when an ``instrument`` is named), ``pressure_mmhg`` (a number in
    [0, 100]), ``instrument`` (the new instrument's name, text of at most 100 characters, only
    with kind ``"instrument"``) and ``note`` (text, at most 200 characters); anything else is
    refused with :class:`DataError`. The detail carries the kind unless the message
    left it to the default."""
    message = _json_object(payload, "set-up change")
    unknown = set(message) - _SETUP_FIELDS - {"stamp"}
    if unknown:
        raise DataError(f"set-up change: unknown field(s) {sorted(unknown)[:5]}; expected "
                        f"'stamp', 'kind', 'pressure_mmhg', 'instrument', 'note'")
    stamp_ns = None
    if "stamp" in message:
        try:
            stamp_ns, _ = _header({"header": {"stamp": message["stamp"]}})
        except DataError as exc:             # the same rules as a header's stamp
            raise DataError("set-up change: " + str(exc).replace("header.stamp", "stamp")
                            .replace("missing object 'stamp'",
                                     "'stamp' must be an object {sec, nanosec}")) from None
    from wrenchd.models.adaptation.adapter import SETUP_KINDS

    kind = message.get("kind", "instrument" if "instrument" in message else "pressure")
    if kind not in SETUP_KINDS:
        raise DataError(f"set-up change: kind must be one of {', '.join(SETUP_KINDS)}, got "
                        f"{str(kind)[:24]}")
    detail: dict[str, Any] = {"kind": kind} if kind != "pressure" or "kind" in message else {}
    if "instrument" in message:
        name = message["instrument"]
        if not isinstance(name, str) or len(name) > 100:
            raise DataError("set-up change: instrument must be text of at most 100 characters")
        if kind != "instrument":
            raise DataError(f"set-up change: an instrument is named in a change of kind {kind}")
        detail["instrument"] = name
    if "pressure_mmhg" in message:
        p = message["pressure_mmhg"]
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0.0 <= p <= 100.0:
            raise DataError(f"set-up change: pressure_mmhg must be a number in [0, 100], "
                            f"got {str(p)[:24]}")
        detail["pressure_mmhg"] = float(p)
    if "note" in message:
        note = message["note"]
        if not isinstance(note, str) or len(note) > 200:
            raise DataError("set-up change: note must be text of at most 200 characters")
        detail["note"] = note
    return stamp_ns, detail
