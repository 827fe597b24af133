"""JSON and ROS 2 CDR encodings of JointState and WrenchStamped."""

import json

import numpy as np
import pytest

from wrenchd.adapters.messages import (decode_joint_state, decode_wrench, encode_joint_state,
                               encode_wrench)
from wrenchd.models.errors import ConfigError, DataError

NAMES = ["outer_yaw", "outer_pitch", "outer_insertion", "outer_roll", "outer_wrist_pitch",
         "outer_wrist_yaw"]


@pytest.mark.parametrize("encoding", ["json", "cdr"])
def test_joint_state_round_trip(encoding):
    rng = np.random.default_rng(1)
    q, dq, tau = rng.normal(size=(3, 6))
    stamp = 1_700_000_123_456_789_012
    payload = encode_joint_state(encoding, stamp, NAMES, q, dq, tau, frame_id="psm1")
    msg = decode_joint_state(encoding, payload)
    assert msg.stamp_ns == stamp and msg.frame_id == "psm1" and msg.name == tuple(NAMES)
    np.testing.assert_array_equal(msg.position, q)
    np.testing.assert_array_equal(msg.velocity, dq)
    np.testing.assert_array_equal(msg.effort, tau)


def test_json_mirrors_the_ros_fields():
    m = json.loads(encode_joint_state("json", 3_000_000_007, NAMES, [0] * 6, [1] * 6, [2] * 6))
    assert m["header"] == {"stamp": {"sec": 3, "nanosec": 7}, "frame_id": ""}
    assert set(m) == {"header", "name", "position", "velocity", "effort"}
    w = json.loads(encode_wrench("json", 5, np.arange(6.0), extra={"free": True}))
    assert w["wrench"] == {"force": {"x": 0, "y": 1, "z": 2}, "torque": {"x": 3, "y": 4, "z": 5}}
    assert w["wrenchd"] == {"free": True}


def test_cdr_is_the_ros2_serialisation():
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    payload = encode_wrench("cdr", 2_500_000_000, np.arange(6.0), frame_id="psm_base")
    assert payload[:4] == b"\x00\x01\x00\x00"           # CDR little-endian encapsulation
    msg = store.deserialize_cdr(payload, "geometry_msgs/msg/WrenchStamped")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (2, 500_000_000)
    assert msg.header.frame_id == "psm_base"
    assert (msg.wrench.force.z, msg.wrench.torque.x) == (2.0, 3.0)
    stamp, frame, w, extra = decode_wrench("cdr", payload)
    assert stamp == 2_500_000_000 and frame == "psm_base" and extra == {}
    np.testing.assert_array_equal(w, np.arange(6.0))


@pytest.mark.parametrize("payload, why", [
    (b"not json", "not JSON"),
    (b"[1,2]", "JSON object"),
    (b'{"header":{"stamp":{"sec":1,"nanosec":0}},"position":[1],"velocity":[1,2],"effort":[1]}',
     "equal"),
    (b'{"header":{"stamp":{"sec":1.5,"nanosec":0}},"position":[],"velocity":[],"effort":[]}',
     "integers"),
    (b'{"header":{"stamp":{"sec":1,"nanosec":0}},"position":"abc","velocity":[],"effort":[]}',
     "list of numbers"),
])
def test_bad_json_joint_states_are_refused_with_the_reason(payload, why):
    with pytest.raises(DataError, match=why):
        decode_joint_state("json", payload)


def test_bad_cdr_and_unknown_encoding_are_refused():
    with pytest.raises(DataError, match="CDR"):
        decode_joint_state("cdr", b"\x00\x01\x00\x00\xff")
    with pytest.raises(ConfigError):
        decode_joint_state("xml", b"")


def test_setup_change_round_trip_and_refusals():
    from wrenchd.adapters.messages import decode_setup_change, encode_setup_change

    assert decode_setup_change(encode_setup_change()) == (None, {})
    stamp, detail = decode_setup_change(encode_setup_change(88_500_000_000, 20, "insufflation"))
    assert stamp == 88_500_000_000
    assert detail == {"pressure_mmhg": 20.0, "note": "insufflation"}
    assert json.loads(encode_setup_change(3_000_000_007)) == {"stamp": {"sec": 3, "nanosec": 7}}
    for payload, reason in [
            (b"not json", "not JSON"),
            (b"[1]", "JSON object"),
            (b'{"pressure": 20}', "unknown field"),
            (b'{"pressure_mmhg": "high"}', "pressure_mmhg"),
            (b'{"pressure_mmhg": -1}', "pressure_mmhg"),
            (b'{"pressure_mmhg": NaN}', "pressure_mmhg"),
            (b'{"pressure_mmhg": true}', "pressure_mmhg"),
            (b'{"stamp": {"sec": -1, "nanosec": 0}}', "sec"),
            (b'{"stamp": {"sec": 1.5, "nanosec": 0}}', "integers"),
            (b'{"stamp": 5}', "'stamp' must be an object"),
            (b'{"note": 5}', "note"),
            (json.dumps({"note": "x" * 201}).encode(), "note")]:
        with pytest.raises(DataError, match=reason):
            decode_setup_change(payload)


def test_a_json_wrench_is_finite_or_refused():
    """JSON has no NaN or infinity: such a wrench is refused by name; a finite one whose
    values' sum overflows is still written, exactly."""
    huge = np.array([1e308, 1e308, 0.0, 0.0, 0.0, -1e308])
    np.testing.assert_array_equal(decode_wrench("json", encode_wrench("json", 5, huge))[2], huge)
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="a wrench must be finite"):
            encode_wrench("json", 5, np.array([0.0, 0.0, bad, 0.0, 0.0, 0.0]))
