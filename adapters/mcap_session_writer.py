"""The session writer: streams joint states and their ground truth into an MCAP session file.

The topics and ROS 2 message types it writes are those of :mod:`wrenchd.adapters.mcap_session`.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from typing import IO, Any

import numpy as np
from mcap.well_known import Profile
from mcap.writer import CompressionType, Writer

from wrenchd.adapters import mcap_session_cdr as cdr
from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.mcap_session import (
    SESSION_FORMAT,
    SESSION_METADATA_NAME,
    TOPIC_JOINT_STATES,
    TOPIC_SENSOR_WRENCH,
    TOPIC_TORQUES,
    TOPIC_TYPES,
    TOPIC_WRENCH,
    WRENCH_FRAME,
)
from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import GroundTruth, JointStates, Session

DEFAULT_CHUNK_SIZE = 1 << 20  # bytes of uncompressed messages per chunk
_LIBRARY = "wrenchd.adapters.mcap_session/2"  # fixed, so equal sessions give equal bytes
#: Every number is rounded to this many of float64's 52 fraction bits: relative error
#: <= 2**-33 (1.2e-10; e.g. <= 2.4e-10 rad at 2 rad), far below encoder resolution and
#: current-sensing noise. zstd then stores the zeroed low bytes almost for free, which keeps
#: a session about a quarter smaller than with every bit.
MANTISSA_BITS = 32
_DROP = 52 - MANTISSA_BITS
_MOTION_NAMES = ("position", "velocity", "acceleration", "internal_torque", "external_torque")


def round_mantissa(values: np.ndarray) -> np.ndarray:
    """``values`` (float64) rounded to :data:`MANTISSA_BITS` fraction bits, to nearest."""
    a = np.ascontiguousarray(values, dtype=np.float64)
    bits = a.view(np.uint64)
    rounded = ((bits + np.uint64(1 << (_DROP - 1)))
               & np.uint64((1 << 64) - (1 << _DROP))).view(np.float64)
    return np.where(np.isfinite(rounded), rounded, a)    # a carry into infinity stays exact


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
        self._ros2: ros2.Ros2Channels | None = None
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
            self._writer.start(profile=Profile.ROS2, library=_LIBRARY)
            self._ros2 = ros2.Ros2Channels(self._writer)
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
            self._open_writer()
            try:
                self._channels[topic] = self._ros2.add(topic, TOPIC_TYPES[topic])
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
        for name in ("position", "velocity", "effort"):
            _check_finite(f"joint_states.{name}", getattr(joint_states, name))
        times = stamps.tolist()
        heads = cdr.headers(times, "")
        topics = [(TOPIC_JOINT_STATES, cdr.joint_state_messages(
            heads, joint_states.names, *(round_mantissa(getattr(joint_states, k))
                                         for k in ("position", "velocity", "effort"))))]
        if truth is not None:
            wrenches = [("truth.external_wrench", TOPIC_WRENCH, truth.external_wrench)]
            if truth.sensor_wrench is not None:
                wrenches.append(("truth.sensor_wrench", TOPIC_SENSOR_WRENCH, truth.sensor_wrench))
            motion = [truth.position, truth.velocity, truth.acceleration, truth.internal_torque,
                      truth.external_torque]
            for name, values in zip(_MOTION_NAMES, motion):
                _check_finite(f"truth.{name}", values)
            for name, values in truth.effects.items():
                _check_finite(f"truth.effects[{name}]", values)
            wrench_heads = cdr.headers(times, WRENCH_FRAME)
            for name, topic, values in wrenches:
                _check_finite(name, values)
                topics.append((topic, cdr.wrench_messages(wrench_heads, round_mantissa(values))))
            topics.append((TOPIC_TORQUES, cdr.torque_messages(
                heads, truth.in_contact, [round_mantissa(m) for m in motion],
                {k: round_mantissa(v) for k, v in truth.effects.items()})))
        # sample by sample, every topic's message in turn (the order a live recorder sees)
        channels = [self._channels[topic] for topic, _ in topics]
        messages = [m for sample in zip(*(ms for _, ms in topics)) for m in sample]
        try:
            _add_messages(writer, channels * n, np.repeat(stamps, len(channels)).tolist(),
                          messages)
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
