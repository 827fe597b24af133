"""The daemon's MCAP log: one ROS 2 bag file per arm, flushed every second, rotated, never fatal.

The log is what an arm received and what the daemon made of it, kept so that a session can be
inspected, replayed and trained on afterwards. The files are ROS 2 MCAP (profile ``ros2``, CDR
messages, ``ros2msg`` schemas: :mod:`wrenchd.adapters.ros2_msgs`), so ``ros2 bag info`` /
``ros2 bag play``, Foxglove and ``rosbags`` open them. Topics (:data:`TOPIC_TYPES`; fields and
units in ``docs/formats-and-keys.md``, "Daemon logs"):

* ``/psm/measured_js`` (``sensor_msgs/msg/JointState``): every accepted input, in the session
  layout of :mod:`wrenchd.adapters.mcap_session`, so a daemon log is a replayable session;
* ``/wrenchd/estimate`` (``wrenchd_msgs/msg/Estimate``): per sample, float32, the wrench
  [N, N m], free-motion flag, gate score, model version and external joint torques;
* ``/wrenchd/events`` (``wrenchd_msgs/msg/Event``): every event, as stamp, kind and JSON;
* ``/wrenchd/status`` (``wrenchd_msgs/msg/Status``): the status snapshot (JSON), once a second.

Metadata ``wrenchd.session`` (the same record as simulated sessions) says where the data came
from and with which configuration.

What the daemon hands over (:data:`Payload`) is CDR bytes, JSON text or the name of a record
maker in :data:`FORMATTERS` with its arguments, so only plain values cross to the log writer
process. :class:`McapLog` writes the files; it flushes, rotates, survives a failing disk and
keeps a disk budget (:class:`LogConfig`; times in s, sizes in MB or bytes).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections import deque
from pathlib import Path
from typing import Any, Callable, IO

import numpy as np
import orjson
from mcap.well_known import MessageEncoding, Profile
from mcap.writer import CompressionType, Writer
from pydantic import BaseModel, ConfigDict, Field, model_validator

from wrenchd.adapters import cdr_wire
from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.mcap_session import SESSION_FORMAT, SESSION_METADATA_NAME, TOPIC_JOINT_STATES
from wrenchd.models.errors import DataError

TOPIC_ESTIMATE = "/wrenchd/estimate"
TOPIC_EVENTS = "/wrenchd/events"
TOPIC_STATUS = "/wrenchd/status"
#: the ROS 2 message type of each topic
TOPIC_TYPES: dict[str, str] = {TOPIC_JOINT_STATES: ros2.JOINT_STATE,
                               TOPIC_ESTIMATE: ros2.ESTIMATE,
                               TOPIC_EVENTS: ros2.EVENT, TOPIC_STATUS: ros2.STATUS}
_LIBRARY = "wrenchd.adapters.mcap_log/2"
_JSON_TOPICS = {TOPIC_EVENTS: ros2.EVENT, TOPIC_STATUS: ros2.STATUS}   # JSON text in a string


def estimate_record(stamp_ns: int, frame_id: str, wrench: np.ndarray, free: bool, score: float,
                    model_version: int, restarted: bool, external: np.ndarray) -> bytes:
    """One ``/wrenchd/estimate`` message (``wrenchd_msgs/msg/Estimate``, CDR, float32).

    ``wrench`` [N, N m] must be six finite numbers (the pipeline never emits another); a
    non-finite joint torque stays NaN / Inf; a non-finite score is written as the cap, 1e9.
    The predicted joint torques are not written: they are the logged effort minus
    ``external`` (:func:`wrenchd.adapters.log_estimates.read_logged_estimates`).
    """
    w = np.asarray(wrench, dtype=np.float64)
    if w.shape != (6,) or not np.isfinite(w).all():
        raise ValueError(f"an estimate's wrench must be 6 finite numbers, got {wrench!r}")
    torque = np.asarray(external, dtype=np.float32)
    if torque.shape != (6,):
        raise ValueError("external must hold 6 joint torques")
    score = float(score)
    score = min(score, 1e9) if math.isfinite(score) else 1e9
    w32 = w.astype(np.float32)
    fast = cdr_wire.encode_estimate(stamp_ns, frame_id, w32, bool(free), score,
                                    int(model_version), bool(restarted), torque)
    if fast is not None:
        return fast
    return ros2.serialize(ros2.message_class(ros2.ESTIMATE)(
        header=ros2.header(stamp_ns, frame_id), force=w32[:3], torque=w32[3:],
        free=bool(free), score=score, model_version=int(model_version),
        restarted=bool(restarted), external=torque))


def joint_state_record(stamp_ns: int, names, position, velocity, effort,
                       frame_id: str = "") -> bytes:
    """One ``/psm/measured_js`` message (``sensor_msgs/msg/JointState``, CDR)."""
    fast = cdr_wire.encode_joint_state(stamp_ns, frame_id, names, position, velocity, effort)
    if fast is not None:
        return fast
    return ros2.serialize(ros2.message_class(ros2.JOINT_STATE)(
        header=ros2.header(stamp_ns, frame_id), name=[str(n) for n in names],
        position=np.asarray(position, dtype=np.float64),
        velocity=np.asarray(velocity, dtype=np.float64),
        effort=np.asarray(effort, dtype=np.float64)))


def event_record(stamp_ns: int, body: bytes | str) -> bytes:
    """One ``/wrenchd/events`` message (``wrenchd_msgs/msg/Event``): ``body`` is the event's
    JSON object (its ``kind`` is copied into the message's own field)."""
    text = body.decode() if isinstance(body, (bytes, bytearray, memoryview)) else str(body)
    event = orjson.loads(text)
    kind = event.get("kind", "") if isinstance(event, dict) else ""
    return ros2.serialize(ros2.message_class(ros2.EVENT)(
        stamp=ros2.stamp(stamp_ns), kind=str(kind), json=text))


def status_record(stamp_ns: int, body: bytes | str) -> bytes:
    """One ``/wrenchd/status`` message (``wrenchd_msgs/msg/Status``): the snapshot's JSON."""
    text = body.decode() if isinstance(body, (bytes, bytearray, memoryview)) else str(body)
    orjson.loads(text)                                     # JSON, or a clear error
    return ros2.serialize(ros2.message_class(ros2.STATUS)(stamp=ros2.stamp(stamp_ns), json=text))


def json_record(topic: str, stamp_ns: int, text: bytes) -> bytes:
    """The topic's ROS 2 message (CDR) of JSON ``text``: a joint state in the wire JSON of
    :mod:`wrenchd.adapters.messages`, an event or status object, or an estimate's fields.

    Raises:
        DataError, ValueError: ``text`` is not what the topic carries.
    """
    if topic == TOPIC_JOINT_STATES:
        from wrenchd.adapters.messages import decode_joint_state

        m = decode_joint_state("json", text)
        return joint_state_record(m.stamp_ns, m.name, m.position, m.velocity, m.effort,
                                  m.frame_id)
    if topic == TOPIC_EVENTS:
        return event_record(stamp_ns, text)
    if topic == TOPIC_STATUS:
        return status_record(stamp_ns, text)
    fields = orjson.loads(text)
    if not isinstance(fields, dict):
        raise DataError(f"{topic}: expected a JSON object, got {text[:40]!r}")
    return ros2.serialize(ros2.from_fields(TOPIC_TYPES[topic], fields))


def message_fields(message_encoding: str, schema_name: str, data: bytes,
                   definition: str | bytes | None = None) -> Any:
    """A logged message as JSON-like values, whichever format wrote it: a JSON log's message
    parsed; of a ROS 2 log, an event's or status's JSON object, any other message's fields
    (:func:`wrenchd.adapters.ros2_msgs.to_fields`). ``definition``: the schema's data, which
    decodes a message written with an earlier definition of its type (None: today's).

    Raises:
        DataError: the message cannot be decoded.
    """
    if message_encoding == "json":
        try:
            return orjson.loads(data)
        except orjson.JSONDecodeError as exc:
            raise DataError(f"not JSON: {exc}") from None
    if message_encoding != MessageEncoding.CDR:
        raise DataError(f"unknown message encoding {message_encoding!r}")
    message = ros2.deserialize(data, schema_name, definition)
    if schema_name in (ros2.EVENT, ros2.STATUS):
        try:
            return orjson.loads(message.json)
        except orjson.JSONDecodeError as exc:
            raise DataError(f"{schema_name}.json is not JSON: {exc}") from None
    return ros2.to_fields(message)


class LogConfig(BaseModel):
    """Where and how the daemon logs."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = True
    directory: str = Field(default="sessions", description="log directory (created)")
    flush_interval_s: float = Field(default=1.0, gt=0.0, description="at most this is lost [s]")
    fsync: bool = Field(default=False, description="also fsync at each flush (power loss)")
    rotate_mb: float = Field(default=512.0, gt=0.0, description="new file after this size [MB]")
    rotate_s: float = Field(default=3600.0, gt=0.0, description="new file after this long [s]")
    retry_s: float = Field(default=5.0, gt=0.0, description="retry after a write failure [s]")
    chunk_size: int = Field(default=1 << 20, ge=1024, description="max chunk [B]")
    max_total_bytes: int | None = Field(
        default=None, gt=0,
        description="the daemon's log files in the directory total at most this [B]: past it "
                    "the oldest closed ones are removed, each with a log_removed event (None: "
                    "no limit)")
    budget_check_s: float = Field(default=10.0, gt=0.0,
                                  description="check the budget this often [s], and after "
                                              "each rotation")

    @model_validator(mode="after")
    def _budget_holds_a_file(self) -> LogConfig:
        if self.max_total_bytes is not None and self.max_total_bytes < self.rotate_mb * 1e6:
            raise ValueError(f"max_total_bytes ({self.max_total_bytes} B) is smaller than one "
                             f"file (rotate_mb = {self.rotate_mb:g} MB): the open file alone "
                             f"would exceed it")
        return self


class McapLog:
    """One arm's rotating, flushed MCAP log.

    :meth:`write` turns JSON text into the topic's ROS 2 message (a joint state as a JSON arm
    received it, an event or a status) and writes CDR bytes as they come.

    Crash safety: at least every ``flush_interval_s`` the open chunk is closed and written and
    the file flushed (optionally fsync'ed), so ``kill -9`` loses at most about that much; the
    session reader recovers every complete chunk. Rotation starts a new file after
    ``rotate_mb`` or ``rotate_s``. A write that fails (disk full, directory gone) never raises
    into the estimator: the log drops the file, counts what it could not write, reports the
    problem through :attr:`problem` (cleared when a fresh file is open), and retries a fresh
    file every ``retry_s``.

    Disk budget: with ``max_total_bytes`` set, the daemon's log files in the directory are kept
    under it by removing the oldest closed ones (never an open one), after each rotation and
    every ``budget_check_s`` (:mod:`wrenchd.adapters.log_budget`; the daemon's log writer
    process runs it). What was removed waits in :attr:`removed` for the daemon to report it.

    Args:
        arm: arm name (file names and metadata).
        config: where and how.
        metadata: JSON-able description stored in every file.
        clock: wall clock [s] used for flushing and rotation (injectable for tests).
        opener: ``open``-like function creating the files (tests hand it ``/dev/full``).
    """

    def __init__(self, arm: str, config: LogConfig, metadata: dict[str, Any] | None = None,
                 clock=time.monotonic, opener=open) -> None:
        self.arm, self.config, self.metadata = arm, config, dict(metadata or {})
        self.clock, self.opener = clock, opener
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self.path: Path | None = None
        self.paths: list[Path] = []
        self.written = 0
        self.lost = 0
        self.refused = 0                      # records that were not a topic's message
        self.last_refusal: str | None = None
        self.problem: str | None = None       # set on failure, cleared when a file opens
        # the disk budget's notices, oldest first, until reported: ("removed", path, bytes) or
        # ("error", path, why) (log_budget.LogBudgets; the daemon's view: log_process)
        self.removed: deque[tuple[str, str, Any]] = deque()
        self.bytes_used: int | None = None     # the directory's log files [B], once checked
        self.bytes_free: int | None = None     # free on the directory's file system [B]
        self.removed_files = 0                 # removed by the budget (the daemon's count)
        self.removed_bytes = 0
        self._opened_at = 0.0
        self._flushed_at = 0.0
        self._retry_at = 0.0
        self._seq = 0

    # -- files --------------------------------------------------------------------------
    def _open(self) -> bool:
        now = self.clock()
        if now < self._retry_at:
            return False
        try:
            directory = Path(self.config.directory)
            directory.mkdir(parents=True, exist_ok=True)
            self._seq += 1
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path = directory / f"{self.arm}-{stamp}-{os.getpid()}-{self._seq:03d}.mcap"
            self._file = self.opener(path, "wb")
            self._writer = Writer(self._file, chunk_size=self.config.chunk_size,
                                  compression=CompressionType.ZSTD)
            self._writer.start(profile=Profile.ROS2, library=_LIBRARY)
            self._writer.add_metadata(SESSION_METADATA_NAME, {
                "format": SESSION_FORMAT,
                "json": json.dumps({"source": "wrenchd daemon", "arm": self.arm,
                                    **self.metadata}, sort_keys=True, default=str)})
            channels = ros2.Ros2Channels(self._writer)
            self._channels = {topic: channels.add(topic, typename)
                              for topic, typename in TOPIC_TYPES.items()}
            self._finalize_chunk()
        except OSError as exc:
            self._fail(f"cannot open a log file in {self.config.directory}: {exc}")
            return False
        self.path = path
        self.paths.append(path)
        self._opened_at = self._flushed_at = now
        self.problem = None                               # writing again
        return True

    def _fail(self, why: str) -> None:
        self.problem = why
        self._retry_at = self.clock() + self.config.retry_s
        try:
            if self._file is not None:
                self._file.close()
        except OSError:
            pass
        self._file = self._writer = None

    def _finalize_chunk(self) -> None:
        # mcap >= 1.6: Writer.flush() ends the open chunk and writes it and everything buffered
        # to the stream (no fsync).
        self._writer.flush()

    def flush(self) -> None:
        """Close the open chunk and push it to the file now."""
        if self._writer is None:
            return
        try:
            self._finalize_chunk()
            if self.config.fsync:
                os.fsync(self._file.fileno())
        except OSError as exc:
            self._fail(f"cannot write {self.path}: {exc}")
        self._flushed_at = self.clock()

    def close(self) -> None:
        """Finish the file (summary, footer)."""
        if self._writer is None:
            return
        try:
            self._writer.finish()
            self._file.close()
        except OSError as exc:
            self.problem = f"cannot finish {self.path}: {exc}"
        self._file = self._writer = None

    # -- writing ------------------------------------------------------------------------
    def write(self, topic: str, stamp_ns: int, payload: bytes) -> bool:
        """Append one message: ``payload`` is the topic's CDR message or JSON text made into
        it (:func:`json_record`). False when it could not be written or made (counted in
        ``lost``; those not made in ``refused`` too)."""
        if not self.config.enabled:
            return False
        if not ros2.is_cdr(payload):
            try:
                payload = json_record(topic, stamp_ns, payload)
            except (DataError, ValueError) as exc:   # orjson's error is a ValueError
                self.refused += 1
                self.lost += 1
                self.last_refusal = f"{topic}: {exc}"
                return False
        if self._writer is None and not self._open():
            self.lost += 1
            return False
        try:
            self._writer.add_message(self._channels[topic], stamp_ns, payload, stamp_ns)
        except OSError as exc:
            self._fail(f"cannot write {self.path}: {exc}")
            self.lost += 1
            return False
        self.written += 1
        return True

    def write_json(self, topic: str, stamp_ns: int, message: dict[str, Any]) -> bool:
        """Append a message given as JSON-like values: an event's or status's object, or the
        fields of the topic's message (left-out fields take ROS's defaults)."""
        if topic in _JSON_TOPICS:
            return self.write(topic, stamp_ns, orjson.dumps(message, default=str))
        try:
            payload = ros2.serialize(ros2.from_fields(TOPIC_TYPES[topic], message))
        except DataError as exc:
            self.refused += 1
            self.lost += 1
            self.last_refusal = f"{topic}: {exc}"
            return False
        return self.write(topic, stamp_ns, payload)

    @property
    def open_path(self) -> Path | None:
        """The file being written, None between files."""
        return self.path if self._writer is not None else None

    @property
    def open_bytes(self) -> int:
        """Bytes written to the open file so far (0 between files)."""
        try:
            return self._file.tell() if self._writer is not None else 0
        except (OSError, ValueError):
            return 0

    def tick(self) -> bool:
        """Flush and rotate when due; call often (e.g. after each sample). True when it closed
        the file (a rotation: the next record opens a new one)."""
        if self._writer is None:
            return False
        now = self.clock()
        if now - self._flushed_at >= self.config.flush_interval_s:
            self.flush()
        if self._writer is None:
            return False
        size_mb = self._file.tell() / 1e6 if self._file is not None else 0.0
        if size_mb >= self.config.rotate_mb or now - self._opened_at >= self.config.rotate_s:
            self.close()
            return True
        return False


#: record makers a payload may name, so that what crosses to the log writer is plain values
FORMATTERS: dict[str, Callable[..., bytes]] = {
    "estimate": estimate_record,
    "joint_state": joint_state_record,
}

#: a record: its bytes (CDR, or JSON made into the topic's message by :meth:`McapLog.write`),
#: or ``(name in FORMATTERS, args)`` to be made by the log writer
Payload = bytes | tuple[str, tuple]


def format_record(payload: Payload) -> bytes:
    """The bytes of a :data:`Payload`."""
    if isinstance(payload, (bytes, bytearray, memoryview)):
        return bytes(payload)
    name, args = payload
    return FORMATTERS[name](*args)
