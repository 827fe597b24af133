"""Sessions as MCAP files: JSON messages with JSON Schemas, readable by Foxglove Studio.

Layout (every message has ``log_time == publish_time == round(t * 1e9)`` ns, sim time from 0):

- ``/psm/measured_js`` (``sensor_msgs/JointState``-like): header, name, position, velocity,
  effort, six joints each.
- ``/psm/truth/wrench`` and, where the scenario has a sensor, ``/psm/truth/sensor_wrench``
  (``geometry_msgs/WrenchStamped``-like, frame ``psm_base``): true and sensed tip wrench.
- ``/psm/truth/torques``: in_contact, true joint position / velocity / acceleration, internal
  and external joint torque, and the per-effect torques under ``effects``.
- Metadata record ``wrenchd.session``: ``{"format": "wrenchd.session/1", "json": <metadata>}``.

Chunks are zstd-compressed and self-contained, so a file whose writer was killed still yields
every complete chunk (:func:`read_session_report`). Output bytes depend only on the session:
no wall-clock time is written and the header's library string is fixed.
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass, field
from collections.abc import Callable, Mapping
from typing import IO, Any

import numpy as np
import zstandard
from mcap.exceptions import EndOfFile, InvalidMagic, McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, Metadata
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import CompressionType, Writer

from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import JOINT_NAMES, N_JOINTS, GroundTruth, JointStates, Session

TOPIC_JOINT_STATES = "/psm/measured_js"
TOPIC_WRENCH = "/psm/truth/wrench"
TOPIC_SENSOR_WRENCH = "/psm/truth/sensor_wrench"
TOPIC_TORQUES = "/psm/truth/torques"
SESSION_METADATA_NAME = "wrenchd.session"
SESSION_FORMAT = "wrenchd.session/1"
DEFAULT_CHUNK_SIZE = 1 << 20  # bytes of uncompressed messages per chunk
_LIBRARY = "wrenchd.adapters.mcap_session/1"  # fixed, so equal sessions give equal bytes
_NS_PER_S = 1_000_000_000
# Every number is written with 10 significant digits ("%.10g": relative error <= 5e-10,
# e.g. <= 1e-9 rad at 2 rad), far below encoder resolution and current-sensing noise. It
# keeps JSON numbers short and formats about twice as fast as json's shortest-repr floats,
# which matters for hour-long sessions. Zeros are written as 0, integers without fraction.
_FLOAT = "%.10g"
_VEC = "[" + ",".join([_FLOAT] * 6) + "]"
_STAMP = '{"header":{"stamp":{"sec":%d,"nanosec":%d},"frame_id":'
_WRENCH_TEMPLATE = (_STAMP + '"psm_base"},"wrench":{"force":{"x":%.10g,"y":%.10g,"z":%.10g},'
                    '"torque":{"x":%.10g,"y":%.10g,"z":%.10g}}}')
_MOTION_NAMES = ("position", "velocity", "acceleration", "internal_torque", "external_torque")

_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode

# --------------------------------------------------------------------------- schemas

_VECTOR6 = {"type": "array", "items": {"type": "number"}, "minItems": 6, "maxItems": 6}
_HEADER = {
    "type": "object",
    "properties": {
        "stamp": {
            "type": "object",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nanosec": {"type": "integer", "minimum": 0, "maximum": _NS_PER_S - 1},
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

# --------------------------------------------------------------------------- writing


def _check_finite(name: str, values: np.ndarray) -> None:
    if not np.all(np.isfinite(values)):
        raise DataError(f"{name} contains NaN or Inf; cannot write it")


def _add_messages(writer: Writer, channels: list[int], log_times: list[int],
                  messages: list[bytes]) -> None:
    add = writer.add_message
    for channel, log_time, data in zip(channels, log_times, messages, strict=True):
        add(channel, log_time, data, log_time)


class SessionWriter:
    """Streams a session into an MCAP file, block by block.

    Args:
        path: output file; overwritten.
        metadata: JSON-serialisable session metadata, written first as ``wrenchd.session``.
        chunk_size: uncompressed bytes per chunk [B]; a killed writer loses at most one chunk.

    Use as a context manager, or call :meth:`open` and :meth:`close`. Blocks must follow
    each other in time; whether truth, a sensor and which effects are written is fixed by
    the first block that carries truth.
    """

    def __init__(self, path: str | os.PathLike[str], *, metadata: Mapping[str, Any] | None = None,
                 chunk_size: int = DEFAULT_CHUNK_SIZE) -> None:
        self.path = os.fspath(path)
        self.metadata = dict(metadata or {})
        self.chunk_size = int(chunk_size)
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._last_ns = -1
        self._effect_names: tuple[str, ...] | None = None
        self._has_truth: bool | None = None
        self._has_sensor = False
        self.samples_written = 0

    def open(self) -> SessionWriter:
        """Creates the file, writes the header, the channel of joint states and the metadata."""
        if self._writer is not None:
            raise AdapterError(f"{self.path}: writer already open")
        try:
            session_json = json.dumps(self.metadata, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise DataError(f"session metadata is not JSON-serialisable: {exc}") from exc
        try:
            self._file = open(self.path, "wb")
            self._writer = Writer(self._file, chunk_size=self.chunk_size,
                                  compression=CompressionType.ZSTD)
            self._writer.start(profile="", library=_LIBRARY)
        except OSError as exc:
            if self._file is not None:
                self._file.close()
            self._file = self._writer = None
            raise AdapterError(f"cannot create {self.path}: {exc}") from exc
        self._channel(TOPIC_JOINT_STATES)
        self.write_metadata(SESSION_METADATA_NAME, {"format": SESSION_FORMAT, "json": session_json})
        return self

    def _open_writer(self) -> Writer:
        if self._writer is None:
            raise AdapterError(f"{self.path}: writer is not open")
        return self._writer

    def _channel(self, topic: str) -> int:
        if topic not in self._channels:
            writer = self._open_writer()
            schema = TOPIC_SCHEMAS[topic]
            name = schema["title"]
            try:
                if name not in self._schemas:
                    self._schemas[name] = writer.register_schema(
                        name, "jsonschema", json.dumps(schema, sort_keys=True).encode())
                self._channels[topic] = writer.register_channel(topic, "json", self._schemas[name])
            except OSError as exc:
                raise AdapterError(f"cannot write {self.path}: {exc}") from exc
        return self._channels[topic]

    def write_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Adds an MCAP Metadata record ``name`` holding the string map ``data``."""
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
            raise DataError(f"metadata {name!r} must map str to str")
        try:
            self._open_writer().add_metadata(name, dict(data))
        except OSError as exc:
            raise AdapterError(f"cannot write {self.path}: {exc}") from exc

    def write_joint_states(self, joint_states: JointStates,
                           truth: GroundTruth | None = None) -> int:
        """Appends a block of samples (and their ground truth, row-aligned); returns its length.

        Raises:
            DataError: the block overlaps earlier samples, has negative times, non-finite
                values, or changes whether truth / sensor / which effects are written.
        """
        writer = self._open_writer()
        n = len(joint_states)
        if n == 0:
            return 0
        stamps = np.rint(joint_states.t * 1e9).astype(np.int64)
        if stamps[0] < 0 or stamps[0] <= self._last_ns or np.any(np.diff(stamps) <= 0):
            raise DataError(
                f"sample times must be >= 0 and increase by >= 1 ns across blocks; block starts "
                f"at {joint_states.t[0]!r} s after {self._last_ns} ns")
        self._check_block(joint_states, truth)
        # (n, 2) sec and nanosec as floats (exact below 2**53), repeated in every message header
        header = np.column_stack([stamps // _NS_PER_S, stamps % _NS_PER_S]).astype(np.float64)
        columns = [header, joint_states.position, joint_states.velocity, joint_states.effort]
        names = _ENCODE(list(joint_states.names)).replace("%", "%%")  # literal in a %-template
        templates = [_STAMP + '""},"name":' + names + ',"position":' + _VEC + ',"velocity":'
                     + _VEC + ',"effort":' + _VEC + "}"]
        channels = [self._channels[TOPIC_JOINT_STATES]]
        if truth is not None:
            wrenches = [("truth.external_wrench", TOPIC_WRENCH, truth.external_wrench)]
            if truth.sensor_wrench is not None:
                wrenches.append(("truth.sensor_wrench", TOPIC_SENSOR_WRENCH, truth.sensor_wrench))
            for name, topic, values in wrenches:
                _check_finite(name, values)
                columns += [header, values]
                templates.append(_WRENCH_TEMPLATE)
                channels.append(self._channels[topic])
            motion = [truth.position, truth.velocity, truth.acceleration, truth.internal_torque,
                      truth.external_torque, *truth.effects.values()]
            for name, values in zip(_MOTION_NAMES + tuple(truth.effects), motion):
                _check_finite(f"truth.{name}", values)
            columns += [header, *motion]
            effects = ",".join(_ENCODE(k).replace("%", "%%") + ":" + _VEC for k in truth.effects)
            torques = ('""},"in_contact":%s,"position":' + _VEC + ',"velocity":' + _VEC
                       + ',"acceleration":' + _VEC + ',"internal":' + _VEC + ',"external":' + _VEC
                       + ',"effects":{' + effects + "}}")
            channels.append(self._channels[TOPIC_TORQUES])
            sample = "\n".join(templates) + "\n" + _STAMP
            by_contact = {c: sample + torques.replace("%s", c, 1) for c in ("false", "true")}
            block = "\n".join(by_contact["true" if c else "false"]
                              for c in truth.in_contact.tolist())
        else:
            block = "\n".join(templates * n)
        # One %-format per block turns every number into text in C; "\n" separates the
        # messages (JSON escapes any newline inside a string).
        args = np.concatenate(columns, axis=1)
        messages = (block % tuple(args.ravel().tolist())).encode().split(b"\n")
        try:
            _add_messages(writer, channels * n, np.repeat(stamps, len(channels)).tolist(), messages)
        except OSError as exc:
            raise AdapterError(f"cannot write {self.path}: {exc}") from exc
        self._last_ns = int(stamps[-1])
        self.samples_written += n
        return n

    def _check_block(self, joint_states: JointStates, truth: GroundTruth | None) -> None:
        if truth is not None and len(truth) != len(joint_states):
            raise DataError(f"truth has {len(truth)} samples, joint states {len(joint_states)}")
        if self._has_truth is None:  # the first block fixes the layout
            self._has_truth = truth is not None
            if truth is not None:
                self._effect_names = tuple(truth.effects)
                self._has_sensor = truth.sensor_wrench is not None
                for topic in (TOPIC_WRENCH, TOPIC_SENSOR_WRENCH, TOPIC_TORQUES):
                    if topic != TOPIC_SENSOR_WRENCH or self._has_sensor:
                        self._channel(topic)
        if (truth is not None) != self._has_truth:
            raise DataError("every block must carry truth, or none may")
        if truth is not None:
            if tuple(truth.effects) != self._effect_names:
                raise DataError(f"effects {tuple(truth.effects)} differ from the first block's "
                                f"{self._effect_names}")
            if (truth.sensor_wrench is not None) != self._has_sensor:
                raise DataError("every truth block must carry sensor_wrench, or none may")

    def close(self) -> None:
        """Writes the last chunk, the summary and the footer, and closes the file."""
        if self._writer is None:
            return
        writer, file = self._writer, self._file
        self._writer = self._file = None
        try:
            writer.finish()
        except OSError as exc:
            raise AdapterError(f"cannot finish {self.path}: {exc}") from exc
        finally:
            file.close()

    def __enter__(self) -> SessionWriter:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()


def write_session(path: str | os.PathLike[str], session: Session, *,
                  chunk_size: int = DEFAULT_CHUNK_SIZE, block_size: int = 8192) -> None:
    """Writes ``session`` to ``path`` as MCAP; equal sessions give byte-identical files.

    Args:
        chunk_size: uncompressed bytes per chunk [B].
        block_size: samples formatted per step; bounds the memory of the formatting.
    """
    js, truth = session.joint_states, session.truth
    with SessionWriter(path, metadata=session.metadata, chunk_size=chunk_size) as writer:
        for start in range(0, len(js), block_size):
            stop = min(start + block_size, len(js))
            writer.write_joint_states(
                js.slice(start, stop), None if truth is None else truth.slice(start, stop))


# --------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class ReadInfo:
    """What :func:`read_session_report` found in the file.

    Attributes:
        truncated: the file ended before its footer (e.g. the writer was killed).
        messages: message records recovered, every topic.
        chunks: complete chunks read.
        topic_messages: recovered messages per topic.
        dropped_samples: joint-state samples left out because their truth was cut off.
        metadata: every other Metadata record, by name.
    """

    truncated: bool
    messages: int
    chunks: int
    topic_messages: dict[str, int]
    dropped_samples: int
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)


class _StrictStream:
    """A file whose short reads raise, so a record cut off by truncation is never parsed."""

    def __init__(self, file: IO[bytes]) -> None:
        self._file = file

    def read(self, size: int = -1) -> bytes:
        data = self._file.read(size)
        if size is not None and size > 0 and len(data) < size:
            raise EndOfFile()
        return data


class _SessionStreamReader(StreamReader):
    """mcap's StreamReader, skipping Message Index records unparsed.

    The reader does not need them (it reads every chunk whole), and parsing them costs a
    fifth of the read time. Overrides a private hook: should it be renamed in a later mcap,
    they are parsed again, which is slower but still correct.
    """

    def _read_record(self, opcode: int, length: int) -> Any:
        if opcode == Opcode.MESSAGE_INDEX:
            self._stream.read(length)
            return None
        return super()._read_record(opcode, length)


def _bad(topic: str, log_time: int, what: str) -> DataError:
    return DataError(f"{topic} message at log time {log_time} ns: {what}")


def _matrix(topic: str, name: str, rows: list[Any], log_times: list[int],
            width: int = 6) -> np.ndarray:
    """Rows of ``width`` finite numbers -> (n, width) float array; DataError names the message."""
    try:
        arr = np.array(rows)
        ok = arr.dtype.kind in "fi" and arr.shape == (len(rows), width)
    except (ValueError, TypeError):
        ok = False
    if not ok:
        for row, log_time in zip(rows, log_times):
            if (not isinstance(row, list) or len(row) != width or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)):
                raise _bad(topic, log_time, f"{name} must be {width} numbers, got {row!r}")
        raise _bad(topic, log_times[0], f"{name} must be {width} numbers")
    arr = arr.astype(np.float64)
    finite = np.isfinite(arr).all(axis=1)
    if not finite.all():
        i = int(np.argmin(finite))
        raise _bad(topic, log_times[i], f"{name} contains NaN or Inf: {rows[i]!r}")
    return arr


def _stamp_ns(message: dict[str, Any]) -> int:
    stamp = message["header"]["stamp"]
    sec, nanosec = stamp["sec"], stamp["nanosec"]
    if type(sec) is not int or type(nanosec) is not int or sec < 0 or not 0 <= nanosec < _NS_PER_S:
        raise ValueError(f"bad header.stamp {stamp!r}")
    return sec * _NS_PER_S + nanosec


def _js_fields(m: dict[str, Any]) -> tuple:
    return _stamp_ns(m), m["name"], m["position"], m["velocity"], m["effort"]


def _wrench_fields(m: dict[str, Any]) -> tuple:
    f, tq = m["wrench"]["force"], m["wrench"]["torque"]
    return _stamp_ns(m), [f["x"], f["y"], f["z"], tq["x"], tq["y"], tq["z"]]


def _torque_fields(m: dict[str, Any]) -> tuple:
    contact = m["in_contact"]
    if not isinstance(contact, bool):
        raise ValueError(f"in_contact must be true or false, got {contact!r}")
    return (_stamp_ns(m), contact, m["position"], m["velocity"], m["acceleration"],
            m["internal"], m["external"], m["effects"])


_FIELDS: dict[str, tuple[Callable[[dict[str, Any]], tuple], tuple[str, ...]]] = {
    TOPIC_JOINT_STATES: (_js_fields, ("stamp", "name", "position", "velocity", "effort")),
    TOPIC_WRENCH: (_wrench_fields, ("stamp", "wrench")),
    TOPIC_SENSOR_WRENCH: (_wrench_fields, ("stamp", "wrench")),
    TOPIC_TORQUES: (_torque_fields, ("stamp", "in_contact", "position", "velocity",
                                     "acceleration", "internal", "external", "effects")),
}


class _Collector:
    """Decodes batches of messages per topic into arrays, validating as it goes."""

    def __init__(self) -> None:
        self.arrays: dict[str, dict[str, list[np.ndarray]]] = {t: {} for t in _FIELDS}
        self.counts: dict[str, int] = {t: 0 for t in _FIELDS}
        self.names: list[str] | None = None
        self.effect_names: list[str] | None = None

    def add(self, topic: str, log_times: list[int], datas: list[bytes]) -> None:
        try:
            messages = json.loads(b"[" + b",".join(datas) + b"]")
        except ValueError:
            for log_time, data in zip(log_times, datas):
                try:
                    json.loads(data)
                except ValueError as exc:
                    raise _bad(topic, log_time, f"not valid JSON ({exc})") from exc
            raise _bad(topic, log_times[0], "batch is not valid JSON") from None
        extract, names = _FIELDS[topic]
        rows = []
        for message, log_time in zip(messages, log_times, strict=True):
            try:
                rows.append(extract(message))
            except (KeyError, TypeError, ValueError) as exc:
                raise _bad(topic, log_time, f"missing or malformed field: {exc!r}") from exc
        columns = dict(zip(names, zip(*rows)))
        out = self.arrays[topic]
        out.setdefault("stamp", []).append(np.array(columns["stamp"], dtype=np.int64))
        for name in ("position", "velocity", "effort", "wrench", "acceleration", "internal",
                     "external"):
            if name in columns:
                out.setdefault(name, []).append(
                    _matrix(topic, name, list(columns[name]), log_times))
        if topic == TOPIC_JOINT_STATES:
            self._check_names(columns["name"], log_times)
        if topic == TOPIC_TORQUES:
            out.setdefault("in_contact", []).append(np.array(columns["in_contact"], dtype=bool))
            self._add_effects(columns["effects"], log_times)
        self.counts[topic] += len(messages)

    def _check_names(self, names: tuple[Any, ...], log_times: list[int]) -> None:
        if self.names is None:
            self.names = names[0]
        for joint_names, log_time in zip(names, log_times):
            if joint_names != self.names:
                raise _bad(TOPIC_JOINT_STATES, log_time,
                           f"joint names {joint_names!r} differ from the first {self.names!r}")
        if not (isinstance(self.names, list) and len(self.names) == N_JOINTS
                and all(isinstance(n, str) for n in self.names)):
            raise _bad(TOPIC_JOINT_STATES, log_times[0],
                       f"name must be 6 strings, got {self.names!r}")

    def _add_effects(self, effects: tuple[Any, ...], log_times: list[int]) -> None:
        if self.effect_names is None:
            self.effect_names = list(effects[0]) if isinstance(effects[0], dict) else []
        for effect, log_time in zip(effects, log_times):
            if not isinstance(effect, dict) or list(effect) != self.effect_names:
                raise _bad(TOPIC_TORQUES, log_time,
                           f"effects must hold {self.effect_names}, got {effect!r}")
        out = self.arrays[TOPIC_TORQUES]
        for name in self.effect_names:
            out.setdefault("effect:" + name, []).append(
                _matrix(TOPIC_TORQUES, f"effects[{name}]", [e[name] for e in effects], log_times))

    def column(self, topic: str, name: str, n: int, width: int = 6) -> np.ndarray:
        parts = self.arrays[topic].get(name)
        if not parts:
            return np.zeros((0, width) if width else (0,))
        return np.concatenate(parts)[:n]


def _scan(path: str, collector: _Collector
          ) -> tuple[bool, int, int, set[str], dict[str, dict[str, str]]]:
    """Reads records up to the footer or the first incomplete one, feeding ``collector``.

    Returns (truncated, messages, chunks, topics with a channel, metadata records by name).
    """
    channels: dict[int, str] = {}
    metadata: dict[str, dict[str, str]] = {}
    messages = chunks = 0
    truncated = False
    try:
        file = open(path, "rb")
    except OSError as exc:
        raise AdapterError(f"cannot open {path}: {exc}") from exc
    with file:
        records = _SessionStreamReader(_StrictStream(file), emit_chunks=True,
                                       validate_crcs=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                break
            except EndOfFile:
                truncated = True
                break
            except InvalidMagic as exc:
                raise AdapterError(f"{path} is not an MCAP file: {exc}") from exc
            except (McapError, ValueError, struct.error, UnicodeDecodeError) as exc:
                raise AdapterError(f"{path}: corrupt MCAP record: {exc}") from exc
            except OSError as exc:
                raise AdapterError(f"cannot read {path}: {exc}") from exc
            if isinstance(record, Chunk):
                try:
                    inner = breakup_chunk(record, validate_crc=True)
                except (McapError, ValueError, struct.error, UnicodeDecodeError,
                        zstandard.ZstdError) as exc:
                    raise AdapterError(f"{path}: corrupt chunk: {exc}") from exc
                chunks += 1
            elif isinstance(record, Metadata):
                metadata[record.name] = dict(record.metadata)
                continue
            else:
                inner = [record]
            batches: dict[str, tuple[list[int], list[bytes]]] = {}
            for rec in inner:
                if isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                    if rec.topic in _FIELDS and rec.message_encoding != "json":
                        raise DataError(f"{path}: {rec.topic} has message encoding "
                                           f"{rec.message_encoding!r}, expected 'json'")
                elif isinstance(rec, Message):
                    messages += 1
                    topic = channels.get(rec.channel_id)
                    if topic in _FIELDS:
                        batch = batches.setdefault(topic, ([], []))
                        batch[0].append(rec.log_time)
                        batch[1].append(rec.data)
            for topic, (log_times, datas) in batches.items():
                collector.add(topic, log_times, datas)
    return truncated, messages, chunks, set(channels.values()), metadata


def read_session_report(path: str | os.PathLike[str], *,
                        allow_truncated: bool = True) -> tuple[Session, ReadInfo]:
    """Reads a session, recovering every complete chunk of a truncated file.

    Sample times come from the joint states' header stamps. Truth is None when the file has
    no truth topics; a truncated file keeps only samples whose truth was recovered too.

    Raises:
        AdapterError: unreadable or not MCAP, nothing recoverable, or truncated while
            ``allow_truncated`` is False.
        DataError: a message does not match its layout (names topic and log time), or the
            topics disagree on their samples.
    """
    path = os.fspath(path)
    collector = _Collector()
    truncated, messages, chunks, topics, metadata = _scan(path, collector)
    if truncated and not allow_truncated:
        raise AdapterError(f"{path} is truncated (no footer)")
    counts = collector.counts
    if counts[TOPIC_JOINT_STATES] == 0 and (truncated or TOPIC_JOINT_STATES not in topics):
        if truncated:
            raise AdapterError(f"{path}: truncated before any {TOPIC_JOINT_STATES} message")
        raise DataError(f"{path} has no {TOPIC_JOINT_STATES} channel")
    has_truth = bool(topics & {TOPIC_WRENCH, TOPIC_TORQUES, TOPIC_SENSOR_WRENCH})
    truth_topics = [TOPIC_WRENCH, TOPIC_TORQUES]
    if TOPIC_SENSOR_WRENCH in topics:
        truth_topics.append(TOPIC_SENSOR_WRENCH)
    aligned = [TOPIC_JOINT_STATES] + (truth_topics if has_truth else [])
    n = min(counts[t] for t in aligned)
    if not truncated and any(counts[t] != n for t in aligned):
        raise DataError(f"{path}: topics disagree on the number of samples: "
                        + ", ".join(f"{t} {counts[t]}" for t in aligned))
    if n == 0 and truncated:
        raise AdapterError(f"{path}: truncated before any complete sample")
    stamps = collector.column(TOPIC_JOINT_STATES, "stamp", n, width=0)
    for topic in aligned[1:]:
        other = collector.column(topic, "stamp", n, width=0)
        if not np.array_equal(other, stamps):
            i = int(np.argmax(other != stamps))
            raise DataError(f"{path}: {topic} sample {i} is stamped {other[i]} ns, "
                            f"{TOPIC_JOINT_STATES} {stamps[i]} ns")
    def column(topic: str, name: str, width: int = 6) -> np.ndarray:
        return collector.column(topic, name, n, width)

    try:
        js = JointStates(
            stamps / 1e9,
            *(column(TOPIC_JOINT_STATES, k) for k in ("position", "velocity", "effort")),
            names=tuple(collector.names) if collector.names else JOINT_NAMES,
        )
        truth = None
        if has_truth:
            truth = GroundTruth(
                *(column(TOPIC_TORQUES, k) for k in ("position", "velocity", "acceleration",
                                                       "internal", "external")),
                column(TOPIC_WRENCH, "wrench"),
                column(TOPIC_TORQUES, "in_contact", width=0).astype(bool),
                {name: column(TOPIC_TORQUES, "effect:" + name)
                 for name in collector.effect_names or []},
                column(TOPIC_SENSOR_WRENCH, "wrench") if TOPIC_SENSOR_WRENCH in topics else None,
            )
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from exc
    session_record = metadata.pop(SESSION_METADATA_NAME, None)
    session_metadata: dict[str, Any] = {}
    if session_record is not None:
        if session_record.get("format") != SESSION_FORMAT:
            raise DataError(f"{path}: metadata {SESSION_METADATA_NAME} has format "
                            f"{session_record.get('format')!r}, expected {SESSION_FORMAT!r}")
        try:
            session_metadata = json.loads(session_record.get("json", "{}"))
        except ValueError as exc:
            raise DataError(f"{path}: metadata {SESSION_METADATA_NAME} is not JSON: {exc}") from exc
    info = ReadInfo(truncated=truncated, messages=messages, chunks=chunks,
                    topic_messages={t: c for t, c in counts.items() if t in topics},
                    dropped_samples=counts[TOPIC_JOINT_STATES] - n, metadata=metadata)
    return Session(js, truth, session_metadata), info


def read_session(path: str | os.PathLike[str], *, allow_truncated: bool = True) -> Session:
    """Reads a session written by :class:`SessionWriter` (or any file with the same topics).

    See :func:`read_session_report` for truncation handling and errors.
    """
    return read_session_report(path, allow_truncated=allow_truncated)[0]
