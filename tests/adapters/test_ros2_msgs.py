"""ROS 2 message definitions of the logs: the standard types match ROS 2's, the complete
definitions follow rosbag2's ros2msg layout and parse in rosbags and the mcap ROS 2 decoder,
messages build from JSON-like fields."""

from __future__ import annotations

import re

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.models.errors import DataError

STANDARD = [t for t in ros2.MSG_TEXT if t not in ros2.OWN_TYPES]


@pytest.mark.parametrize("typename", STANDARD)
def test_standard_texts_have_the_fields_of_ros2_humble(typename):
    humble = get_typestore(Stores.ROS2_HUMBLE)
    ours = get_types_from_msg(ros2.MSG_TEXT[typename], typename)[typename]
    assert ours[1] == humble.fielddefs[typename][1]


def test_full_definition_follows_rosbag2s_layout():
    text = ros2.full_definition(ros2.WRENCH_STAMPED)
    sections = text.split("\n" + "=" * 80 + "\n")
    assert sections[0] == ros2.MSG_TEXT[ros2.WRENCH_STAMPED]    # the type first, no delimiter
    named = [s.split("\n", 1)[0] for s in sections[1:]]
    # depth first, each dependency once, a type's direct dependencies in name order, each
    # named as the fields name it (what rosbag2 writes, what Foxglove's parser matches)
    assert named == ["MSG: geometry_msgs/Wrench", "MSG: geometry_msgs/Vector3",
                     "MSG: std_msgs/Header", "MSG: builtin_interfaces/Time"]
    assert sections[2] == "MSG: geometry_msgs/Vector3\n" + ros2.MSG_TEXT[ros2.VECTOR3]
    assert ros2.dependencies(ros2.JOINT_TORQUE_TRUTH) == [
        "std_msgs/Header", "wrenchd_msgs/TorqueEffect"]
    field_types = set(re.findall(r"^([a-z_]+/[A-Za-z0-9]+)(?:\[\])? ", text, re.M))
    assert {n.removeprefix("MSG: ") for n in named} == field_types


@pytest.mark.parametrize("typename", list(ros2.MSG_TEXT))
def test_every_definition_parses_in_rosbags_and_the_mcap_decoder(typename):
    text = ros2.full_definition(typename)
    parsed = get_types_from_msg(text, typename)
    assert typename in parsed
    assert parsed[typename][1] == ros2.typestore().fielddefs[typename][1]
    assert typename in generate_dynamic(typename, text)


def test_messages_from_fields_take_ros_defaults_and_refuse_unknown_fields():
    msg = ros2.from_fields(ros2.ESTIMATE, {"header": {"stamp": {"sec": 3}}, "free": True,
                                           "external": [1, 2, 3, 4, 5, 6]})
    back = ros2.to_fields(ros2.deserialize(ros2.serialize(msg), ros2.ESTIMATE))
    assert back["header"] == {"stamp": {"sec": 3, "nanosec": 0}, "frame_id": ""}
    assert back["external"] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert back["force"] == [0.0] * 3 and back["score"] == 0.0 and back["free"] is True
    effects = ros2.from_fields(ros2.JOINT_TORQUE_TRUTH, {"effects": [{"name": "seal"}]}).effects
    assert effects[0].name == "seal" and np.array_equal(effects[0].torque, np.zeros(6))
    with pytest.raises(DataError, match=r"no field\(s\) \['speed'\]"):
        ros2.from_fields(ros2.ESTIMATE, {"speed": 1})
    with pytest.raises(DataError, match="external must be 6 numbers"):
        ros2.from_fields(ros2.ESTIMATE, {"external": [1, 2]})
    with pytest.raises(DataError, match=r"no field\(s\) \['predicted'\]"):   # effort - external
        ros2.from_fields(ros2.ESTIMATE, {"predicted": [0] * 6})
    with pytest.raises(DataError, match="header must be an object"):
        ros2.from_fields(ros2.ESTIMATE, {"header": 5})


def test_cdr_is_told_from_json_and_garbage_is_a_data_error():
    data = ros2.serialize(ros2.from_fields(ros2.STATUS, {"json": "{}"}))
    assert ros2.is_cdr(data) and not ros2.is_cdr(b'{"a": 1}') and not ros2.is_cdr(b" {}")
    with pytest.raises(DataError, match="not a CDR wrenchd_msgs/msg/Estimate"):
        ros2.deserialize(data[:6], ros2.ESTIMATE)


def test_a_message_decodes_with_the_definition_its_file_stores():
    """An estimate written with the former float64 definition reads back with it, today's with
    today's; a definition that does not parse is a data error."""
    from tests.adapters.float64_log import DEFINITION_FLOAT64, _store, estimate_float64

    old = estimate_float64(_store(), 3_000_000_001, np.arange(6.0) / 3, True, 0.25, 7, False,
                           np.full(6, 1 / 3), np.full(6, -1 / 7))
    msg = ros2.deserialize(old, ros2.ESTIMATE, DEFINITION_FLOAT64.encode())
    assert msg.wrench.torque.z == 5 / 3 and msg.model_version == 7 and msg.score == 0.25
    np.testing.assert_array_equal(msg.predicted, np.full(6, 1 / 3))     # float64, exact
    np.testing.assert_array_equal(msg.external, np.full(6, -1 / 7))
    new = ros2.serialize(ros2.from_fields(ros2.ESTIMATE, {"force": [1 / 3, 0, 0],
                                                          "external": [-1 / 7] * 6}))
    assert len(new) < 0.5 * len(old)                       # float32, without predicted
    for definition in (None, ros2.full_definition(ros2.ESTIMATE)):
        back = ros2.deserialize(new, ros2.ESTIMATE, definition)
        assert back.force[0] == np.float32(1 / 3) and back.external.dtype == np.float32
    with pytest.raises(DataError, match="not a CDR"):         # today's type, yesterday's bytes
        ros2.deserialize(old[:40], ros2.ESTIMATE)
    with pytest.raises(DataError, match="cannot read the definition"):
        ros2.deserialize(new, ros2.ESTIMATE, "float64[ broken\n")


def test_stamps_to_time_and_back():
    stamp_ns = 1_700_000_000 * ros2.NS_PER_S + 123_456_789
    assert ros2.split_ns(stamp_ns) == (1_700_000_000, 123_456_789)
    header = ros2.header(stamp_ns, "psm_base")
    assert (header.stamp.sec, header.stamp.nanosec, header.frame_id) == (
        1_700_000_000, 123_456_789, "psm_base")
    assert ros2.time_ns(header.stamp) == stamp_ns


@pytest.mark.parametrize(("sec", "nanosec", "what"), [(-1, 0, "header.stamp.sec"),
                                                      (0, ros2.NS_PER_S, "header.stamp.nanosec")])
def test_a_time_out_of_range_is_refused(sec, nanosec, what):
    bad = ros2.message_class(ros2.TIME)(sec=sec, nanosec=nanosec)
    with pytest.raises(DataError, match=re.escape(what)):
        ros2.time_ns(bad)
