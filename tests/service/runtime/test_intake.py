"""The channel intake: one key expression for the arms' keys, and a real zenoh session
delivering samples, ticks and strangers to the thread that takes them."""

import threading
import time

import pytest

from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.models.errors import ConfigError
from wrenchd.service.runtime.intake import ChannelIntake, channel_fits, key_pattern


def test_the_pattern_keeps_what_the_keys_share():
    assert key_pattern(["dvrk/PSM1/measured_js"]) == "dvrk/PSM1/measured_js"
    assert key_pattern(["dvrk/PSM1/measured_js", "dvrk/PSM2/measured_js",
                        "dvrk/PSM3/measured_js"]) == "dvrk/PSM$*/measured_js"
    assert key_pattern(["a/left_arm/js", "a/right_arm/js"]) == "a/$*t_arm/js"
    assert key_pattern(["a/x/js", "a/y/js"]) == "a/*/js"
    assert key_pattern(["0/PSM1/measured_js/sensor_msgs::msg::dds_::JointState_/abc",
                        "0/PSM2/measured_js/sensor_msgs::msg::dds_::JointState_/abc"]) == (
        "0/PSM$*/measured_js/sensor_msgs::msg::dds_::JointState_/abc")


def test_keys_that_no_single_expression_fits():
    assert key_pattern(["dvrk/PSM1/measured_js", "robot/PSM2/state/measured_js"]) is None
    assert key_pattern(["@a/js", "@b/js"]) is None
    with pytest.raises(ConfigError):
        key_pattern([])
    assert channel_fits(["dvrk/PSM1/measured_js", "dvrk/PSM2/measured_js"])
    assert not channel_fits(["dvrk/PSM1/measured_js", "robot/PSM2/state/measured_js"])
    assert not channel_fits(["dvrk/*/measured_js"])           # a pattern, not an arm's key


@pytest.fixture
def session():
    s = open_session(ZenohConfig())
    yield s
    s.close()


def _taken_later(intake, out):
    thread = threading.Thread(target=lambda: out.append(intake.take()))
    thread.start()
    return thread


def test_samples_reach_their_arm_in_order_and_strangers_are_counted(session):
    intake = ChannelIntake(session, ["dvrk/PSM1/measured_js", "dvrk/PSM2/measured_js"], 100)
    try:
        assert intake.pattern == "dvrk/PSM$*/measured_js"
        for i in range(3):
            session.put("dvrk/PSM2/measured_js", f"b{i}".encode())
            session.put("dvrk/PSM1/measured_js", f"a{i}".encode())
        session.put("dvrk/PSM7/measured_js", b"not ours")
        session.put("dvrk/MTML/measured_js", b"not even matched")
        time.sleep(0.2)
        taken = intake.take()
        assert [p for _, p, _ in taken[0]] == [b"a0", b"a1", b"a2"]
        assert [p for _, p, _ in taken[1]] == [b"b0", b"b1", b"b2"]
        assert all(mark is None for _, _, mark in taken[0] + taken[1])
        assert intake.foreign == 1 and intake.full == 0
    finally:
        intake.close()


def test_a_tick_wakes_the_taking_thread_with_nothing(session):
    intake = ChannelIntake(session, ["dvrk/PSM1/measured_js"], 10)
    out: list = []
    thread = _taken_later(intake, out)
    try:
        time.sleep(0.2)
        assert thread.is_alive()                 # blocked: nothing came
        intake.tick()
        thread.join(5.0)
        assert not thread.is_alive() and out == [[[]]]
    finally:
        if thread.is_alive():                    # never leave the channel borrowed
            intake.tick()
            thread.join(5.0)
        intake.close()


def test_a_full_channel_keeps_the_newest_and_is_counted(session):
    intake = ChannelIntake(session, ["dvrk/PSM1/measured_js"], 5)
    try:
        for i in range(12):
            session.put("dvrk/PSM1/measured_js", str(i).encode())
        time.sleep(0.2)
        taken = intake.take()
        assert [p for _, p, _ in taken[0]] == [str(i).encode() for i in range(7, 12)]
        assert intake.full == 1
    finally:
        intake.close()


def test_keys_that_do_not_fit_are_refused(session):
    with pytest.raises(ConfigError, match="intake"):
        ChannelIntake(session, ["dvrk/PSM1/measured_js", "x/PSM2/a/measured_js"], 10)
    with pytest.raises(ConfigError, match="exact keys"):
        ChannelIntake(session, ["dvrk/PSM1/**"], 10)
