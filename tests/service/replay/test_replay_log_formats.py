"""Replay reads daemon logs of every format: the ROS 2 log that McapLog writes today, the
ROS 2 log of float64 estimates before it and the former JSON log (written here in their
layouts), with their set-up change events, also from a log its daemon never finished; and
writes its own output as a ROS 2 bag."""

from __future__ import annotations

import numpy as np
import orjson
import pytest
import torch
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from tests.adapters.float64_log import write_float64_daemon_log
from tests.adapters.json_mcap import write_json_daemon_log
from wrenchd.adapters.mcap_log import TOPIC_EVENTS, TOPIC_JOINT_STATES, LogConfig, McapLog
from wrenchd.adapters.messages import encode_joint_state
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.service.pipeline import PipelineConfig
from wrenchd.service.replay.loop import replay
from wrenchd.service.replay.output import write_replay_mcap
from wrenchd.service.replay.policies import get_policy
from wrenchd.service.replay.source import announced_changes, load_session, stamps_ns

CONFIG = PipelineConfig(calibration_s=2.0)
CHANGE_T = 2.5
EVENT = {"t": CHANGE_T, "kind": "setup_change", "arm": "PSM1", "pressure_mmhg": 15.0,
         "carry_over": True}


@pytest.fixture(scope="module")
def fs():
    torch.set_num_threads(1)
    return load_pretrained("seal")


def _ros2_log(directory, session, finish: bool = True) -> str:
    """The daemon's log of ``session``: JSON inputs as received, the set-up change event;
    ``finish=False``: flushed but never finished, as its daemon killed."""
    clock = [0.0]
    log = McapLog("PSM1", LogConfig(directory=str(directory)), clock=lambda: clock[0])
    js = session.joint_states
    for i in range(len(js)):
        ns = int(round(js.t[i] * 1e9))
        if ns == int(CHANGE_T * 1e9):
            log.write(TOPIC_EVENTS, ns, orjson.dumps(EVENT))
        log.write(TOPIC_JOINT_STATES, ns, encode_joint_state(
            "json", ns, js.names, js.position[i], js.velocity[i], js.effort[i]))
        clock[0] = js.t[i]
        log.tick()
    if finish:
        log.close()
    else:
        log.flush()
    return str(log.path)


def test_a_ros2_log_and_a_former_json_log_replay_alike(tmp_path, fs):
    src = load_session("sim:trocar:5:3")
    new = _ros2_log(tmp_path / "new", src)
    old = tmp_path / "old.mcap"
    write_json_daemon_log(old, src, events=[(int(CHANGE_T * 1e9), EVENT)])
    sessions = {name: load_session(str(path)) for name, path in (("new", new), ("old", old))}
    detail = {k: v for k, v in EVENT.items() if k not in ("t", "kind")}
    for name, session in sessions.items():
        assert session.truth is None, name
        np.testing.assert_array_equal(stamps_ns(session.joint_states), stamps_ns(src.joint_states))
        # both keep the inputs exactly (JSON with shortest floats, CDR float64)
        np.testing.assert_array_equal(session.joint_states.effort, src.joint_states.effort)
        assert announced_changes(session) == [(CHANGE_T, detail)], name
    frozen = get_policy("frozen").configure(CONFIG)
    r_new, r_old = (replay(sessions[k], fs, frozen) for k in ("new", "old"))
    assert len(r_new.t) == len(src.joint_states)
    np.testing.assert_array_equal(r_new.wrench, r_old.wrench)
    # the replay's own output: a ROS 2 bag of estimates and events
    out = tmp_path / "replay.mcap"
    write_replay_mcap(out, r_new)
    with AnyReader([out], default_typestore=get_typestore(Stores.EMPTY)) as bag:
        topics = {c.topic: c.msgtype for c in bag.connections}
        estimates = [bag.deserialize(raw, c.msgtype) for c, _, raw in bag.messages()
                     if c.topic == "/wrenchd/estimate"]
    assert topics == {"/wrenchd/estimate": "wrenchd_msgs/msg/Estimate",
                      "/wrenchd/events": "wrenchd_msgs/msg/Event"}
    np.testing.assert_array_equal([e.force for e in estimates],
                                  r_new.wrench[:, :3].astype(np.float32))


def test_a_log_of_float64_estimates_replays_as_todays(tmp_path, fs):
    src = load_session("sim:trocar:3:3")
    new = load_session(_ros2_log(tmp_path / "new", src))
    old_path = tmp_path / "float64.mcap"
    write_float64_daemon_log(old_path, src, src.truth)
    old = load_session(str(old_path))
    np.testing.assert_array_equal(old.joint_states.effort, src.joint_states.effort)
    frozen = get_policy("frozen").configure(CONFIG)
    r_new, r_old = replay(new, fs, frozen), replay(old, fs, frozen)
    assert len(r_old.t) == len(src.joint_states)
    np.testing.assert_array_equal(r_old.wrench, r_new.wrench)


def test_a_log_its_daemon_never_finished_still_announces_its_setup_changes(tmp_path):
    src = load_session("sim:trocar:4:3")
    path = _ros2_log(tmp_path, src, finish=False)
    session = load_session(path)
    assert 0 < len(session.joint_states) <= len(src.joint_states)
    detail = {k: v for k, v in EVENT.items() if k not in ("t", "kind")}
    assert announced_changes(session) == [(CHANGE_T, detail)]
