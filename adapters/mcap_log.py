"""The daemon's MCAP log: one file per arm, flushed every second, rotated, never fatal.

Topics (JSON with JSON Schemas, so Foxglove plots them):

=====================  ===================================================================
``/psm/measured_js``   every accepted input, the session format of
                       :mod:`wrenchd.adapters.mcap_session` (so a daemon log is a replayable session)
``/wrenchd/estimate``  per sample: wrench, free-motion flag, gate score, model version,
                       predicted and external joint torques (residual)
``/wrenchd/events``    errors, gaps, contacts, drifts, rounds, model swaps, log problems
``/wrenchd/status``    the status snapshot, once a second
=====================  ===================================================================

Metadata ``wrenchd.session`` (the same record as simulated sessions) says where the data
came from and with which configuration.

Crash safety: at least every ``flush_interval_s`` the open chunk is closed and written and the
file flushed (optionally fsync'ed), so ``kill -9`` loses at most about that much; the session
reader recovers every complete chunk. Rotation starts a new file after ``rotate_mb`` or
``rotate_s``. A write that fails (disk full, directory gone) never raises into the
estimator: the log drops the file, counts what it could not write, reports the problem through
:attr:`McapLog.problem` (cleared when a fresh file is open), and retries a fresh file every
``retry_s``.
"""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path
from typing import Any, Callable, IO

import numpy as np
import orjson
from mcap.writer import CompressionType, Writer
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.adapters.mcap_session import (JOINT_STATE_SCHEMA, SESSION_FORMAT, SESSION_METADATA_NAME,
                                   TOPIC_JOINT_STATES)
from wrenchd.adapters.messages import encode_joint_state

TOPIC_ESTIMATE = "/wrenchd/estimate"
TOPIC_EVENTS = "/wrenchd/events"
TOPIC_STATUS = "/wrenchd/status"
_LIBRARY = "wrenchd.adapters.mcap_log/1"
_DRAFT = "https://json-schema.org/draft/2020-12/schema"
_V6 = {"type": "array", "items": {"type": ["number", "null"]}, "minItems": 6, "maxItems": 6}
_ENCODE = json.JSONEncoder(separators=(",", ":"), allow_nan=False).encode

ESTIMATE_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT, "title": "wrenchd/Estimate",
    "description": "Tip wrench [N, N m] (force in base axes, torque about the tip), gate "
                   "verdict and joint torques [N m; N on insertion] of one sample.",
    "type": "object",
    "properties": {
        "header": JOINT_STATE_SCHEMA["properties"]["header"],
        "wrench": {"type": "object", "properties": {
            k: {"type": "object", "properties": {a: {"type": "number"} for a in "xyz"}}
            for k in ("force", "torque")}},
        "free": {"type": "boolean"}, "score": {"type": "number"},
        "model_version": {"type": "integer"}, "restarted": {"type": "boolean"},
        "predicted": _V6, "external": _V6,
    },
    "required": ["header", "wrench", "free", "model_version", "predicted", "external"],
}
EVENT_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT, "title": "wrenchd/Event",
    "description": "Something that happened: kind (error, gap, contact_start, contact_end, "
                   "drift, round, model, log_error, ...) with its details; t in session s.",
    "type": "object", "properties": {"t": {"type": "number"}, "kind": {"type": "string"}},
    "required": ["t", "kind"],
}
STATUS_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT, "title": "wrenchd/Status",
    "description": "Daemon status snapshot (the answer of the status queryable).",
    "type": "object",
}


def estimate_record(stamp_ns: int, frame_id: str, wrench: np.ndarray, free: bool, score: float,
                    model_version: int, restarted: bool, predicted: np.ndarray,
                    external: np.ndarray) -> bytes:
    """One ``/wrenchd/estimate`` message (:data:`ESTIMATE_SCHEMA`); it is written for every
    sample, so through orjson (arrays natively; a non-finite torque becomes ``null``, which
    the schema allows). ``wrench`` must be finite (the pipeline never emits a non-finite one)."""
    w = np.asarray(wrench, dtype=np.float64).tolist()
    if not all(map(math.isfinite, w)):
        raise ValueError("an estimate's wrench must be finite")
    score = float(score)
    score = min(score, 1e9) if math.isfinite(score) else 1e9
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return orjson.dumps({
        "header": {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": frame_id},
        "wrench": {"force": {"x": w[0], "y": w[1], "z": w[2]},
                   "torque": {"x": w[3], "y": w[4], "z": w[5]}},
        "free": bool(free), "score": score, "model_version": int(model_version),
        "restarted": bool(restarted),
        "predicted": np.ascontiguousarray(predicted, dtype=np.float64),
        "external": np.ascontiguousarray(external, dtype=np.float64)},
        option=orjson.OPT_SERIALIZE_NUMPY)


SCHEMAS = {TOPIC_JOINT_STATES: JOINT_STATE_SCHEMA, TOPIC_ESTIMATE: ESTIMATE_SCHEMA,
           TOPIC_EVENTS: EVENT_SCHEMA, TOPIC_STATUS: STATUS_SCHEMA}


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


class McapLog:
    """One arm's rotating, flushed MCAP log (see the module docstring).

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
        self.problem: str | None = None       # set on failure, cleared when a file opens
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
            self._writer.start(profile="", library=_LIBRARY)
            self._writer.add_metadata(SESSION_METADATA_NAME, {
                "format": SESSION_FORMAT,
                "json": json.dumps({"source": "wrenchd daemon", "arm": self.arm,
                                    **self.metadata}, sort_keys=True, default=str)})
            self._channels = {}
            for topic, schema in SCHEMAS.items():
                sid = self._writer.register_schema(schema["title"], "jsonschema",
                                                   json.dumps(schema).encode())
                self._channels[topic] = self._writer.register_channel(topic, "json", sid)
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
        """Append one message; False when it could not be written (counted in ``lost``)."""
        if not self.config.enabled:
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
        return self.write(topic, stamp_ns, _ENCODE(message).encode())

    def tick(self) -> None:
        """Flush and rotate when due; call often (e.g. after each sample)."""
        if self._writer is None:
            return
        now = self.clock()
        if now - self._flushed_at >= self.config.flush_interval_s:
            self.flush()
        if self._writer is None:
            return
        size_mb = self._file.tell() / 1e6 if self._file is not None else 0.0
        if size_mb >= self.config.rotate_mb or now - self._opened_at >= self.config.rotate_s:
            self.close()


def _joint_state_json(stamp_ns: int, names, position, velocity, effort, frame_id: str) -> bytes:
    return encode_joint_state("json", stamp_ns, names, position, velocity, effort, frame_id)


#: record makers a payload may name, so that what crosses to the log writer is plain values
FORMATTERS: dict[str, Callable[..., bytes]] = {
    "estimate": estimate_record,
    "joint_state": _joint_state_json,
}

#: a record: its bytes, or ``(name in FORMATTERS, args)`` to be made by the log writer
Payload = bytes | tuple[str, tuple]


def format_record(payload: Payload) -> bytes:
    """The bytes of a :data:`Payload`."""
    if isinstance(payload, (bytes, bytearray, memoryview)):
        return bytes(payload)
    name, args = payload
    return FORMATTERS[name](*args)
