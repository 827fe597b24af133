"""CPU placement: the daemon's threads and its adaptation worker run where ``[cpus]`` says."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.service.runtime.settings import load_settings
from tests.support import children_of, expect_line, free_port, stop_within, wait_for


def _allowed(pid: int, tid: int | None = None) -> str:
    path = f"/proc/{pid}/task/{tid}/status" if tid else f"/proc/{pid}/status"
    for line in Path(path).read_text().splitlines():
        if line.startswith("Cpus_allowed_list:"):
            return line.split(":", 1)[1].strip()
    raise AssertionError("no Cpus_allowed_list")


def test_a_cpu_that_does_not_exist_is_refused_by_name():
    with pytest.raises(ConfigError, match="cpus.daemon.*do not exist"):
        load_settings(cpus={"daemon": [os.cpu_count() + 3]})
    with pytest.raises(ConfigError, match="cpus.worker"):
        load_settings(cpus={"worker": []})


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPUs")
def test_the_daemon_and_its_worker_run_on_their_cpus(tmp_path):
    daemon_cpu, worker_cpu = sorted(os.sched_getaffinity(0))[-1], sorted(os.sched_getaffinity(0))[0]
    config = tmp_path / "wrenchd.toml"
    config.write_text(f"""
robot = "external"
[cpus]
daemon = [{daemon_cpu}]
worker = [{worker_cpu}]
[zenoh]
listen = ["tcp/127.0.0.1:{free_port()}"]
[log]
directory = "{tmp_path / 'logs'}"
""")
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    try:
        expect_line(daemon, "listening", 120.0, "the daemon")
        wait_for(lambda: children_of(daemon.pid), 20.0, "the adaptation worker")
        threads = [int(t) for t in os.listdir(f"/proc/{daemon.pid}/task")]
        assert len(threads) > 3                         # estimation, log, zenoh's own threads
        assert {_allowed(daemon.pid, t) for t in threads} == {str(daemon_cpu)}
        # the worker (spawned: it imports torch first) sets its own when it starts
        wait_for(lambda: str(worker_cpu) in {_allowed(c) for c in children_of(daemon.pid)},
                 30.0, "the worker on its CPU")
    finally:
        _, err = stop_within(daemon, 60.0, "the daemon", signal.SIGINT)
    assert daemon.returncode == 0, err
