"""Real-time scheduling (``[cpus] realtime_priority``): the threads a sample passes through run
under SCHED_FIFO, the log writer and the console one step below, the adaptation worker in the
normal class; a process that may not use it is told so by name before anything starts."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.service.runtime.settings import AUTO_REALTIME_PRIORITY, load_settings
from tests.support import children_of, expect_line, free_port, stop_within, wait_for

ROOT = Path(__file__).resolve().parents[3]
PRIORITY = 7


def _policy(pid: int, tid: int) -> tuple[str, int, int]:
    """(thread name, scheduling policy, real-time priority) from /proc."""
    stat = Path(f"/proc/{pid}/task/{tid}/stat").read_text()
    name = stat[stat.index("(") + 1:stat.rindex(")")]
    fields = stat[stat.rindex(")") + 2:].split()
    return name, int(fields[38]), int(fields[37])       # policy (41st), rt_priority (40th)


def _config(tmp_path: Path, priority: int | None = PRIORITY, adaptation: bool = True) -> Path:
    config = tmp_path / "wrenchd.toml"
    setting = f"[cpus]\nrealtime_priority = {priority}" if priority is not None else ""
    config.write_text(f"""
robot = "external"
{setting}
[zenoh]
listen = ["tcp/127.0.0.1:{free_port()}"]
[log]
directory = "{tmp_path / 'logs'}"
[[arms]]
name = "PSM1"
[arms.pipeline.adaptation]
enabled = {str(adaptation).lower()}
""")
    return config


def _may_use_realtime() -> bool:
    probe = subprocess.run([sys.executable, "-c", "import os; os.sched_setscheduler("
                            "0, os.SCHED_FIFO, os.sched_param(1))"], capture_output=True,
                           timeout=60)
    return probe.returncode == 0


def test_the_priority_is_checked():
    with pytest.raises(ConfigError, match="realtime_priority"):
        load_settings(cpus={"realtime_priority": 100})
    with pytest.raises(ConfigError, match="realtime_priority"):
        load_settings(cpus={"realtime_priority": "sometimes"})
    assert load_settings().cpus.realtime_priority == "auto"
    assert load_settings(cpus={"realtime_priority": "off"}).cpus.realtime_priority == "off"


def _threads(pid: int) -> dict[int, tuple[str, int, int]]:
    return {tid: _policy(pid, tid) for tid in map(int, os.listdir(f"/proc/{pid}/task"))}


@pytest.mark.skipif(not _may_use_realtime(), reason="this machine gives no real-time class")
def test_by_default_the_sample_path_is_real_time_where_permitted(tmp_path):
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(_config(tmp_path, None))], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        expect_line(daemon, "listening", 120.0, "the daemon")
        threads = _threads(daemon.pid)
        assert any(policy == os.SCHED_FIFO and prio == AUTO_REALTIME_PRIORITY
                   for _, policy, prio in threads.values()), threads
    finally:
        stop_within(daemon, 60.0, "the daemon", signal.SIGINT)


@pytest.mark.skipif(not _may_use_realtime(), reason="this machine gives no real-time class")
def test_a_samples_threads_are_real_time_and_the_rest_is_not(tmp_path):
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(_config(tmp_path))], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        expect_line(daemon, "listening", 120.0, "the daemon")
        wait_for(lambda: children_of(daemon.pid), 20.0, "the adaptation worker")
        children = children_of(daemon.pid)
        threads = _threads(daemon.pid)
        fifo = {tid for tid, (_, policy, prio) in threads.items()
                if policy == os.SCHED_FIFO and prio == PRIORITY}
        below = {tid for tid, (_, policy, prio) in threads.items()
                 if policy == os.SCHED_FIFO and prio == PRIORITY - 1}
        normal = {tid for tid, (_, policy, _) in threads.items() if policy == os.SCHED_OTHER}
        assert fifo | below | normal == set(threads), threads
        # zenoh's runtime threads (its link threads, rx-/tx-, are made by them later)
        assert any(threads[t][0].startswith(("net-", "acc-", "rx-", "tx-")) for t in fifo), threads
        assert not any(threads[t][0].startswith(("net-", "acc-")) for t in normal), threads
        python_fifo = [t for t in fifo if threads[t][0].startswith("python")]
        assert len(python_fifo) >= 2, threads        # estimation, zenoh's callback thread
        # the log writer, the console and the main thread (once it has started the robots)
        assert len(below) == 3 and daemon.pid in below, threads
        for child in children:                      # the adaptation worker
            assert all(_policy(child, int(t))[1] == os.SCHED_OTHER
                       for t in os.listdir(f"/proc/{child}/task"))
    finally:
        _, err = stop_within(daemon, 60.0, "the daemon", signal.SIGINT)
    assert daemon.returncode == 0, err


@pytest.mark.skipif(os.geteuid() != 0 or not Path("/usr/bin/setpriv").exists(),
                    reason="needs root and setpriv to run the daemon without privileges")
def test_a_daemon_that_may_not_is_refused_with_what_to_do_or_by_default_runs_normally():
    unprivileged = ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups",
                    "--inh-caps=-all", sys.executable, "-m", "wrenchd", "serve", "--config"]
    # pytest's own temporary directories are root's alone
    with tempfile.TemporaryDirectory() as tmp:
        Path(tmp).chmod(0o777)
        # no adaptation worker: as user nobody here, multiprocessing's resource tracker (which
        # its queues start) died at random, a fault of this set-up, not of scheduling
        config = _config(Path(tmp), adaptation=False)
        config.chmod(0o644)
        run = subprocess.run([*unprivileged, str(config)], capture_output=True, text=True,
                             cwd=ROOT, env={**os.environ, "HOME": tmp}, timeout=120)
        default = Path(tmp) / "default"
        default.mkdir(mode=0o777)
        config = _config(default, None, adaptation=False)
        config.chmod(0o644)
        daemon = subprocess.Popen([*unprivileged, str(config)], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                  env={**os.environ, "HOME": tmp})
        try:
            expect_line(daemon, "listening", 120.0, "the unprivileged daemon")
            assert {p for _, p, _ in _threads(daemon.pid).values()} == {os.SCHED_OTHER}
        finally:
            _, err = stop_within(daemon, 60.0, "the unprivileged daemon", signal.SIGINT)
        assert daemon.returncode == 0, err
        assert "real-time scheduling is not permitted here" in err, err
    assert run.returncode != 0
    assert "realtime_priority = 7" in run.stderr and "CAP_SYS_NICE" in run.stderr, run.stderr
    assert "listening" not in run.stdout
