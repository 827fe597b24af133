"""The per-sample CDR fast paths (:mod:`wrenchd.adapters.cdr_wire`) held to ``rosbags``.

Encoding: the same bytes as ``rosbags`` for any stamp, frame id, names and values (wrench,
joint state, estimate). Decoding: on valid
messages of every shape, the same fields; on corrupted ones (truncated, extended, a byte or a
length field overwritten), either no answer (``rosbags`` then decides, refusal included) or
the answer ``rosbags`` gives. The second message of a stream, read through the layout the
first left, is checked as closely as the first.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wrenchd.adapters import cdr_wire
from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.messages import decode_joint_state, encode_joint_state
from wrenchd.models.errors import DataError

FUZZ = settings(max_examples=200, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])
stamps = st.integers(min_value=0, max_value=2 ** 31 * 1_000_000_000 - 1)
texts = st.text(max_size=12)
floats = st.floats(allow_nan=True, allow_infinity=True)


def _rosbags_joint_state(payload: bytes):
    """The fields ``rosbags`` reads (None: it refuses the payload)."""
    try:
        msg = ros2.deserialize(payload, ros2.JOINT_STATE)
        stamp_ns = ros2.time_ns(msg.header.stamp)
    except DataError:
        return None
    return (stamp_ns, msg.header.frame_id, tuple(msg.name), np.asarray(msg.position),
            np.asarray(msg.velocity), np.asarray(msg.effort))


def _assert_same(fast, slow) -> None:
    assert fast[:3] == slow[:3]
    for a, b in zip(fast[3:], slow[3:]):
        assert a.dtype == np.float64 and a.flags.writeable
        np.testing.assert_array_equal(a, b)         # NaN equal to NaN, bits otherwise


def _rosbags_wrench(stamp_ns: int, frame_id: str, wrench: list[float]) -> bytes:
    vector = ros2.message_class(ros2.VECTOR3)
    return ros2.serialize(ros2.message_class(ros2.WRENCH_STAMPED)(
        header=ros2.header(stamp_ns, frame_id), wrench=ros2.message_class(ros2.WRENCH)(
            force=vector(x=wrench[0], y=wrench[1], z=wrench[2]),
            torque=vector(x=wrench[3], y=wrench[4], z=wrench[5]))))


@FUZZ
@given(stamps, texts, st.lists(floats, min_size=6, max_size=6))
def test_wrench_bytes_are_rosbags_bytes(stamp_ns, frame_id, wrench):
    fast = cdr_wire.encode_wrench_stamped(stamp_ns, frame_id, np.array(wrench))
    assert fast == _rosbags_wrench(stamp_ns, frame_id, wrench)


def test_wrench_out_of_range_is_left_to_rosbags():
    assert cdr_wire.encode_wrench_stamped(2 ** 31 * 1_000_000_000, "f", np.zeros(6)) is None
    assert cdr_wire.encode_wrench_stamped(-1, "f", np.zeros(6)) is None
    assert cdr_wire.encode_wrench_stamped(0, "\ud800", np.zeros(6)) is None  # no UTF-8
    assert cdr_wire.encode_wrench_stamped(0, "f", np.zeros(5)) is None


def _rosbags_joint_state_bytes(stamp_ns, frame_id, names, position, velocity, effort):
    return ros2.serialize(ros2.message_class(ros2.JOINT_STATE)(
        header=ros2.header(stamp_ns, frame_id), name=list(names),
        position=np.asarray(position, dtype=np.float64),
        velocity=np.asarray(velocity, dtype=np.float64),
        effort=np.asarray(effort, dtype=np.float64)))


@FUZZ
@given(stamps, texts, st.integers(1, 8), st.data())
def test_joint_state_bytes_are_rosbags_bytes(stamp_ns, frame_id, n, data):
    names = data.draw(st.one_of(st.just([]), st.lists(texts, min_size=n, max_size=n)))
    values = [data.draw(st.lists(floats, min_size=n, max_size=n)) for _ in range(3)]
    fast = cdr_wire.encode_joint_state(stamp_ns, frame_id, names, *values)
    assert fast == _rosbags_joint_state_bytes(stamp_ns, frame_id, names, *values)


def test_joint_states_it_cannot_write_are_left_to_rosbags():
    one = np.zeros(1)
    assert cdr_wire.encode_joint_state(0, "", [], [], [], []) is None
    assert cdr_wire.encode_joint_state(0, "", [], one, np.zeros(2), one) is None
    assert cdr_wire.encode_joint_state(0, "", [], np.zeros((1, 1)), one, one) is None
    assert cdr_wire.encode_joint_state(0, "", [np.str_("a")], one, one, one) is None
    assert cdr_wire.encode_joint_state(-1, "", [], one, one, one) is None


@FUZZ
@given(stamps, texts, st.lists(floats, min_size=12, max_size=12), st.booleans(),
       st.floats(0.0, 1e9), st.integers(-(2 ** 63), 2 ** 63 - 1), st.booleans())
def test_estimate_bytes_are_rosbags_bytes(stamp_ns, frame_id, values, free, score, version,
                                          restarted):
    with np.errstate(over="ignore"):
        wrench = np.array(values[:6]).astype(np.float32)
        external = np.array(values[6:]).astype(np.float32)
    fast = cdr_wire.encode_estimate(stamp_ns, frame_id, wrench, free, score, version,
                                    restarted, external)
    assert fast == ros2.serialize(ros2.message_class(ros2.ESTIMATE)(
        header=ros2.header(stamp_ns, frame_id), force=wrench[:3], torque=wrench[3:],
        free=free, score=score, model_version=version, restarted=restarted,
        external=external))


@st.composite
def joint_states(draw):
    n = draw(st.integers(min_value=1, max_value=8))
    names = draw(st.one_of(st.just([]), st.lists(texts, min_size=n, max_size=n)))
    values = [draw(st.lists(floats, min_size=n, max_size=n)) for _ in range(3)]
    return encode_joint_state("cdr", draw(stamps), names, *values, frame_id=draw(texts))


@FUZZ
@given(joint_states(), stamps)
def test_joint_state_fields_are_rosbags_fields(payload, other_stamp):
    fast = cdr_wire.decode_joint_state(payload)
    assert fast is not None
    _assert_same(fast, _rosbags_joint_state(payload))
    # the stream's next message: the same layout, another stamp and other values
    sec, nanosec = divmod(other_stamp, 1_000_000_000)
    values = np.frombuffer(payload, np.uint8).copy()
    values[4:12] = np.frombuffer(np.array([sec, nanosec], "<u4").tobytes(), np.uint8)
    values[-8:] = np.frombuffer(np.array([0.25], "<f8").tobytes(), np.uint8)
    following = values.tobytes()
    fast = cdr_wire.decode_joint_state(following)
    assert fast is not None
    _assert_same(fast, _rosbags_joint_state(following))


@FUZZ
@given(joint_states(), st.data())
def test_corrupted_joint_state_is_rosbags_answer_or_none(payload, data):
    cdr_wire.decode_joint_state(payload)                # its layout is known now
    raw = bytearray(payload)
    how = data.draw(st.sampled_from(["cut", "extend", "byte", "word"]))
    if how == "cut":
        raw = raw[:data.draw(st.integers(0, len(raw) - 1))]
    elif how == "extend":
        raw += bytes(data.draw(st.integers(1, 16)))
    elif how == "byte":
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    else:
        at = data.draw(st.integers(4, len(raw) - 4))
        raw[at:at + 4] = data.draw(st.integers(0, 2 ** 32 - 1)).to_bytes(4, "little")
    corrupted = bytes(raw)
    fast = cdr_wire.decode_joint_state(corrupted)
    if fast is not None:
        slow = _rosbags_joint_state(corrupted)
        assert slow is not None, "the fast path read what rosbags refuses"
        _assert_same(fast, slow)


def test_a_count_between_vectors_that_differs_is_read_field_by_field():
    """Same length, frame id and names as a known stream, but the second vector's count
    changed: the block read must not answer for it."""
    payload = encode_joint_state("cdr", 5, list("abcdef"), np.arange(6.0), np.ones(6),
                                 np.zeros(6))
    assert cdr_wire.decode_joint_state(payload) is not None
    raw = bytearray(payload)
    at = len(raw) - 8 * (2 * 6 + 2)            # the velocity's count: 2 vectors, 2 slots on
    assert int.from_bytes(raw[at:at + 4], "little") == 6
    raw[at:at + 4] = (5).to_bytes(4, "little")
    assert cdr_wire.decode_joint_state(bytes(raw)) is None
    with pytest.raises(DataError):
        decode_joint_state("cdr", bytes(raw))


def test_unequal_or_empty_vectors_are_left_to_the_checks():
    payload = encode_joint_state("cdr", 5, [], [1.0, 2.0], [1.0], [1.0, 2.0])
    assert cdr_wire.decode_joint_state(payload) is not None   # a message, if not a sample
    with pytest.raises(DataError, match="one equal, non-zero length"):
        decode_joint_state("cdr", payload)
    empty = encode_joint_state("cdr", 5, [], [], [], [])
    assert cdr_wire.decode_joint_state(empty) is None
    with pytest.raises(DataError):
        decode_joint_state("cdr", empty)
