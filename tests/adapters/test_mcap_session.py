"""MCAP session files: round trip, viewer compatibility, determinism, truncation, bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk
from mcap.writer import Writer

from wrenchd.adapters.mcap_session import (
    SESSION_FORMAT,
    TOPIC_JOINT_STATES,
    TOPIC_SENSOR_WRENCH,
    TOPIC_TORQUES,
    TOPIC_WRENCH,
)
from wrenchd.adapters.mcap_session_reader import read_session, read_session_report
from wrenchd.adapters.mcap_session_writer import SessionWriter, write_session
from wrenchd.models.errors import AdapterError, DataError
from wrenchd.models.series import GroundTruth, JointStates, Session

# The writer keeps 10 significant digits ("%.10g"): relative error <= 5e-10.
RTOL = 5.0001e-10


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


def assert_sessions_close(got: Session, want: Session) -> None:
    np.testing.assert_array_equal(got.joint_states.t, want.joint_states.t)
    assert got.joint_states.names == want.joint_states.names
    for name in ("position", "velocity", "effort"):
        np.testing.assert_allclose(getattr(got.joint_states, name),
                                   getattr(want.joint_states, name), rtol=RTOL, atol=0)
    if want.truth is None:
        assert got.truth is None
        return
    g, w = got.truth, want.truth
    for name in ("position", "velocity", "acceleration", "internal_torque", "external_torque",
                 "external_wrench"):
        np.testing.assert_allclose(getattr(g, name), getattr(w, name), rtol=RTOL, atol=0)
    np.testing.assert_array_equal(g.in_contact, w.in_contact)
    assert list(g.effects) == list(w.effects)
    for name in w.effects:
        np.testing.assert_allclose(g.effects[name], w.effects[name], rtol=RTOL, atol=0)
    if w.sensor_wrench is None:
        assert g.sensor_wrench is None
    else:
        np.testing.assert_allclose(g.sensor_wrench, w.sensor_wrench, rtol=RTOL, atol=0)


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


def test_opens_with_the_mcap_library_reader(tmp_path):
    session = make_session(120)
    path = tmp_path / "s.mcap"
    write_session(path, session)
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().library == "wrenchd.adapters.mcap_session/1"
        summary = reader.get_summary()
        assert summary is not None
        assert {s.encoding for s in summary.schemas.values()} == {"jsonschema"}
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        assert sorted(c.topic for c in summary.channels.values()) == sorted(
            [TOPIC_JOINT_STATES, TOPIC_WRENCH, TOPIC_SENSOR_WRENCH, TOPIC_TORQUES])
        assert summary.statistics.message_count == 4 * 120
        counts: dict[str, int] = {}
        for _schema, channel, _message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        assert counts == dict.fromkeys(counts, 120) and len(counts) == 4
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    assert records["wrenchd.session"]["format"] == SESSION_FORMAT
    assert json.loads(records["wrenchd.session"]["json"]) == session.metadata


def _check_structure(value, schema, where="") -> None:
    """The JSON Schema subset our schemas use: type, properties, required, items, sizes."""
    kind = schema.get("type")
    if kind == "object":
        assert isinstance(value, dict), where
        for key in schema.get("required", []):
            assert key in value, f"{where}.{key} missing"
        for key, item in value.items():
            sub = schema.get("properties", {}).get(key, schema.get("additionalProperties"))
            if isinstance(sub, dict):
                _check_structure(item, sub, f"{where}.{key}")
    elif kind == "array":
        assert isinstance(value, list), where
        assert schema.get("minItems", 0) <= len(value) <= schema.get("maxItems", math.inf), where
        for i, item in enumerate(value):
            _check_structure(item, schema["items"], f"{where}[{i}]")
    elif kind == "number":
        assert isinstance(value, (int, float)) and not isinstance(value, bool), where
        assert math.isfinite(value), where
    elif kind == "integer":
        assert isinstance(value, int) and not isinstance(value, bool), where
        assert schema.get("minimum", -math.inf) <= value <= schema.get("maximum", math.inf), where
    elif kind == "boolean":
        assert isinstance(value, bool), where
    elif kind == "string":
        assert isinstance(value, str), where


def test_every_message_validates_against_its_channel_schema(tmp_path):
    """Checked with the subset of JSON Schema the channels use (``_check_structure``);
    jsonschema itself is not among the locked dependencies."""
    path = tmp_path / "s.mcap"
    write_session(path, make_session(60))
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            definition = json.loads(schema.data)
            decoded = json.loads(message.data)
            _check_structure(decoded, definition, channel.topic)
            stamp = decoded["header"]["stamp"]
            assert message.log_time == message.publish_time
            assert message.log_time == stamp["sec"] * 1_000_000_000 + stamp["nanosec"]
            frame = "psm_base" if "wrench" in channel.topic else ""
            assert decoded["header"]["frame_id"] == frame
            # and the check refuses what the schema forbids: a missing field, a wrong type
            broken = json.loads(message.data)
            del broken["header"]
            with pytest.raises(AssertionError):
                _check_structure(broken, definition, channel.topic)
            broken = json.loads(message.data)
            broken["header"]["stamp"]["sec"] = "12"
            with pytest.raises(AssertionError):
                _check_structure(broken, definition, channel.topic)


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
    """A hand-made MCAP with the given measured_js payloads, 5 ms apart."""
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
