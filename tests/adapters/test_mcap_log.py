"""The daemon's MCAP log: a ROS 2 bag that ROS tools' libraries decode, flushed each second,
readable after a crash, rotated, never fatal, smaller than the former logs."""

import shutil

import numpy as np
import orjson
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from tests.adapters.float64_log import write_float64_daemon_log
from tests.adapters.json_mcap import write_json_daemon_log
from wrenchd.adapters import ros2_msgs as ros2
from wrenchd.adapters.mcap_log import (TOPIC_ESTIMATE, TOPIC_EVENTS, TOPIC_STATUS, TOPIC_TYPES,
                                       LogConfig, McapLog, estimate_record, format_record,
                                       message_fields)
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.messages import decode_joint_state, encode_joint_state
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.series import JOINT_NAMES


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def write_samples(log: McapLog, clock: Clock, start: int, n: int, rate: float = 200.0) -> None:
    for i in range(start, start + n):
        ns = int(i * 1e9 / rate)
        log.write(TOPIC_JOINT_STATES, ns, encode_joint_state(
            "json", ns, JOINT_NAMES, np.full(6, 0.1), np.zeros(6), np.ones(6)))
        log.write(TOPIC_ESTIMATE, ns, estimate_record(ns, "psm_base", np.full(6, float(i)), True,
                                                      0.5, 0, False, np.ones(6)))
        clock.now = (i + 1) / rate
        log.tick()


def test_a_killed_writer_loses_at_most_the_flush_interval(tmp_path):
    clock = Clock()
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path), flush_interval_s=1.0), clock=clock)
    write_samples(log, clock, 0, 1000)                  # 5 s, never closed: as after kill -9
    session, info = read_session_report(log.path)
    assert info.truncated
    assert 1000 - 200 <= len(session.joint_states) <= 1000
    log.close()
    session, info = read_session_report(log.path)
    assert not info.truncated and len(session.joint_states) == 1000


def test_rotation_by_duration_keeps_every_sample(tmp_path):
    clock = Clock()
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path), rotate_s=2.0), clock=clock)
    write_samples(log, clock, 0, 1000)
    log.close()
    assert len(log.paths) >= 2
    total = sum(len(read_session_report(p)[0].joint_states) for p in log.paths)
    assert total == 1000


def test_a_full_disk_is_reported_and_logging_resumes(tmp_path):
    clock = Clock()
    full = {"on": True}

    def opener(path, mode):        # the first file lands on a full disk (Linux /dev/full)
        return open("/dev/full" if full["on"] else path, mode)

    log = McapLog("PSM1", LogConfig(directory=str(tmp_path), retry_s=1.0, chunk_size=4096),
                  clock=clock, opener=opener)
    write_samples(log, clock, 0, 400)
    assert log.problem is not None and "No space left" in log.problem
    assert log.lost > 0
    full["on"] = False                                  # space again: a retry opens a new file
    log.problem = None
    write_samples(log, clock, 400, 400)
    log.close()
    assert log.problem is None
    recovered = read_session_report(log.path)[0].joint_states
    assert len(recovered) == 400 and recovered.t[-1] == 799 / 200.0   # all after the retry


def test_a_vanished_directory_is_recreated(tmp_path):
    clock = Clock()
    directory = tmp_path / "logs"
    log = McapLog("PSM1", LogConfig(directory=str(directory), rotate_s=1.0), clock=clock)
    write_samples(log, clock, 0, 100)
    shutil.rmtree(directory)                           # an operator cleans up mid-session
    write_samples(log, clock, 100, 400)                # rotation opens a new file: mkdir again
    log.close()
    assert log.path.exists() and log.path.parent == directory
    assert len(read_session_report(log.path)[0].joint_states) > 0


def _log_session(tmp_path, seconds: float = 4.0):
    """A simulated session logged as the daemon does: JSON joint states as received, an
    estimate per sample (its values from the simulator's truth), events and a status."""
    sim = run_scenario("trocar-contact", seconds, 2)
    js, truth = sim.joint_states, sim.truth
    clock = Clock()
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path)), metadata={"arm": "PSM1"},
                  clock=clock)
    for i in range(len(js)):
        ns = int(round(js.t[i] * 1e9))
        assert log.write(TOPIC_JOINT_STATES, ns, encode_joint_state(
            "json", ns, js.names, js.position[i], js.velocity[i], js.effort[i]))
        assert log.write(TOPIC_ESTIMATE, ns, estimate_record(
            ns, "psm_base", truth.external_wrench[i], not truth.in_contact[i], 0.1 * i, 3,
            i == 0, truth.external_torque[i]))
        if i % 200 == 100:
            assert log.write(TOPIC_EVENTS, ns, orjson.dumps({"t": float(js.t[i]), "kind": "gap",
                                                             "gap_s": 0.02}))
            assert log.write_json(TOPIC_STATUS, ns, {"counters": {"estimated": i + 1}})
        clock.now = js.t[i]
        log.tick()
    log.close()
    return sim, log


def test_the_log_is_a_ros2_bag_that_ros_tools_libraries_decode(tmp_path):
    sim, log = _log_session(tmp_path)
    js, truth = sim.joint_states, sim.truth
    n = len(js)
    path = log.path
    with Reader(path) as bag:                              # rosbags' rosbag2 reader, bare file
        assert {c.topic: (c.msgtype, c.msgcount) for c in bag.connections} == {
            TOPIC_JOINT_STATES: (ros2.JOINT_STATE, n), TOPIC_ESTIMATE: (ros2.ESTIMATE, n),
            TOPIC_EVENTS: (ros2.EVENT, 4), TOPIC_STATUS: (ros2.STATUS, 4)}
    # types built from the file's own definitions only
    with AnyReader([path], default_typestore=get_typestore(Stores.EMPTY)) as bag:
        got: dict[str, list] = {}
        for connection, _, raw in bag.messages():
            got.setdefault(connection.topic, []).append(bag.deserialize(raw, connection.msgtype))
    np.testing.assert_array_equal([m.effort for m in got[TOPIC_JOINT_STATES]], js.effort)
    est = got[TOPIC_ESTIMATE]                              # float32: the values rounded once
    np.testing.assert_array_equal([[*m.force, *m.torque] for m in est],
                                  truth.external_wrench.astype(np.float32))
    np.testing.assert_array_equal([m.external for m in est],
                                  truth.external_torque.astype(np.float32))
    assert not any(hasattr(m, "predicted") for m in est)  # effort - external: not stored
    assert [m.free for m in est] == (~truth.in_contact).tolist()
    assert est[7].score == np.float32(0.1 * 7) and est[7].model_version == 3
    assert est[0].restarted and not est[1].restarted and est[5].header.frame_id == "psm_base"
    assert [m.kind for m in got[TOPIC_EVENTS]] == ["gap"] * 4
    assert orjson.loads(got[TOPIC_EVENTS][1].json)["t"] == js.t[300]
    assert orjson.loads(got[TOPIC_STATUS][2].json) == {"counters": {"estimated": 501}}
    # the mcap library's ROS 2 decoder agrees, and message_fields reads both kinds back
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        decoded = {}
        for schema, channel, message, msg in reader.iter_decoded_messages():
            assert schema.name == TOPIC_TYPES[channel.topic] and schema.encoding == "ros2msg"
            decoded.setdefault(channel.topic, []).append((msg, message, schema))
    msg, message, schema = decoded[TOPIC_ESTIMATE][9]
    assert list(msg.external) == truth.external_torque[9].astype(np.float32).tolist()
    fields = message_fields("cdr", schema.name, message.data, schema.data)
    assert fields["torque"][2] == np.float32(truth.external_wrench[9, 5])
    _, message, schema = decoded[TOPIC_EVENTS][0]
    assert message_fields("cdr", schema.name, message.data) == {"t": js.t[100], "kind": "gap",
                                                                "gap_s": 0.02}


def test_inputs_are_kept_exactly_and_what_is_no_message_is_refused(tmp_path):
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path)))
    q = np.array([0.1, -1 / 3, np.pi, 1e-17, 2.0**-40, -7.123456789012345])
    as_json = encode_joint_state("json", 5, JOINT_NAMES, q, q * 2, q * 3, "base")
    as_cdr = encode_joint_state("cdr", 10, JOINT_NAMES, q, q * 2, q * 3, "base")
    assert log.write(TOPIC_JOINT_STATES, 5, as_json)
    assert log.write(TOPIC_JOINT_STATES, 10, as_cdr)
    assert not log.write(TOPIC_JOINT_STATES, 15, b'{"header": 3}')
    assert not log.write(TOPIC_EVENTS, 15, b"{not json")
    assert not log.write_json(TOPIC_ESTIMATE, 15, {"wrench": {}, "speed": 3})
    assert (log.written, log.lost, log.refused) == (2, 3, 3)
    assert "speed" in log.last_refusal
    log.close()
    with open(log.path, "rb") as f:
        stored = [m.data for _, _, m in make_reader(f).iter_messages()]
    assert stored[1] == as_cdr                              # CDR as handed over
    first = decode_joint_state("cdr", stored[0])
    assert first.stamp_ns == 5 and first.frame_id == "base"
    np.testing.assert_array_equal(first.position, q)       # JSON's shortest floats: exact
    np.testing.assert_array_equal(first.effort, q * 3)


def test_the_ros2_log_is_smaller_than_the_former_logs(tmp_path):
    """Per sample, the same joint states and estimates as today's ROS 2 log (float32
    estimates without the predicted torques), as the ROS 2 log of float64 estimates before it
    and as the former JSON log (JSON joint states as received, orjson estimates)."""
    sim, log = _log_session(tmp_path / "ros2", seconds=10.0)
    n = len(sim.joint_states)
    old_json, old_f64 = tmp_path / "json.mcap", tmp_path / "float64.mcap"
    write_json_daemon_log(old_json, sim, estimates=sim.truth)
    write_float64_daemon_log(old_f64, sim, sim.truth)
    new_bps, f64_bps, json_bps = (p.stat().st_size / n for p in (log.path, old_f64, old_json))
    assert new_bps < 0.85 * f64_bps < 0.85 * json_bps, (new_bps, f64_bps, json_bps)
    assert new_bps < 220, new_bps                        # 195, 245 and 280 B here


def test_the_daemon_logs_an_input_with_six_names_as_received(tmp_path):
    """The ``/joint_states`` record the daemon hands over: a JSON or little-endian CDR input
    with its six names as received, one without names re-encoded with the default names;
    either way the log holds the values exactly."""
    from wrenchd.service.runtime.arm import joint_state_payload

    q = np.array([0.1, -1 / 3, np.pi, 1e-17, 2.0**-40, -7.123456789012345])
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path)))
    sent = [("json", encode_joint_state("json", 5, JOINT_NAMES, q, q, q, "base")),
            ("cdr", encode_joint_state("cdr", 10, JOINT_NAMES, q, q, q, "base")),
            ("cdr", encode_joint_state("cdr", 15, [], q, q, q, "base"))]
    records = []
    for encoding, payload in sent:
        record = joint_state_payload(payload, decode_joint_state(encoding, payload), encoding)
        records.append(record)
        assert log.write(TOPIC_JOINT_STATES, decode_joint_state(encoding, payload).stamp_ns,
                         format_record(record))
    assert records[0] is sent[0][1] and records[1] is sent[1][1]
    assert records[2][0] == "joint_state"                   # no names: made again
    log.close()
    with open(log.path, "rb") as f:
        stored = [decode_joint_state("cdr", m.data) for _, _, m in make_reader(f).iter_messages()]
    assert [m.stamp_ns for m in stored] == [5, 10, 15]
    assert all(m.name == JOINT_NAMES for m in stored)
    for m in stored:
        np.testing.assert_array_equal(m.position, q)
