"""MCAP session files: ROS 2 round trip, read by ROS tools' libraries, the former JSON format,
determinism, truncation, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from tests.adapters.json_mcap import write_json_session
from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.mcap_session import (
    SESSION_FORMAT,
    TOPIC_JOINT_STATES,
    TOPIC_SENSOR_WRENCH,
    TOPIC_TORQUES,
    TOPIC_TYPES,
    TOPIC_WRENCH,
)
from wrenchd.adapters.mcap_session_reader import read_session, read_session_report
from wrenchd.adapters.mcap_session_writer import SessionWriter, round_mantissa, write_session
from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import GroundTruth, JointStates, Session

# The writer rounds every number to 32 fraction bits: relative error <= 2**-33.
RTOL = 2.0**-33
# The former JSON sessions kept 10 significant digits: relative error <= 5e-10.
JSON_RTOL = 5.0001e-10


def make_session(n: int = 300, *, seed: int = 0, sensor: bool = True,
                 truth: bool = True) -> Session:
    rng = np.random.default_rng(seed)

    def m(scale: float = 1.0) -> np.ndarray:
        return rng.standard_normal((n, 6)) * scale

    t = np.arange(n) / 200.0
    js = JointStates(t, m(), m(2.0), m(0.5))
    gt = None
    if truth:
        gt = GroundTruth(
            m(), m(), m(50.0), m(), m(0.1), m(3.0), rng.random(n) < 0.4,
            {"coulomb_viscous": m(0.2), "seal": m(0.05)},
            m(3.0) if sensor else None,
        )
    metadata = {"scenario": "unit", "seed": seed, "rates": {"control_hz": 200.0},
                "tags": ["a", "b"]}
    return Session(js, gt, metadata)


def assert_sessions_close(got: Session, want: Session, rtol: float = RTOL) -> None:
    np.testing.assert_array_equal(got.joint_states.t, want.joint_states.t)
    assert got.joint_states.names == want.joint_states.names
    for name in ("position", "velocity", "effort"):
        np.testing.assert_allclose(getattr(got.joint_states, name),
                                   getattr(want.joint_states, name), rtol=rtol, atol=0)
    if want.truth is None:
        assert got.truth is None
        return
    g, w = got.truth, want.truth
    for name in ("position", "velocity", "acceleration", "internal_torque", "external_torque",
                 "external_wrench"):
        np.testing.assert_allclose(getattr(g, name), getattr(w, name), rtol=rtol, atol=0)
    np.testing.assert_array_equal(g.in_contact, w.in_contact)
    assert list(g.effects) == list(w.effects)
    for name in w.effects:
        np.testing.assert_allclose(g.effects[name], w.effects[name], rtol=rtol, atol=0)
    if w.sensor_wrench is None:
        assert g.sensor_wrench is None
    else:
        np.testing.assert_allclose(g.sensor_wrench, w.sensor_wrench, rtol=rtol, atol=0)


def test_round_trip_with_truth_effects_and_metadata(tmp_path):
    session = make_session()
    path = tmp_path / "s.mcap"
    write_session(path, session)
    got, info = read_session_report(path)
    assert_sessions_close(got, session)
    assert got.metadata == session.metadata
    assert not info.truncated
    assert info.messages == 4 * 300
    assert info.topic_messages == {TOPIC_JOINT_STATES: 300, TOPIC_WRENCH: 300,
                                   TOPIC_SENSOR_WRENCH: 300, TOPIC_TORQUES: 300}
    assert info.dropped_samples == 0


def test_round_trip_without_sensor_and_without_truth(tmp_path):
    no_sensor = make_session(50, sensor=False)
    write_session(tmp_path / "a.mcap", no_sensor)
    got = read_session(tmp_path / "a.mcap")
    assert got.truth is not None and got.truth.sensor_wrench is None
    assert_sessions_close(got, no_sensor)

    measured_only = make_session(50, truth=False)
    write_session(tmp_path / "b.mcap", measured_only)
    got, info = read_session_report(tmp_path / "b.mcap")
    assert got.truth is None
    assert info.topic_messages == {TOPIC_JOINT_STATES: 50}
    assert_sessions_close(got, measured_only)


def test_sample_times_survive_exactly(tmp_path):
    # t = k / 200 -> k * 5e6 ns -> back: the nearest double again.
    session = make_session(1000, truth=False)
    write_session(tmp_path / "t.mcap", session)
    np.testing.assert_array_equal(read_session(tmp_path / "t.mcap").joint_states.t,
                                  session.joint_states.t)


def test_opens_with_the_mcap_library_reader_as_ros2(tmp_path):
    session = make_session(120)
    path = tmp_path / "s.mcap"
    write_session(path, session)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == "ros2" and header.library == "wrenchd.adapters.mcap_session/2"
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert {c.topic: summary.schemas[c.schema_id].name
                for c in summary.channels.values()} == TOPIC_TYPES
        assert summary.statistics.message_count == 4 * 120
        # the mcap library's own ROS 2 decoder, from the schemas in the file
        rows: dict[str, list] = {}
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            stamp = decoded.header.stamp
            assert message.log_time == message.publish_time
            assert message.log_time == stamp.sec * 1_000_000_000 + stamp.nanosec
            assert decoded.header.frame_id == ("psm_base" if "wrench" in channel.topic else "")
            rows.setdefault(channel.topic, []).append(decoded)
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert {t: len(r) for t, r in rows.items()} == dict.fromkeys(TOPIC_TYPES, 120)
    assert records["wrenchd.session"]["format"] == SESSION_FORMAT
    assert json.loads(records["wrenchd.session"]["json"]) == session.metadata
    js, truth = session.joint_states, session.truth
    np.testing.assert_allclose([m.effort for m in rows[TOPIC_JOINT_STATES]], js.effort,
                               rtol=RTOL, atol=0)
    assert rows[TOPIC_JOINT_STATES][7].name == list(js.names)
    w = rows[TOPIC_SENSOR_WRENCH][9].wrench
    np.testing.assert_allclose([w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y,
                                w.torque.z], truth.sensor_wrench[9], rtol=RTOL, atol=0)
    torques = rows[TOPIC_TORQUES][11]
    assert torques.in_contact == bool(truth.in_contact[11])
    assert [e.name for e in torques.effects] == list(truth.effects)
    np.testing.assert_allclose(torques.effects[1].torque, truth.effects["seal"][11],
                               rtol=RTOL, atol=0)


def test_rosbags_opens_it_as_a_ros2_bag_from_the_file_alone(tmp_path):
    """rosbags' rosbag2 Reader opens the bare .mcap; its AnyReader builds every type from the
    definitions in the file (an empty type store to start from) and decodes every message."""
    session = make_session(50)
    path = tmp_path / "s.mcap"
    write_session(path, session)
    with Reader(path) as bag:
        assert {c.topic: (c.msgtype, c.msgcount) for c in bag.connections} == {
            t: (k, 50) for t, k in TOPIC_TYPES.items()}
        assert all(c.ext.serialization_format == "cdr" for c in bag.connections)
        qos = bag.connections[0].ext.offered_qos_profiles[0]
        assert (qos.reliability.name, qos.durability.name) == ("RELIABLE", "VOLATILE")
    with AnyReader([path], default_typestore=get_typestore(Stores.EMPTY)) as bag:
        got: dict[str, list] = {}
        for connection, _, raw in bag.messages():
            got.setdefault(connection.topic, []).append(bag.deserialize(raw, connection.msgtype))
    np.testing.assert_allclose([m.position for m in got[TOPIC_JOINT_STATES]],
                               session.joint_states.position, rtol=RTOL, atol=0)
    np.testing.assert_allclose([m.external for m in got[TOPIC_TORQUES]],
                               session.truth.external_torque, rtol=RTOL, atol=0)
    np.testing.assert_allclose([m.wrench.force.z for m in got[TOPIC_WRENCH]],
                               session.truth.external_wrench[:, 2], rtol=RTOL, atol=0)


def test_rounding_keeps_32_fraction_bits_to_nearest():
    x = np.array([1.0, np.pi, -np.e * 1e5, 1e-300, 0.0, -0.0, np.inf, np.nan,
                  np.nextafter(2.0, 0.0), np.finfo(np.float64).max])
    r = round_mantissa(x)
    finite = np.isfinite(x)
    np.testing.assert_allclose(r[finite], x[finite], rtol=RTOL, atol=0)
    low = r[:9][finite[:9]].view(np.uint64) & np.uint64((1 << 20) - 1)
    assert not low.any()                                   # 20 low bits cleared
    assert r[8] == 2.0                                     # rounds up across a power of two
    assert r[9] == x[9] and np.isposinf(r[6]) and np.isnan(r[7])   # no carry into infinity
    assert np.signbit(r[5])


def test_a_former_json_session_reads_as_before(tmp_path):
    """Sessions written before the ROS 2 format (JSON, 10 significant digits) still read, and
    to the same session as the ROS 2 file of the same data."""
    session = make_session(80, seed=3)
    write_json_session(tmp_path / "old.mcap", session)
    write_session(tmp_path / "new.mcap", session)
    old, info = read_session_report(tmp_path / "old.mcap")
    assert not info.truncated and info.topic_messages[TOPIC_TORQUES] == 80
    assert old.metadata == session.metadata
    assert_sessions_close(old, session, rtol=JSON_RTOL)
    assert_sessions_close(old, read_session(tmp_path / "new.mcap"), rtol=JSON_RTOL + RTOL)


def test_same_session_gives_identical_bytes_whatever_the_blocks(tmp_path):
    session = make_session(500)
    write_session(tmp_path / "a.mcap", session, chunk_size=16 * 1024)
    write_session(tmp_path / "b.mcap", session, chunk_size=16 * 1024)
    # streaming in odd blocks must produce the very same file as the batch writer
    js, truth = session.joint_states, session.truth
    with SessionWriter(tmp_path / "c.mcap", metadata=session.metadata, chunk_size=16 * 1024) as w:
        for start in range(0, 500, 37):
            stop = min(start + 37, 500)
            block_truth = truth.slice(start, stop)
            assert w.write_joint_states(js.slice(start, stop), block_truth) == stop - start
    a = (tmp_path / "a.mcap").read_bytes()
    assert a == (tmp_path / "b.mcap").read_bytes()
    assert a == (tmp_path / "c.mcap").read_bytes()


def _chunk_messages(path) -> list[tuple[int, int, dict[str, int]]]:
    """(start offset, end offset, messages per channel id) of every chunk, from the summary."""
    out = []
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        for index in summary.chunk_indexes:
            f.seek(index.chunk_start_offset + 1 + 8)  # opcode, record length
            chunk = Chunk.read(ReadDataStream(f))
            per_channel: dict[str, int] = {}
            for record in breakup_chunk(chunk):
                if isinstance(record, Message):
                    topic = summary.channels[record.channel_id].topic
                    per_channel[topic] = per_channel.get(topic, 0) + 1
            out.append((index.chunk_start_offset,
                        index.chunk_start_offset + index.chunk_length, per_channel))
    return out


def test_truncated_file_yields_every_complete_chunk(tmp_path):
    session = make_session(400)
    path = tmp_path / "full.mcap"
    write_session(path, session, chunk_size=16 * 1024)
    data = path.read_bytes()
    chunks = _chunk_messages(path)
    assert len(chunks) >= 10
    third_start, third_end, _ = chunks[2]
    cuts = {
        "60 percent": int(0.6 * len(data)),
        "mid third chunk": (third_start + third_end) // 2,
        "right after a chunk": chunks[5][1],  # its message indexes are cut away
        "in the summary": chunks[-1][1] + (len(data) - chunks[-1][1]) // 2,
    }
    for label, cut in cuts.items():
        cut_path = tmp_path / "cut.mcap"
        cut_path.write_bytes(data[:cut])
        complete = [c for c in chunks if c[1] <= cut]
        per_topic: dict[str, int] = {}
        for _, _, counts in complete:
            for topic, count in counts.items():
                per_topic[topic] = per_topic.get(topic, 0) + count
        got, info = read_session_report(cut_path)
        assert info.truncated, label
        assert info.chunks == len(complete), label
        assert info.messages == sum(per_topic.values()), label
        assert info.topic_messages == per_topic, label
        n = min(per_topic.values())
        assert len(got.joint_states) == n, label
        assert info.dropped_samples == per_topic[TOPIC_JOINT_STATES] - n, label
        assert got.metadata == session.metadata
        want = Session(session.joint_states.slice(0, n), session.truth.slice(0, n))
        assert_sessions_close(got, want)
        with pytest.raises(AdapterError, match="truncated"):
            read_session(cut_path, allow_truncated=False)


def test_cut_before_the_first_complete_chunk_is_an_adapter_error(tmp_path):
    path = tmp_path / "full.mcap"
    write_session(path, make_session(400), chunk_size=16 * 1024)
    first_start, first_end, _ = _chunk_messages(path)[0]
    (tmp_path / "cut.mcap").write_bytes(path.read_bytes()[:(first_start + first_end) // 2])
    with pytest.raises(AdapterError, match="truncated"):
        read_session(tmp_path / "cut.mcap")


def test_not_mcap_raises_adapter_error(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(np.random.default_rng(1).bytes(4096))
    with pytest.raises(AdapterError, match="not an MCAP file"):
        read_session(garbage)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(AdapterError):
        read_session(empty)
    with pytest.raises(AdapterError, match="cannot open"):
        read_session(tmp_path / "missing.mcap")


def _write_raw_joint_states(path, messages: list[dict]) -> None:
    """A hand-made MCAP in the former JSON format with the given measured_js payloads, 5 ms
    apart."""
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("sensor_msgs/JointState", "jsonschema", b"{}")
        channel = writer.register_channel(TOPIC_JOINT_STATES, "json", schema)
        for k, message in enumerate(messages):
            ns = k * 5_000_000
            writer.add_message(channel, ns, json.dumps(message).encode(), ns)
        writer.finish()


def _js_message(k: int) -> dict:
    ns = k * 5_000_000
    return {"header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": ""},
            "name": ["a", "b", "c", "d", "e", "f"], "position": [0.1 * k] * 6,
            "velocity": [0.0] * 6, "effort": [1.0] * 6}


def test_a_daemon_style_file_with_joint_states_only_reads(tmp_path):
    _write_raw_joint_states(tmp_path / "d.mcap", [_js_message(k) for k in range(10)])
    got, info = read_session_report(tmp_path / "d.mcap")
    assert got.truth is None and got.metadata == {} and not info.truncated
    assert got.joint_states.names == ("a", "b", "c", "d", "e", "f")
    np.testing.assert_allclose(got.joint_states.t, np.arange(10) * 0.005)
    np.testing.assert_allclose(got.joint_states.position[:, 2], 0.1 * np.arange(10))


@pytest.mark.parametrize("field, value, pattern", [
    ("position", [0.0] * 5, "position must be 6 numbers"),
    ("effort", [1.0, float("nan"), 0, 0, 0, 0], "effort contains NaN"),
    ("velocity", ["1.0"] * 6, "velocity must be 6 numbers"),
    ("effort", None, "missing or malformed field"),
])
def test_invalid_messages_raise_data_error_naming_topic_and_time(tmp_path, field, value, pattern):
    messages = [_js_message(k) for k in range(8)]
    if value is None:
        del messages[3][field]
    else:
        messages[3][field] = value
    _write_raw_joint_states(tmp_path / "bad.mcap", messages)
    with pytest.raises(DataError, match=pattern) as err:
        read_session(tmp_path / "bad.mcap")
    assert TOPIC_JOINT_STATES in str(err.value) and "15000000 ns" in str(err.value)


def test_message_that_is_not_json_raises_data_error(tmp_path):
    path = tmp_path / "bad.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        channel = writer.register_channel(TOPIC_JOINT_STATES, "json",
                                          writer.register_schema("x", "jsonschema", b"{}"))
        writer.add_message(channel, 7, b"{not json", 7)
        writer.finish()
    with pytest.raises(DataError, match="at log time 7 ns: not valid JSON"):
        read_session(path)


def test_writer_rejects_bad_blocks(tmp_path):
    session = make_session(20)
    with SessionWriter(tmp_path / "w.mcap") as writer:
        writer.write_joint_states(session.joint_states.slice(0, 10))
        with pytest.raises(DataError, match="increase"):
            writer.write_joint_states(session.joint_states.slice(5, 15))
        with pytest.raises(DataError, match="truth"):
            writer.write_joint_states(session.joint_states.slice(10, 20),
                                      session.truth.slice(0, 20))
    bad_truth = session.truth.slice(0, 20)
    bad_truth.external_wrench[3, 1] = np.nan
    with pytest.raises(DataError, match="external_wrench contains NaN"):
        write_session(tmp_path / "x.mcap", Session(session.joint_states, bad_truth))
    with pytest.raises(DataError, match="JSON"):
        write_session(tmp_path / "y.mcap", Session(session.joint_states, None, {"x": object()}))


def test_stamps_that_do_not_increase_raise_data_error(tmp_path):
    messages = [_js_message(k) for k in range(5)]
    messages[3]["header"] = messages[2]["header"]
    _write_raw_joint_states(tmp_path / "dup.mcap", messages)
    with pytest.raises(DataError, match="strictly increasing"):
        read_session(tmp_path / "dup.mcap")


def _write_raw_cdr(path, payloads: list[bytes], schema: str = ros2.JOINT_STATE,
                   encoding: str = "cdr") -> None:
    """A hand-made ROS 2 MCAP with the given measured_js payloads, 5 ms apart."""
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        sid = writer.register_schema(schema, "ros2msg", ros2.full_definition(schema).encode())
        channel = writer.register_channel(TOPIC_JOINT_STATES, encoding, sid)
        for k, payload in enumerate(payloads):
            writer.add_message(channel, k * 5_000_000, payload, k * 5_000_000)
        writer.finish()


def _cdr_js(k: int, position=None, effort=None, stamp_ns=None) -> bytes:
    fields = _js_message(k)
    return ros2.serialize(ros2.message_class(ros2.JOINT_STATE)(
        header=ros2.header(k * 5_000_000 if stamp_ns is None else stamp_ns, ""),
        name=fields["name"], position=np.array(position or fields["position"], dtype=float),
        velocity=np.zeros(6), effort=np.array(effort or fields["effort"], dtype=float)))


@pytest.mark.parametrize("payload, pattern", [
    (_cdr_js(3, position=[0.0] * 5), "position must be 6 numbers"),
    (_cdr_js(3, effort=[1.0, float("nan"), 0, 0, 0, 0]), "effort contains NaN"),
    (b"\x00\x01\x00\x00\x07", "not a CDR sensor_msgs/msg/JointState"),
])
def test_invalid_cdr_messages_raise_data_error_naming_topic_and_time(tmp_path, payload, pattern):
    payloads = [_cdr_js(k) for k in range(8)]
    payloads[3] = payload
    _write_raw_cdr(tmp_path / "bad.mcap", payloads)
    with pytest.raises(DataError, match=pattern) as err:
        read_session(tmp_path / "bad.mcap")
    assert TOPIC_JOINT_STATES in str(err.value) and "15000000 ns" in str(err.value)


def test_a_cdr_joint_state_file_reads_and_bad_channels_are_refused(tmp_path):
    _write_raw_cdr(tmp_path / "ok.mcap", [_cdr_js(k) for k in range(10)])
    got = read_session(tmp_path / "ok.mcap")
    assert got.truth is None and got.joint_states.names == ("a", "b", "c", "d", "e", "f")
    np.testing.assert_array_equal(got.joint_states.position[:, 2], 0.1 * np.arange(10))
    _write_raw_cdr(tmp_path / "type.mcap", [b"\x00\x01\x00\x00"], schema=ros2.WRENCH_STAMPED)
    with pytest.raises(DataError, match="carries 'geometry_msgs/msg/WrenchStamped', expected "
                                        "'sensor_msgs/msg/JointState'"):
        read_session(tmp_path / "type.mcap")
    _write_raw_cdr(tmp_path / "enc.mcap", [b"\x00"], encoding="protobuf")
    with pytest.raises(DataError, match="message encoding 'protobuf'"):
        read_session(tmp_path / "enc.mcap")
    payloads = [_cdr_js(k) for k in range(5)]
    payloads[3] = _cdr_js(3, stamp_ns=2 * 5_000_000)
    _write_raw_cdr(tmp_path / "dup.mcap", payloads)
    with pytest.raises(DataError, match="strictly increasing"):
        read_session(tmp_path / "dup.mcap")


def test_wrenchd_files_are_told_from_other_ros2_bags(tmp_path):
    from wrenchd.adapters.mcap_session_reader import is_wrenchd_file
    from wrenchd.adapters.rosbag import write_joint_states_bag

    session = make_session(300)
    write_session(tmp_path / "s.mcap", session, chunk_size=16 * 1024)
    write_json_session(tmp_path / "old.mcap", session)
    (tmp_path / "cut.mcap").write_bytes((tmp_path / "s.mcap").read_bytes()[:5000])
    bag = write_joint_states_bag(tmp_path / "recorded.mcap", session.joint_states)
    with open(bag, "rb") as f:
        assert make_reader(f).get_header().profile == "ros2"      # rosbags' own writer
    assert [is_wrenchd_file(tmp_path / n) for n in ("s.mcap", "old.mcap", "cut.mcap")] == [
        True, True, True]
    assert not is_wrenchd_file(bag)
    (tmp_path / "garbage.mcap").write_bytes(b"\x89MCAP0\r\nxx")
    with pytest.raises(AdapterError, match="not an MCAP file"):
        is_wrenchd_file(tmp_path / "garbage.mcap")
