"""The per-sample CDR messages in a few ``struct`` calls.

Every sample the daemon decodes a ``sensor_msgs/JointState`` and encodes a
``geometry_msgs/WrenchStamped``, and its log writer encodes a ``wrenchd_msgs/msg/Estimate``
(and a joint state that did not arrive as CDR). The ``rosbags`` type store
(:mod:`wrenchd.adapters.ros2_msgs`) does each through its generic, generated code and a
dataclass per nested message: 9-17 us a message on a 2-core EPYC, against the floor's
whole plumbing of 30-200 us a sample. These fast paths read and write the same bytes for the
common case and answer ``None`` for anything else (big-endian data, an empty vector, a stamp
out of range, text that is not UTF-8, bytes left over), where the caller goes back to
``rosbags``: every refusal and its reason stay the library's. The tests hold both to
``rosbags`` on random and on corrupted messages.

The layout is the ROS 2 one: a 4-byte encapsulation header (``00 01 00 00``, little-endian
CDR), then the fields, each aligned to its own size counted from the end of that header;
a string is its ``uint32`` length (the NUL included), its bytes and a NUL; a sequence its
``uint32`` count and its elements (OMG DDS-XTypes 1.3, 7.4.3.5, "XCDR version 1").
"""

from __future__ import annotations

import functools
import struct
from typing import NamedTuple

import numpy as np

_HEAD = b"\x00\x01\x00\x00"            # CDR_LE, options 0
_STAMP = struct.Struct("<iI")            # sec, nanosec
_U32 = struct.Struct("<I")
_NS_PER_S = 1_000_000_000
_F64 = np.dtype("<f8")


def _utf8(text: str) -> bytes | None:
    try:
        return text.encode()
    except UnicodeEncodeError:             # a lone surrogate
        return None


def _split_stamp(stamp_ns: int) -> tuple[int, int] | None:
    """``(sec, nanosec)`` of a stamp ``builtin_interfaces/Time`` holds, else None."""
    sec, nanosec = divmod(stamp_ns, _NS_PER_S)
    return (sec, nanosec) if 0 <= sec < 2 ** 31 else None


def read_stamp(data: bytes) -> int | None:
    """The header stamp [ns] of a little-endian CDR message that starts with a
    ``std_msgs/Header`` (a joint state, a wrench), or None."""
    if len(data) < 16 or data[:4] != _HEAD:
        return None
    sec, nanosec = _STAMP.unpack_from(data, 4)
    if sec < 0 or nanosec >= _NS_PER_S:
        return None
    return sec * _NS_PER_S + nanosec


def _text(data: bytes, pos: int) -> tuple[str, int] | None:
    """The CDR string at ``pos`` (already 4-aligned) and the offset after it, or None."""
    if pos + 4 > len(data):
        return None
    (size,) = _U32.unpack_from(data, pos)
    pos += 4
    end = pos + size
    if size == 0 or end > len(data) or data[end - 1] != 0:
        return None
    try:
        return data[pos:end - 1].decode(), end
    except UnicodeDecodeError:
        return None


class _Layout(NamedTuple):
    """Where a stream's joint states keep their values: the bytes from the frame id's
    length to the first value (frame id, names, first count) are ``key``; then ``3 n + 2``
    doubles' worth: three vectors of ``n``, each count (``uint32``, 4 bytes of padding) in
    the slot between two vectors."""
    key: bytes
    frame_id: str
    names: tuple[str, ...]
    n: int


#: the layouts seen, by message length; a stream's messages keep theirs
_LAYOUTS: dict[int, _Layout] = {}
_MAX_LAYOUTS = 64


def _parse_joint_state(data: bytes) -> tuple | None:
    """:func:`decode_joint_state` field by field; a message of three equal vectors leaves
    its layout in :data:`_LAYOUTS`."""
    frame = _text(data, 12)
    if frame is None:
        return None
    frame_id, pos = frame
    pos += -(pos - 4) % 4
    if pos + 4 > len(data):
        return None
    (count,) = _U32.unpack_from(data, pos)
    pos += 4
    names = []
    for _ in range(count):
        pos += -(pos - 4) % 4
        name = _text(data, pos)
        if name is None:
            return None
        names.append(name[0])
        pos = name[1]
    vectors, sizes, first = [], [], 0
    for k in range(3):
        pos += -(pos - 4) % 4
        if pos + 4 > len(data):
            return None
        (size,) = _U32.unpack_from(data, pos)
        pos += 4
        pos += -(pos - 4) % 8
        end = pos + 8 * size
        if size == 0 or end > len(data):
            return None
        if k == 0:
            first = pos
        vectors.append(np.frombuffer(data, _F64, size, pos).copy())
        sizes.append(size)
        pos = end
    if pos != len(data):
        return None
    names = tuple(names)
    if sizes[0] == sizes[1] == sizes[2]:
        if len(_LAYOUTS) >= _MAX_LAYOUTS:
            _LAYOUTS.clear()
        _LAYOUTS[len(data)] = _Layout(data[12:first], frame_id, names, sizes[0])
    return frame_id, names, *vectors


def decode_joint_state(data: bytes) -> tuple[int, str, tuple[str, ...], np.ndarray,
                                              np.ndarray, np.ndarray] | None:
    """``(stamp_ns, frame_id, names, position, velocity, effort)`` of a little-endian CDR
    ``sensor_msgs/JointState`` with non-empty vectors of one length (writable float64), or
    None where ``rosbags`` should decide.

    A stream's messages differ only in their stamp and values: once one has been read field
    by field, the next of the same length and the same frame id, names and count is read as
    one block of doubles (the counts between its vectors checked)."""
    stamp_ns = read_stamp(data)
    if stamp_ns is None:
        return None
    layout = _LAYOUTS.get(len(data))
    if layout is not None and data[12:12 + len(layout.key)] == layout.key:
        n = layout.n
        block = np.frombuffer(data, _F64, 3 * n + 2, 12 + len(layout.key)).copy()
        counts = block.view("<u4")
        if counts[2 * n] == n and counts[4 * n + 2] == n:
            return (stamp_ns, layout.frame_id, layout.names, block[:n],
                    block[n + 1:2 * n + 1], block[2 * n + 2:])
    parsed = _parse_joint_state(data)
    return None if parsed is None else (stamp_ns, *parsed)


@functools.lru_cache(maxsize=32)
def _wrench_layout(frame_id: str) -> tuple[struct.Struct, bytes] | None:
    """The packer of a WrenchStamped with this frame id, and the id's bytes."""
    text = _utf8(frame_id)
    if text is None:
        return None
    size = len(text) + 1
    pad = -(12 + size) % 8                  # the force's doubles start 8-aligned
    return struct.Struct(f"<4siII{size}s{pad}x6d"), text


def encode_wrench_stamped(stamp_ns: int, frame_id: str, wrench) -> bytes | None:
    """Little-endian CDR of a ``geometry_msgs/WrenchStamped`` (``wrench``: six values, force
    then torque), the bytes ``rosbags`` writes; None where it should decide."""
    stamp = _split_stamp(stamp_ns)
    layout = _wrench_layout(frame_id)
    values = wrench.tolist() if isinstance(wrench, np.ndarray) else list(wrench)
    if stamp is None or layout is None or len(values) != 6:
        return None
    packer, text = layout
    return packer.pack(_HEAD, *stamp, len(text) + 1, text, *values)


@functools.lru_cache(maxsize=64)
def _joint_state_layout(frame_id: str, names: tuple[str, ...], n: int
                        ) -> tuple[bytes, struct.Struct] | None:
    """What follows the stamp in a JointState with this frame id and these names, up to its
    first value, and the packer of its ``3 n`` values (with the counts between them)."""
    texts = [_utf8(text) for text in (frame_id, *names)]
    if None in texts:
        return None
    out = bytearray()

    def put(word: int, text: bytes = b"", align: int = 4) -> None:
        out.extend(bytes(-(8 + len(out)) % 4))          # the frame id's length is at 8
        out.extend(_U32.pack(word) + text)
        out.extend(bytes(-(8 + len(out)) % align))

    put(len(texts[0]) + 1, texts[0] + b"\x00")          # the frame id
    put(len(names))
    for text in texts[1:]:
        put(len(text) + 1, text + b"\x00")
    put(n, align=8)                                     # the first count; doubles follow
    return bytes(out), struct.Struct(f"<{n}dI4x{n}dI4x{n}d")


def encode_joint_state(stamp_ns: int, frame_id: str, names, position, velocity,
                       effort) -> bytes | None:
    """Little-endian CDR of a ``sensor_msgs/JointState`` whose three vectors have one
    non-zero length (``names`` as many or none), the bytes ``rosbags`` writes; None where it
    should decide."""
    stamp = _split_stamp(stamp_ns)
    arrays = [np.asarray(v, dtype=np.float64) for v in (position, velocity, effort)]
    n = len(arrays[0]) if arrays[0].ndim == 1 else 0
    names = tuple(names)
    if (stamp is None or n == 0 or arrays[1].shape != (n,) or arrays[2].shape != (n,)
            or not all(type(name) is str for name in names)):
        return None
    layout = _joint_state_layout(frame_id, names, n)
    if layout is None:
        return None
    prefix, packer = layout
    p, v, e = (a.tolist() for a in arrays)
    return _HEAD + _STAMP.pack(*stamp) + prefix + packer.pack(*p, n, *v, n, *e)


@functools.lru_cache(maxsize=32)
def _estimate_layout(frame_id: str) -> tuple[struct.Struct, bytes] | None:
    """The packer of a ``wrenchd_msgs/msg/Estimate`` with this frame id, and the id's bytes."""
    text = _utf8(frame_id)
    if text is None:
        return None
    at = 12 + len(text) + 1                   # after the frame id, from the end of the head
    p = []
    for size, align in ((24, 4), (1, 1), (4, 4), (8, 8), (1, 1), (24, 4)):
        p.append(-at % align)                 # force and torque, free, score, version,
        at += p[-1] + size                    # restarted, external
    return struct.Struct(f"<4siII{len(text) + 1}s{p[0]}x24s?{p[2]}xf{p[3]}xq?{p[5]}x24s"), text


def encode_estimate(stamp_ns: int, frame_id: str, wrench32: np.ndarray, free: bool,
                    score: float, model_version: int, restarted: bool,
                    external32: np.ndarray) -> bytes | None:
    """Little-endian CDR of a ``wrenchd_msgs/msg/Estimate`` (``wrench32`` (6,) and
    ``external32`` (6,) float32, ``score`` within float32), the bytes ``rosbags`` writes;
    None where it should decide."""
    stamp = _split_stamp(stamp_ns)
    layout = _estimate_layout(frame_id)
    if stamp is None or layout is None or not -2 ** 63 <= model_version < 2 ** 63:
        return None
    packer, text = layout
    return packer.pack(_HEAD, *stamp, len(text) + 1, text,
                       wrench32.astype("<f4").tobytes(), free, score, model_version,
                       restarted, external32.astype("<f4").tobytes())
