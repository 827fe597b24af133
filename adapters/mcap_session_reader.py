"""The session reader: decodes an MCAP session file, recovering what a truncated file holds.

It reads both formats, choosing by each channel's message encoding: ROS 2 CDR (``cdr``, the
types of :mod:`wrenchd.adapters.mcap_session`) and the JSON that earlier versions wrote
(``json``). It validates every message against the session layout and reports what it found
(:class:`ReadInfo`). Daemon logs (:mod:`wrenchd.adapters.mcap_log`) read as sessions without
truth.
"""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO, Any

import numpy as np
import zstandard
from mcap.exceptions import EndOfFile, InvalidMagic, McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.well_known import MessageEncoding

from wrenchd.adapters import mcap_session_cdr as cdr
from wrenchd.adapters.mcap_session import (
    SESSION_FORMAT,
    SESSION_METADATA_NAME,
    TOPIC_JOINT_STATES,
    TOPIC_SENSOR_WRENCH,
    TOPIC_TORQUES,
    TOPIC_TYPES,
    TOPIC_WRENCH,
)
from wrenchd.adapters.ros2_msgs import NS_PER_S
from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import JOINT_NAMES, N_JOINTS, GroundTruth, JointStates, Session


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
            if isinstance(row, np.ndarray):
                bad = row.shape != (width,) or row.dtype.kind not in "fi"
            else:
                bad = (not isinstance(row, list) or len(row) != width or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) for v in row))
            if bad:
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
    if type(sec) is not int or type(nanosec) is not int or sec < 0 or not 0 <= nanosec < NS_PER_S:
        raise ValueError(f"bad header.stamp {stamp!r}")
    return sec * NS_PER_S + nanosec


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

    def add(self, topic: str, encoding: str, log_times: list[int], datas: list[bytes]) -> None:
        extract, names = _FIELDS[topic]
        rows = []
        if encoding == MessageEncoding.CDR:
            extract_cdr = cdr.FIELDS[topic]
            for data, log_time in zip(datas, log_times, strict=True):
                try:
                    rows.append(extract_cdr(cdr.decode(topic, data)))
                except DataError as exc:
                    raise _bad(topic, log_time, str(exc)) from None
                except ValueError as exc:
                    raise _bad(topic, log_time, f"malformed field: {exc}") from None
        else:
            rows = self._json_rows(topic, extract, log_times, datas)
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
        self.counts[topic] += len(rows)

    @staticmethod
    def _json_rows(topic: str, extract, log_times: list[int], datas: list[bytes]) -> list[tuple]:
        try:
            messages = json.loads(b"[" + b",".join(datas) + b"]")
        except ValueError:
            for log_time, data in zip(log_times, datas):
                try:
                    json.loads(data)
                except ValueError as exc:
                    raise _bad(topic, log_time, f"not valid JSON ({exc})") from exc
            raise _bad(topic, log_times[0], "batch is not valid JSON") from None
        rows = []
        for message, log_time in zip(messages, log_times, strict=True):
            try:
                rows.append(extract(message))
            except (KeyError, TypeError, ValueError) as exc:
                raise _bad(topic, log_time, f"missing or malformed field: {exc!r}") from exc
        return rows

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
    channels: dict[int, tuple[str, str]] = {}          # id: (topic, message encoding)
    schemas: dict[int, str] = {}
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
            batches: dict[tuple[str, str], tuple[list[int], list[bytes]]] = {}
            for rec in inner:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Channel):
                    channels[rec.id] = (rec.topic, rec.message_encoding)
                    if rec.topic in _FIELDS:
                        _check_channel(path, rec, schemas.get(rec.schema_id))
                elif isinstance(rec, Message):
                    messages += 1
                    channel = channels.get(rec.channel_id)
                    if channel is not None and channel[0] in _FIELDS:
                        batch = batches.setdefault(channel, ([], []))
                        batch[0].append(rec.log_time)
                        batch[1].append(rec.data)
            for (topic, encoding), (log_times, datas) in batches.items():
                collector.add(topic, encoding, log_times, datas)
    return truncated, messages, chunks, {t for t, _ in channels.values()}, metadata


def _check_channel(path: str, channel: Channel, schema_name: str | None) -> None:
    """A session topic's channel must be JSON, or CDR of the topic's ROS 2 type."""
    if channel.message_encoding == "json":
        return
    if channel.message_encoding != MessageEncoding.CDR:
        raise DataError(f"{path}: {channel.topic} has message encoding "
                        f"{channel.message_encoding!r}, expected 'cdr' (or 'json')")
    if schema_name != TOPIC_TYPES[channel.topic]:
        raise DataError(f"{path}: {channel.topic} carries {schema_name!r}, expected "
                        f"{TOPIC_TYPES[channel.topic]!r}")


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


def is_wrenchd_file(path: str | os.PathLike[str]) -> bool:
    """True when the MCAP file at ``path`` was written by wrenchd (a session, a daemon log or a
    replay output, in either format): its header names a wrenchd writer as its library. Only
    the header is read, so a truncated file is told too; a ROS 2 bag that ``ros2 bag record``
    wrote is not wrenchd's, though both have the ``ros2`` profile.

    Raises:
        AdapterError: the file cannot be read or is not MCAP.
    """
    try:
        with open(path, "rb") as file:
            record = next(StreamReader(_StrictStream(file)).records)
    except OSError as exc:
        raise AdapterError(f"cannot open {path}: {exc}") from exc
    except (McapError, EndOfFile, StopIteration, ValueError, struct.error) as exc:
        raise AdapterError(f"{path} is not an MCAP file: {exc!r}") from exc
    return isinstance(record, Header) and record.library.startswith("wrenchd.")
