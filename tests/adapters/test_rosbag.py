"""ROS 2 bag reader and writer: bags built by the ``rosbags`` library itself (its Writer and
its type store's CDR serialisation, as ``ros2 bag record`` stores a dVRK's topics), read back
by wrenchd and compared exactly with the WPI recording they were made from."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from wrenchd.adapters.csv_psm import read_wpi_csv
from wrenchd.adapters.rosbag import (
    bag_topics, read_joint_states_bag, write_joint_states_bag,
)
from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import JOINT_NAMES, JointStates

STORE = get_typestore(Stores.ROS2_HUMBLE)
JS = "sensor_msgs/msg/JointState"
ARM, JAW = "/PSM1/measured_js", "/PSM1/jaw/measured_js"
EPOCH_NS = 1_732_000_000_123_456_789        # a wall-clock start, as a lab's recording has
MTM_NAMES = ["outer_yaw", "shoulder_pitch", "elbow_pitch", "wrist_platform", "wrist_pitch",
             "wrist_yaw", "wrist_roll"]


def _joint_state(stamp_ns: int, names, position, velocity, effort):
    t = STORE.types
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9),
        frame_id="")
    return t[JS](header=header, name=list(names),
                 position=np.asarray(position, dtype=np.float64),
                 velocity=np.asarray(velocity, dtype=np.float64),
                 effort=np.asarray(effort, dtype=np.float64))


def _ros_bag(path: Path, topics: dict[str, list[tuple[int, object, str]]],
             storage: StoragePlugin = StoragePlugin.MCAP) -> Path:
    """A rosbag2 directory written by rosbags: ``{topic: [(log_ns, message, msgtype)]}``."""
    with Writer(path, version=9, storage_plugin=storage) as writer:
        conns = {name: writer.add_connection(name, msgs[0][2], typestore=STORE)
                 for name, msgs in topics.items()}
        merged = sorted((log, name, msg, kind) for name, msgs in topics.items()
                        for log, msg, kind in msgs)
        for log, name, msg, kind in merged:
            writer.write(conns[name], log, STORE.serialize_cdr(msg, kind))
    return path


def _arm_messages(js: JointStates, start_ns: int = 0, jaw: np.ndarray | None = None):
    arm, jaws = [], []
    for i, t in enumerate(js.t):
        stamp = start_ns + round(t * 1e9)
        q, dq, tau = js.position[i], js.velocity[i], js.effort[i]
        names = JOINT_NAMES
        arm.append((stamp, _joint_state(stamp, names, q, dq, tau), JS))
        if jaw is not None:
            jaws.append((stamp, _joint_state(stamp, ["jaw"], jaw[i, :1], jaw[i, 1:2],
                                             jaw[i, 2:]), JS))
    return arm, jaws


@pytest.fixture(scope="module")
def wpi(wpi_data):
    return read_wpi_csv(wpi_data / "one_no_weight.csv")


@pytest.fixture(scope="module")
def short(wpi):
    js, jaw = wpi
    return js.slice(0, 300), jaw[:300]


def _assert_same(read: JointStates, js: JointStates) -> None:
    for name in ("t", "position", "velocity", "effort"):
        np.testing.assert_array_equal(getattr(read, name), getattr(js, name), err_msg=name)
    assert read.names == JOINT_NAMES


def test_mcap_directory_from_wpi_round_trips_exactly(wpi, tmp_path):
    js, jaw = wpi
    arm, jaws = _arm_messages(js, jaw=jaw)
    bag = _ros_bag(tmp_path / "session", {ARM: arm, JAW: jaws})
    got = read_joint_states_bag(bag)
    _assert_same(got.joint_states, js)
    np.testing.assert_array_equal(got.jaw, jaw)
    np.testing.assert_array_equal(got.jaw_t, js.t)
    assert (got.start_ns, got.time_source, got.topic) == (0, "header", ARM)
    assert len(got.joint_states) == 5999


def test_sqlite3_directory_with_epoch_stamps(short, tmp_path):
    js, _ = short
    arm, _ = _arm_messages(js, start_ns=EPOCH_NS)
    bag = _ros_bag(tmp_path / "sqlite", {ARM: arm}, StoragePlugin.SQLITE3)
    assert any(p.suffix == ".db3" for p in bag.iterdir())
    got = read_joint_states_bag(bag)
    assert got.start_ns == EPOCH_NS and got.jaw is None
    _assert_same(got.joint_states, js)          # times relative to the first stamp, exact


def test_bare_mcap_file(short, tmp_path):
    js, jaw = short
    arm, jaws = _arm_messages(js, jaw=jaw)
    bag = _ros_bag(tmp_path / "dir", {ARM: arm, JAW: jaws})
    bare = tmp_path / "recording.mcap"
    shutil.move(next(bag.glob("*.mcap")), bare)
    got = read_joint_states_bag(bare)
    _assert_same(got.joint_states, js)
    np.testing.assert_array_equal(got.jaw, jaw)


def test_seven_joint_messages_carry_the_jaw(short, tmp_path):
    js, jaw = short
    msgs = [(round(t * 1e9), _joint_state(round(t * 1e9), JOINT_NAMES + ("jaw",),
                                          np.r_[js.position[i], jaw[i, 0]],
                                          np.r_[js.velocity[i], jaw[i, 1]],
                                          np.r_[js.effort[i], jaw[i, 2]]), JS)
            for i, t in enumerate(js.t)]
    got = read_joint_states_bag(_ros_bag(tmp_path / "b", {ARM: msgs}), jaw_topic=None)
    _assert_same(got.joint_states, js)
    np.testing.assert_array_equal(got.jaw, jaw)


def test_unstamped_headers_fall_back_on_log_time(short, tmp_path):
    js, _ = short
    msgs = [(EPOCH_NS + round(t * 1e9),
             _joint_state(0, JOINT_NAMES, js.position[i], js.velocity[i], js.effort[i]), JS)
            for i, t in enumerate(js.t)]
    got = read_joint_states_bag(_ros_bag(tmp_path / "b", {ARM: msgs}))
    assert got.time_source == "log" and got.start_ns == EPOCH_NS
    _assert_same(got.joint_states, js)


def test_writer_output_is_a_bag_rosbags_reads(short, tmp_path):
    js, jaw = short
    for storage, path in (("mcap", tmp_path / "w1"), ("sqlite3", tmp_path / "w2"),
                          ("mcap", tmp_path / "w3.mcap")):
        write_joint_states_bag(path, js, storage=storage, start_ns=EPOCH_NS, jaw=jaw)
        with Reader(path) as reader:
            conns = [c for c in reader.connections if c.topic == ARM]
            assert [c.msgtype for c in conns] == [JS]
            decoded = [(log, STORE.deserialize_cdr(raw, JS))
                       for _, log, raw in reader.messages(conns)]
        assert len(decoded) == len(js)
        log, last = decoded[-1]
        assert last.header.stamp.sec * 10**9 + last.header.stamp.nanosec == log
        assert log == EPOCH_NS + round(js.t[-1] * 1e9)
        assert list(last.name) == list(JOINT_NAMES)
        np.testing.assert_array_equal(np.stack([m.position for _, m in decoded]), js.position)
        got = read_joint_states_bag(path)
        _assert_same(got.joint_states, js)
        np.testing.assert_array_equal(got.jaw, jaw)
    assert bag_topics(tmp_path / "w1") == {ARM: (JS, len(js)), "/PSM1/jaw/measured_js": (JS, len(js))}


def test_set_point_bag_without_effort(short, tmp_path):
    js, _ = short
    path = write_joint_states_bag(tmp_path / "sp", js, topic="/PSM1/servo_jp", with_effort=False)
    with Reader(path) as reader:
        msgs = [STORE.deserialize_cdr(raw, JS) for _, _, raw in reader.messages()]
    assert len(msgs) == len(js) and msgs[0].effort.size == 0
    np.testing.assert_array_equal(msgs[5].velocity, js.velocity[5])


# -- refusals ------------------------------------------------------------------------------
def test_missing_topic_lists_the_topics_there(short, tmp_path):
    js, _ = short
    arm, _ = _arm_messages(js.slice(0, 5))
    bag = _ros_bag(tmp_path / "b", {"/PSM2/measured_js": arm})
    with pytest.raises(DataError, match=r"no topic '/PSM1/measured_js'.*/PSM2/measured_js "
                                        r"\(sensor_msgs/msg/JointState\)"):
        read_joint_states_bag(bag)


def test_wrong_message_type(tmp_path):
    t = STORE.types
    kind = "geometry_msgs/msg/WrenchStamped"
    msg = t[kind](header=t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id=""),
        wrench=t["geometry_msgs/msg/Wrench"](force=t["geometry_msgs/msg/Vector3"](x=1, y=0, z=0),
                                            torque=t["geometry_msgs/msg/Vector3"](x=0, y=0, z=0)))
    bag = _ros_bag(tmp_path / "b", {ARM: [(1, msg, kind)]})
    with pytest.raises(DataError, match="carries geometry_msgs/msg/WrenchStamped"):
        read_joint_states_bag(bag)


@pytest.mark.parametrize("names, count, pattern", [
    (JOINT_NAMES[:5], 5, "message 0 has 5 joints, expected 6 or 7"),
    (MTM_NAMES, 7, "a dVRK PSM publishes"),
    ((), 6, "joints are no names"),
])
def test_wrong_joints(names, count, pattern, tmp_path):
    msgs = [(k + 1, _joint_state(k + 1, names, np.zeros(count), np.zeros(count),
                                 np.zeros(count)), JS) for k in range(3)]
    with pytest.raises(DataError, match=pattern):
        read_joint_states_bag(_ros_bag(tmp_path / "b", {ARM: msgs}))


def test_non_finite_value_names_message_and_joint(short, tmp_path):
    js, _ = short
    arm, _ = _arm_messages(js.slice(0, 10))
    bad = js.velocity[4].copy()
    bad[2] = np.nan
    stamp = arm[4][0]
    arm[4] = (stamp, _joint_state(stamp, JOINT_NAMES, js.position[4], bad, js.effort[4]), JS)
    with pytest.raises(DataError, match="message 4: velocity of joint 3 is nan"):
        read_joint_states_bag(_ros_bag(tmp_path / "b", {ARM: arm}))


def test_non_increasing_stamps(short, tmp_path):
    js, _ = short
    arm, _ = _arm_messages(js.slice(0, 10), start_ns=EPOCH_NS)
    log, msg, kind = arm[6]
    stale = _joint_state(EPOCH_NS + 10_000_000, JOINT_NAMES, js.position[6], js.velocity[6],
                         js.effort[6])                 # stamped as message 2, logged in order
    arm[6] = (log, stale, kind)
    with pytest.raises(DataError, match="header stamps must increase: message 6"):
        read_joint_states_bag(_ros_bag(tmp_path / "b", {ARM: arm}))


def test_not_a_bag(tmp_path):
    with pytest.raises(AdapterError, match="no ROS 2 bag"):
        read_joint_states_bag(tmp_path / "absent")
    (tmp_path / "plain").mkdir()
    with pytest.raises(AdapterError, match="without metadata.yaml"):
        read_joint_states_bag(tmp_path / "plain")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(AdapterError, match="cannot read ROS 2 bag"):
        read_joint_states_bag(junk)
    with pytest.raises(AdapterError, match="expected a rosbag2 directory"):
        read_joint_states_bag(__file__)


def test_writer_refuses_existing_path_and_bad_storage(short, tmp_path):
    js, _ = short
    (tmp_path / "taken").mkdir()
    with pytest.raises(AdapterError, match="exists"):
        write_joint_states_bag(tmp_path / "taken", js)
    with pytest.raises(DataError, match="storage must be one of"):
        write_joint_states_bag(tmp_path / "x", js, storage="bag")
    with pytest.raises(DataError, match="bare .mcap file needs storage 'mcap'"):
        write_joint_states_bag(tmp_path / "x.mcap", js, storage="sqlite3")
