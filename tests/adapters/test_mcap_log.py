"""The daemon's MCAP log: flushed each second, readable after a crash, rotated, never fatal."""

import shutil

import numpy as np

from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, LogConfig, McapLog
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.messages import encode_joint_state
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
        log.write_json(TOPIC_ESTIMATE, ns, {"i": i})
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
