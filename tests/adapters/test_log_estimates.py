"""The logged estimates read back from every layout wrenchd has written: today's float32 one
(predicted torques rebuilt from the logged effort), the float64 ROS 2 one and the JSON one
(predicted torques as stored); the files stay bags that the MCAP library's ROS 2 decoder and
rosbags read from their own definitions."""

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from tests.adapters.float64_log import DEFINITION_FLOAT64, write_float64_daemon_log
from tests.adapters.json_mcap import write_json_daemon_log
from tests.adapters.test_mcap_log import _log_session
from wrenchd.adapters.log_estimates import read_logged_estimates
from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE
from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.errors import AdapterError


@pytest.fixture(scope="module")
def sim():
    return run_scenario("trocar-contact", 3.0, 2)


def _check_fields(est, truth, wrench, external):
    n = len(truth.in_contact)
    assert len(est) == n
    np.testing.assert_array_equal(est.wrench, wrench)
    np.testing.assert_array_equal(est.external, external)
    assert est.free.tolist() == (~truth.in_contact).tolist()
    assert est.model_version.tolist() == [3] * n
    assert est.restarted.tolist() == [True] + [False] * (n - 1)


def test_todays_log_rebuilds_predicted_from_the_logged_effort(tmp_path):
    sim, log = _log_session(tmp_path, seconds=3.0)
    js, truth = sim.joint_states, sim.truth
    est = read_logged_estimates(log.path)
    f32 = np.float32
    _check_fields(est, truth, truth.external_wrench.astype(f32),
                  truth.external_torque.astype(f32))
    np.testing.assert_array_equal(est.stamp_ns, np.rint(js.t * 1e9).astype(np.int64))
    np.testing.assert_array_equal(est.score, (0.1 * np.arange(len(js))).astype(f32))
    assert not est.predicted_stored
    np.testing.assert_array_equal(est.predicted, js.effort - truth.external_torque.astype(f32))
    # within float32's rounding of the external torque of what the estimator predicted
    # (here the simulator's measured effort minus its true external torque)
    bound = np.abs(truth.external_torque) * 2.0**-24 + 1e-30
    assert (np.abs(est.predicted - (js.effort - truth.external_torque)) <= bound).all()


def test_a_float64_log_reads_with_its_stored_predicted_torques(tmp_path, sim):
    path = tmp_path / "float64.mcap"
    write_float64_daemon_log(path, sim, sim.truth)
    truth = sim.truth
    est = read_logged_estimates(path)
    _check_fields(est, truth, truth.external_wrench, truth.external_torque)
    assert est.predicted_stored
    np.testing.assert_array_equal(est.predicted, truth.internal_torque)     # exact, float64
    np.testing.assert_array_equal(est.score, 0.1 * np.arange(len(est)))
    # still a session: its joint states read exactly
    session, info = read_session_report(path)
    assert not info.truncated and session.truth is None
    np.testing.assert_array_equal(session.joint_states.effort, sim.joint_states.effort)


def test_a_json_log_reads_with_its_stored_predicted_torques(tmp_path, sim):
    path = tmp_path / "json.mcap"
    write_json_daemon_log(path, sim, estimates=sim.truth)
    est = read_logged_estimates(path)
    _check_fields(est, sim.truth, sim.truth.external_wrench, sim.truth.external_torque)
    assert est.predicted_stored
    np.testing.assert_array_equal(est.predicted, sim.truth.internal_torque)


def test_old_and_new_logs_stay_bags_that_decoders_read_from_their_own_definitions(tmp_path,
                                                                                    sim):
    old = tmp_path / "float64.mcap"
    write_float64_daemon_log(old, sim, sim.truth)
    _, log = _log_session(tmp_path / "new", seconds=3.0)
    for path, fields in ((old, {"wrench", "predicted", "external"}),
                         (log.path, {"force", "torque", "external"})):
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            decoded = [(schema, msg) for schema, channel, _, msg in
                       reader.iter_decoded_messages(topics=[TOPIC_ESTIMATE])]
        assert len(decoded) == len(sim.joint_states)
        schema, msg = decoded[5]
        assert fields <= set(msg.__slots__)
        assert (schema.data.decode() == DEFINITION_FLOAT64) == (path == old)
        with AnyReader([path], default_typestore=get_typestore(Stores.EMPTY)) as bag:
            msgs = [bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages()
                    if c.topic == TOPIC_ESTIMATE]
        np.testing.assert_array_equal([m.external for m in msgs],
                                      read_logged_estimates(path).external)


def test_a_cut_log_reads_to_where_it_stops_and_a_non_mcap_file_is_refused(tmp_path):
    _, log = _log_session(tmp_path, seconds=4.0)
    data = log.path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[:len(data) // 2])                 # a writer killed mid-file
    est = read_logged_estimates(cut)
    whole = read_logged_estimates(log.path)
    assert 0 < len(est) < len(whole)
    np.testing.assert_array_equal(est.predicted, whole.predicted[:len(est)])
    (tmp_path / "not.mcap").write_bytes(b"hello, this is no MCAP file at all")
    with pytest.raises(AdapterError, match="not an MCAP file"):
        read_logged_estimates(tmp_path / "not.mcap")
    with pytest.raises(AdapterError, match="cannot open"):
        read_logged_estimates(tmp_path / "missing.mcap")
