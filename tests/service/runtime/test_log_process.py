"""The log writer process: records reach the MCAP files, the daemon's view follows, the files
are finished when the daemon dies, and a writer that dies is replaced."""

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from mcap.reader import make_reader

from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, LogConfig, McapLog, estimate_record
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.messages import decode_joint_state, encode_joint_state
from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.runtime.log_process import LogWriterProcess

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def put_samples(writer: LogWriterProcess, log: McapLog, start: int, n: int) -> None:
    for i in range(start, start + n):
        ns = int(i * 5e6)
        q = [0.1 * i] * 6
        writer.put(log, TOPIC_JOINT_STATES, ns,
                   ("joint_state", (ns, list(JOINT_NAMES), q, [0.0] * 6, [1.0] * 6, "base")))
        writer.put(log, TOPIC_ESTIMATE, ns,
                   ("estimate", (ns, "psm_base", [float(i)] * 6, True, 0.5, 3, False,
                                 [1.0] * 6)))


def messages(path):
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.data)
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]


def wait_for(predicate, timeout_s: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.05)
    return predicate()


def test_records_are_formatted_and_written_by_the_process(tmp_path):
    logs = [McapLog(arm, LogConfig(directory=str(tmp_path / arm)), metadata={"arm": arm})
            for arm in ("PSM1", "PSM2")]
    writer = LogWriterProcess(logs)
    try:
        assert writer.process.pid != os.getpid() and writer.process.is_alive()
        put_samples(writer, logs[0], 0, 300)
        put_samples(writer, logs[1], 0, 100)
        writer.put(logs[1], TOPIC_ESTIMATE, 1, ("estimate", ("not a stamp",)))  # cannot be made
        assert wait_for(lambda: logs[0].written == 600)        # the daemon's view follows
        assert logs[0].path is not None and logs[0].path.exists()
    finally:
        writer.close()
    assert not writer.process.is_alive()
    assert (logs[0].written, logs[0].lost, logs[1].written, logs[1].lost) == (600, 0, 200, 1)
    assert writer.errors == 1
    session, info = read_session_report(logs[0].path)           # finished: not truncated
    assert not info.truncated and len(session.joint_states) == 300
    np.testing.assert_allclose(session.joint_states.position[7], [0.7] * 6)
    est = [d for topic, _, d in messages(logs[0].path) if topic == TOPIC_ESTIMATE]
    assert est[5] == estimate_record(int(5 * 5e6), "psm_base", [5.0] * 6, True, 0.5, 3, False,
                                     np.ones(6))
    js = [d for topic, _, d in messages(logs[1].path) if topic == TOPIC_JOINT_STATES]
    assert js[2] == encode_joint_state("cdr", int(2 * 5e6), JOINT_NAMES, [0.2] * 6,
                                       np.zeros(6), np.ones(6), "base")


def test_the_files_are_finished_when_the_daemon_is_killed(tmp_path):
    """kill -9 of the process that owns the writer: the writer sees its pipe end, writes what
    it was handed and finishes the file (summary and footer)."""
    script = textwrap.dedent(f"""
        import os, signal, sys, time
        sys.path.insert(0, {ROOT!r})
        sys.path.insert(0, {os.path.dirname(os.path.abspath(__file__))!r})
        from wrenchd.adapters.mcap_log import LogConfig, McapLog
        from wrenchd.service.runtime.log_process import LogWriterProcess
        from test_log_process import put_samples
        log = McapLog("PSM1", LogConfig(directory={str(tmp_path)!r}))
        writer = LogWriterProcess([log])
        put_samples(writer, log, 0, 400)
        while log.written < 800:
            time.sleep(0.02)
        print(writer.process.pid, flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    child = int(proc.stdout.split()[0])
    assert wait_for(lambda: not os.path.exists(f"/proc/{child}") or
                    open(f"/proc/{child}/stat").read().split()[2] == "Z")
    paths = sorted(tmp_path.glob("PSM1-*.mcap"))
    assert len(paths) == 1
    session, info = read_session_report(paths[0])
    assert not info.truncated and len(session.joint_states) == 400


def test_a_dead_writer_is_reported_and_replaced(tmp_path):
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path), retry_s=0.5))
    writer = LogWriterProcess([log])
    try:
        put_samples(writer, log, 0, 100)
        assert wait_for(lambda: log.written == 200)
        first = writer.process
        os.kill(first.pid, signal.SIGKILL)
        assert wait_for(lambda: log.problem is not None)
        assert "log writer process stopped" in log.problem
        put_samples(writer, log, 100, 50)                     # while no writer: lost, counted
        assert wait_for(lambda: writer.restarts == 1 and writer.process is not first)
        put_samples(writer, log, 150, 100)
        assert wait_for(lambda: log.written >= 400 and log.problem is None)
    finally:
        writer.close()
    assert len(log.paths) == 2                                 # the new writer's new file
    second, info = read_session_report(log.paths[1])
    assert not info.truncated
    assert second.joint_states.position[-1, 0] == 0.1 * 249
    assert log.written + log.lost >= 500 and log.lost >= 1
    assert decode_joint_state("cdr", messages(log.paths[1])[0][2]).frame_id == "base"


def test_the_writer_keeps_the_disk_budget_and_tells_the_daemon(tmp_path):
    budget = 60_000
    log = McapLog("PSM1", LogConfig(directory=str(tmp_path), rotate_mb=0.02, chunk_size=4096,
                                    max_total_bytes=budget, budget_check_s=0.2))
    writer = LogWriterProcess([log])
    rng = np.random.default_rng(0)
    try:
        for i in range(3000):           # noise: hardly compressed; handed over a few at a time
            if i % 50 == 49:            # (the writer rotates between the batches it receives)
                time.sleep(0.02)
            ns = int(i * 5e6)
            writer.put(log, TOPIC_JOINT_STATES, ns, ("joint_state", (
                ns, list(JOINT_NAMES), *rng.normal(size=(3, 6)).tolist(), "base")))
            writer.put(log, TOPIC_ESTIMATE, ns, ("estimate", (
                ns, "psm_base", rng.normal(size=6).tolist(), True, 0.5, 3, False,
                rng.normal(size=6).tolist())))
        assert wait_for(lambda: log.written == 6000 and log.removed_files >= 3)
        assert wait_for(lambda: log.bytes_free is not None)
        assert 0 < log.bytes_used <= budget + 20_000 + 8192    # + the open file's growth
        assert 0 < log.bytes_free == pytest.approx(shutil.disk_usage(tmp_path).free, rel=0.1)
    finally:
        writer.close()
    notices = list(log.removed)                    # for the daemon to publish (ArmRuntime)
    assert len(notices) == log.removed_files and notices[0][1] == str(log.paths[0])
    assert sum(n[2] for n in notices) == log.removed_bytes
    for what, path, size in notices:
        assert what == "removed" and not os.path.exists(path) and size > 0
    assert log.paths[-1].exists()                  # never the open file
    assert sum(p.stat().st_size for p in tmp_path.glob("PSM1-*.mcap")) <= budget + 28_192
