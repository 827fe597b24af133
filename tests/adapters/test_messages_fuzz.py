"""Bad input, fuzzed: every decoder of ``wrenchd.adapters.messages`` refuses garbage with DataError.

Property for ``decode_joint_state`` (JSON and CDR) and ``decode_wrench`` (JSON and CDR): on any
payload the decoder either raises :class:`DataError` or returns a message that holds exactly
what was sent (right types, equal lengths). Any other exception would reach the daemon's
catch-all as an ``internal`` error instead of a ``decode`` error, and would crash a subscriber
such as ``wrenchd echo``.

Inputs: arbitrary bytes; valid messages with one field replaced by another JSON value (wrong
types, NaN/Inf, nested containers, missing fields); independent lengths of name, position,
velocity, effort; CDR payloads truncated, extended or with bytes overwritten (length fields
included). Bugs the fuzzing found are kept as plain tests at the end, each with the exact payload.
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from wrenchd.adapters.messages import decode_joint_state, decode_wrench, encode_joint_state, \
    encode_wrench
from wrenchd.models.errors import DataError
from wrenchd.models.series import JointSample

FUZZ = settings(max_examples=150, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow])
NS = 1_000_000_000

# JSON numbers a publisher can send: floats with NaN/Inf (json.loads reads NaN, Infinity),
# ints within 64 bits (an int beyond float64 is refused: the exact-payload tests below).
numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                    st.integers(min_value=-(2 ** 63), max_value=2 ** 63))
scalars = st.one_of(st.none(), numbers, st.text(max_size=8), st.booleans())
json_values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=7), st.dictionaries(st.text(max_size=6), inner, max_size=4)),
    max_leaves=12)


def _dumps(message) -> bytes:
    return json.dumps(message, allow_nan=True).encode()


def _same(a, b) -> bool:
    """Equal floats, NaN equal to NaN."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


def check_joint_state(msg) -> None:
    """What a pipeline relies on in a decoded joint state."""
    assert isinstance(msg, JointSample)
    assert type(msg.stamp_ns) is int and isinstance(msg.frame_id, str)
    assert all(isinstance(n, str) for n in msg.name)
    n = len(msg.position)
    assert n > 0
    for v in (msg.position, msg.velocity, msg.effort):
        assert isinstance(v, np.ndarray) and v.dtype == np.float64 and v.shape == (n,)
    assert len(msg.name) in (0, n)


def decode_or_refuse(decode, *args):
    """The decoder's result, or None when it refused with DataError (anything else fails)."""
    try:
        return decode(*args)
    except DataError as exc:
        assert str(exc), "a refusal must say why"
        return None


def valid_joint_state_dict(n: int = 6) -> dict:
    return {"header": {"stamp": {"sec": 12, "nanosec": 345}, "frame_id": "psm_base"},
            "name": [f"j{i}" for i in range(n)], "position": [0.1 * i for i in range(n)],
            "velocity": [0.0] * n, "effort": [0.5] * n}


def valid_wrench_dict() -> dict:
    return {"header": {"stamp": {"sec": 3, "nanosec": 7}, "frame_id": "psm_base"},
            "wrench": {"force": {"x": 1.0, "y": -2.0, "z": 0.5},
                       "torque": {"x": 0.0, "y": 0.01, "z": -0.02}},
            "wrenchd": {"free": True, "model_version": 2}}


JOINT_STATE_PATHS = [("header",), ("header", "stamp"), ("header", "stamp", "sec"),
                     ("header", "stamp", "nanosec"), ("header", "frame_id"), ("name",),
                     ("name", 0), ("position",), ("position", 2), ("velocity",),
                     ("velocity", 5), ("effort",), ("effort", 0)]


def _replace(message: dict, path: tuple, value, delete: bool) -> None:
    parent = message
    for p in path[:-1]:
        parent = parent[p]
    if delete:
        del parent[path[-1]]
    else:
        parent[path[-1]] = value


# -- joint states -------------------------------------------------------------------------
@FUZZ
@given(encoding=st.sampled_from(["json", "cdr"]), payload=st.binary(max_size=400))
@example(encoding="json", payload=b"")
@example(encoding="json", payload=b"\xff\xfe{")
@example(encoding="json", payload=b"[" * 5000)
@example(encoding="cdr", payload=b"\x00\x01\x00\x00")
def test_joint_state_decoders_refuse_arbitrary_bytes(encoding, payload):
    msg = decode_or_refuse(decode_joint_state, encoding, payload)
    if msg is not None:
        check_joint_state(msg)


@FUZZ
@given(path=st.sampled_from(JOINT_STATE_PATHS), value=json_values, delete=st.booleans())
def test_json_joint_state_with_a_field_replaced(path, value, delete):
    message = valid_joint_state_dict()
    _replace(message, path, value, delete)
    msg = decode_or_refuse(decode_joint_state, "json", _dumps(message))
    if msg is None:
        return
    check_joint_state(msg)
    # accepted: it holds exactly what was sent, nothing coerced (a bool or a string is no number)
    for field in ("position", "velocity", "effort"):
        sent = message[field]
        assert all(type(v) in (int, float) for v in sent)
        assert _same(getattr(msg, field), sent)
    stamp = message["header"]["stamp"]
    assert msg.stamp_ns == stamp["sec"] * NS + stamp["nanosec"]
    assert 0 <= stamp["nanosec"] < NS


@FUZZ
@given(encoding=st.sampled_from(["json", "cdr"]),
       lengths=st.tuples(*[st.integers(0, 8)] * 4),
       values=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=8, max_size=8))
def test_joint_state_lengths_are_checked(encoding, lengths, values):
    n_name, n_q, n_dq, n_tau = lengths
    names = [f"j{i}" for i in range(n_name)]
    q, dq, tau = values[:n_q], values[:n_dq], values[:n_tau]
    if encoding == "json":
        message = valid_joint_state_dict()
        message.update(name=names, position=q, velocity=dq, effort=tau)
        payload = _dumps(message)
    else:
        payload = encode_joint_state("cdr", 5 * NS + 9, names, q, dq, tau, frame_id="f")
    ok = n_q > 0 and n_q == n_dq == n_tau and n_name in (0, n_q)
    msg = decode_or_refuse(decode_joint_state, encoding, payload)
    assert (msg is not None) == ok, (lengths, msg)
    if msg is not None:
        check_joint_state(msg)
        # NaN and Inf pass the decoder untouched: refusing them is the pipeline's validation
        assert _same(msg.position, q) and _same(msg.velocity, dq) and _same(msg.effort, tau)


@st.composite
def damaged_cdr(draw):
    n = draw(st.integers(0, 7))
    payload = bytearray(encode_joint_state("cdr", draw(st.integers(0, 2 ** 40)),
                                           [f"joint{i}" for i in range(n)], [0.5] * n,
                                           [0.25] * n, [1.0] * n, frame_id="psm_base"))
    kind = draw(st.sampled_from(["truncate", "extend", "overwrite", "length"]))
    if kind == "truncate":
        del payload[draw(st.integers(0, max(len(payload) - 1, 0))):]
    elif kind == "extend":
        payload += draw(st.binary(min_size=1, max_size=64))
    elif kind == "overwrite":
        at = draw(st.integers(0, len(payload) - 1))
        chunk = draw(st.binary(min_size=1, max_size=8))
        payload[at:at + len(chunk)] = chunk
    else:  # a 4-byte sequence/string length, anywhere aligned, set to something absurd
        at = 4 * draw(st.integers(1, len(payload) // 4 - 1))
        payload[at:at + 4] = struct.pack("<I", draw(st.sampled_from(
            [0, 1, 7, 0x7FFFFFFF, 0xFFFFFFFF, len(payload)])))
    return bytes(payload)


@FUZZ
@given(payload=damaged_cdr())
def test_cdr_joint_state_damaged(payload):
    msg = decode_or_refuse(decode_joint_state, "cdr", payload)
    if msg is not None:
        check_joint_state(msg)


# -- wrenches -----------------------------------------------------------------------------
def check_wrench(result) -> None:
    stamp_ns, frame, wrench, extra = result
    assert type(stamp_ns) is int and isinstance(frame, str) and isinstance(extra, dict)
    assert isinstance(wrench, np.ndarray) and wrench.shape == (6,) and wrench.dtype == np.float64


@FUZZ
@given(payload=st.binary(max_size=400))
@example(payload=b"\x00")
def test_cdr_wrench_decoder_refuses_arbitrary_bytes(payload):
    result = decode_or_refuse(decode_wrench, "cdr", payload)
    if result is not None:
        check_wrench(result)


WRENCH_PATHS = [("header",), ("header", "stamp"), ("header", "stamp", "sec"),
                ("header", "stamp", "nanosec"), ("header", "frame_id"), ("wrench",),
                ("wrench", "force"), ("wrench", "force", "x"), ("wrench", "torque", "z")]
# numbers, and values a number field cannot hold (strings and bools: the exact-payload
# test_json_wrench_refuses_non_numbers below)
wrench_values = st.one_of(st.none(), numbers, st.lists(numbers, max_size=3),
                          st.dictionaries(st.text(max_size=3), numbers, max_size=3))


@FUZZ
@given(path=st.sampled_from(WRENCH_PATHS), value=wrench_values, delete=st.booleans(),
       extra=st.one_of(st.none(), st.dictionaries(st.text(max_size=5), scalars, max_size=3)))
def test_json_wrench_with_a_field_replaced(path, value, delete, extra):
    message = valid_wrench_dict()
    message["wrenchd"] = extra
    _replace(message, path, value, delete)
    result = decode_or_refuse(decode_wrench, "json", _dumps(message))
    if result is None:
        return
    check_wrench(result)
    w = message["wrench"]
    sent = [w["force"]["x"], w["force"]["y"], w["force"]["z"],
            w["torque"]["x"], w["torque"]["y"], w["torque"]["z"]]
    assert _same(result[2], sent)
    # as JSON text: a NaN among the extra values is equal to itself there (not as a float)
    assert json.dumps(result[3], sort_keys=True) == json.dumps(extra or {}, sort_keys=True)


@pytest.mark.parametrize("encoding", ["json", "cdr"])
@given(wrench=st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64),
                       min_size=6, max_size=6), stamp_ns=st.integers(0, 2 ** 31 * NS - 1))
@FUZZ
def test_wrench_round_trip(encoding, wrench, stamp_ns):
    """The encoders' output decodes to the same wrench (stamps within ROS int32 seconds)."""
    payload = encode_wrench(encoding, stamp_ns, np.array(wrench), frame_id="psm_base",
                            extra={"free": False})
    got_ns, frame, got, extra = decode_wrench(encoding, payload)
    assert got_ns == stamp_ns and frame == "psm_base" and _same(got, wrench)
    assert extra == ({"free": False} if encoding == "json" else {})


# -- bugs found by the fuzzing above: exact payloads ------------------------------------
HUGE = "9" * 400      # a JSON integer beyond float64


def test_json_joint_state_integer_beyond_float_range():
    message = valid_joint_state_dict()
    payload = _dumps(message).replace(b'"position": [0.0', f'"position": [{HUGE}'.encode())
    assert HUGE.encode() in payload
    with pytest.raises(DataError, match="beyond float64"):
        decode_joint_state("json", payload)


def test_json_joint_state_sec_beyond_int32_is_refused():
    message = valid_joint_state_dict()
    message["header"]["stamp"]["sec"] = 2 ** 31
    with pytest.raises(DataError):
        decode_joint_state("json", _dumps(message))


@pytest.mark.parametrize("payload, why", [
    (b"[]", "JSON object"),                 # was AttributeError: list has no .get (in _header)
    (b"0", "JSON object"),                  # was AttributeError
    (b"[" * 5000, "not JSON"),              # was RecursionError from json.loads
    (_dumps({**valid_wrench_dict(), "wrenchd": [1]}), "wrenchd"),   # was TypeError: dict([1])
    (_dumps({**valid_wrench_dict(), "wrenchd": "ab"}), "wrenchd"),  # was ValueError: dict("ab")
    (_dumps(valid_wrench_dict()).replace(b'"x": 1.0', f'"x": {HUGE}'.encode()),
     "beyond float64"),                     # was OverflowError
], ids=["list", "number", "deep", "extra-list", "extra-str", "huge-int"])
def test_json_wrench_refuses_with_data_error(payload, why):
    with pytest.raises(DataError, match=why):
        decode_wrench("json", payload)


@pytest.mark.parametrize("value", ["1.5", True], ids=["string", "bool"])
def test_json_wrench_refuses_non_numbers(value):
    message = valid_wrench_dict()
    message["wrench"]["force"]["x"] = value
    with pytest.raises(DataError):
        decode_wrench("json", _dumps(message))


def test_json_joint_state_refuses_non_numbers():
    """A string, bool, null or list where a number belongs is refused, naming the field;
    NaN is a number (refusing it is the pipeline's validation)."""
    for value in ("1.5", True, None, [1.0]):
        message = valid_joint_state_dict()
        message["position"][0] = value
        with pytest.raises(DataError, match="position"):
            decode_joint_state("json", _dumps(message))
    assert math.isnan(decode_joint_state("json", _dumps(
        {**valid_joint_state_dict(1), "position": [float("nan")]})).position[0])
