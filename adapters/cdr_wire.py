"""The daemon's two hot-path CDR messages in a few ``struct`` calls.

Every sample the daemon decodes a ``sensor_msgs/JointState`` and encodes a
``geometry_msgs/WrenchStamped``. The ``rosbags`` type store
(:mod:`wrenchd.adapters.ros2_msgs`) does either through its generic, generated code and a
dataclass per nested message: about 22 us and 11 us a sample on a 2-core EPYC, as much as the
floor's whole plumbing. These fast paths read and write the same bytes for the common case
and answer ``None`` for anything else (big-endian data, an empty vector, a stamp out of range,
text that is not UTF-8, bytes left over), where the caller goes back to ``rosbags``: every
refusal and its reason stay the library's. The tests hold both to ``rosbags`` on random and
on corrupted messages.

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
    if len(data) < 16 or data[:4] != _HEAD:
        return None
    sec, nanosec = _STAMP.unpack_from(data, 4)
    if sec < 0 or nanosec >= _NS_PER_S:
        return None
    stamp_ns = sec * _NS_PER_S + nanosec
    layout = _LAYOUTS.get(len(data))
    if layout is None or data[12:12 + len(layout.key)] != layout.key:
        parsed = _parse_joint_state(data)
        return None if parsed is None else (stamp_ns, *parsed)
    n = layout.n
    block = np.frombuffer(data, _F64, 3 * n + 2, 12 + len(layout.key)).copy()
    counts = block.view("<u4")
    if counts[2 * n] != n or counts[4 * n + 2] != n:
        parsed = _parse_joint_state(data)
        return None if parsed is None else (stamp_ns, *parsed)
    return (stamp_ns, layout.frame_id, layout.names, block[:n], block[n + 1:2 * n + 1],
            block[2 * n + 2:])


@functools.lru_cache(maxsize=32)
def _wrench_layout(frame_id: str) -> tuple[struct.Struct, bytes] | None:
    """The packer of a WrenchStamped with this frame id, and the id's bytes."""
    try:
        text = frame_id.encode()
    except UnicodeEncodeError:
        return None
    size = len(text) + 1
    pad = -(12 + size) % 8                  # the force's doubles start 8-aligned
    return struct.Struct(f"<4siII{size}s{pad}x6d"), text


def encode_wrench_stamped(stamp_ns: int, frame_id: str, wrench) -> bytes | None:
    """Little-endian CDR of a ``geometry_msgs/WrenchStamped`` (``wrench``: six values, force
    then torque), the bytes ``rosbags`` writes; None where it should decide."""
    sec, nanosec = divmod(stamp_ns, _NS_PER_S)
    layout = _wrench_layout(frame_id)
    if layout is None or not 0 <= sec < 2 ** 31:
        return None
    packer, text = layout
    values = wrench.tolist() if isinstance(wrench, np.ndarray) else list(wrench)
    if len(values) != 6:
        return None
    return packer.pack(_HEAD, sec, nanosec, len(text) + 1, text, *values)
