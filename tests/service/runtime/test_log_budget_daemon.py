"""The daemon's log on a disk budget, end to end (``wrenchd serve`` with its simulated PSM,
a real zenoh session on loopback): the files stay within the budget, each file removed is a
``log_removed`` event, the status says what the directory holds and what the disk has free;
and a log directory that cannot be written is a ``log_error`` event while estimation goes on."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.support import (communicate_within, expect_line, free_port, stop_within,
                           wait_for, write_config)
from wrenchd.adapters.log_budget import LOG_FILE_NAME
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session

BUDGET = 150_000


def _serve(tmp_path, log_text: str, duration_s: float):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = tmp_path / "wrenchd.toml"
    config.write_text(f'robot = "simulated"\n[zenoh]\nlisten = ["{endpoint}"]\n'
                      f"[log]\n{log_text}")
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config), "--duration", str(duration_s)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    return daemon, endpoint


def _watch(daemon, endpoint, until, what: str) -> tuple[list[dict], dict]:
    """The events the daemon publishes until ``until(events)``, then its status."""
    events: list[dict] = []
    session = None
    try:
        expect_line(daemon, "listening", 120.0, "the daemon")
        session = open_session(ZenohConfig(connect=[endpoint]))
        sub = session.declare_subscriber("dvrk/PSM1/wrenchd/events", lambda s: events.append(
            json.loads(s.payload.to_bytes())))
        wait_for(lambda: until(events), 60.0, what)
        replies = list(session.get("dvrk/PSM1/wrenchd/status", timeout=5.0))
        status = json.loads(replies[0].ok.payload.to_bytes())
        sub.undeclare()
    except BaseException:
        stop_within(daemon, 60.0, "the daemon")
        raise
    finally:
        if session is not None:
            session.close()
    return events, status


def test_the_log_stays_within_its_budget_and_says_what_it_removed(tmp_path):
    logs = tmp_path / "logs"
    daemon, endpoint = _serve(tmp_path, f'directory = "{logs}"\nrotate_mb = 0.05\n'
                                        f"max_total_bytes = {BUDGET}\nbudget_check_s = 0.5\n",
                              duration_s=30)
    events, status = _watch(daemon, endpoint,
                            lambda ev: sum(e["kind"] == "log_removed" for e in ev) >= 3,
                            "three log_removed events")
    out, err = stop_within(daemon, 60.0, "the daemon")
    assert daemon.returncode == 0, err[-3000:]
    removed = [e for e in events if e["kind"] == "log_removed"]
    for e in removed:
        assert e["arm"] == "PSM1" and e["bytes"] > 0 and LOG_FILE_NAME.match(
            e["path"].rsplit("/", 1)[1])
        assert e["path"].startswith(str(logs)) and not (logs / e["path"]).exists()
    log = status["log"]
    assert log["max_total_bytes"] == BUDGET and log["directory"] == str(logs)
    assert log["removed_files"] >= len(removed) >= 3
    assert log["removed_bytes"] >= sum(e["bytes"] for e in removed)
    assert 0 < log["bytes_used"] <= BUDGET + 50_000 + 8192     # + the open file's growth
    assert log["bytes_free"] > 0 and log["problem"] is None
    assert status["counters"]["estimated"] > 0
    files = [p for p in logs.iterdir() if LOG_FILE_NAME.match(p.name)]
    assert sum(p.stat().st_size for p in files) <= BUDGET + 50_000 + 8192
    last = out.strip().splitlines()[-1]            # "... stopped: ...; log PATH, ..., PATH"
    assert "PSM1 stopped" in last
    assert (logs / last.rsplit("log ", 1)[1].split(", ")[-1]).exists()   # the open one stays
    assert (logs / "robot").is_dir() and any((logs / "robot").iterdir())   # not a log: kept


def test_a_log_directory_that_cannot_be_written_is_a_log_error_and_estimation_goes_on(
        tmp_path):
    (tmp_path / "a-file").write_text("not a directory")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp_path / "wrenchd.toml", endpoint, "json",
                          tmp_path / "a-file" / "logs", arms=("PSM1",))
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    events: list[dict] = []
    session = robot = None
    try:
        expect_line(daemon, "listening", 120.0, "the daemon")
        session = open_session(ZenohConfig(connect=[endpoint]))
        sub = session.declare_subscriber("dvrk/PSM1/wrenchd/events", lambda s: events.append(
            json.loads(s.payload.to_bytes())))
        robot = subprocess.Popen(
            [sys.executable, "-m", "wrenchd", "robot", "--scenario", "trocar", "--seed", "2",
             "--arm", "PSM1", "--duration", "3", "--connect", endpoint,
             "--out-dir", str(tmp_path / "robot"), "--quiet"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        out, err = communicate_within(robot, 120.0, "the robot")
        assert robot.returncode == 0, err
        published = int(out.strip().splitlines()[-1].split("after ")[1].split()[0])

        def status():
            return json.loads(list(session.get("dvrk/PSM1/wrenchd/status", timeout=5.0)
                                   )[0].ok.payload.to_bytes())

        wait_for(lambda: status()["counters"]["estimated"] == published, 20.0,
                 "every sample estimated")
        wait_for(lambda: any(e["kind"] == "log_error" for e in events), 20.0, "a log_error")
        last = status()
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        if robot is not None and robot.poll() is None:
            robot.kill()
        _, d_err = stop_within(daemon, 60.0, "the daemon")
    assert daemon.returncode == 0, d_err[-3000:]
    error = next(e for e in events if e["kind"] == "log_error")
    assert error["arm"] == "PSM1" and "cannot open a log file" in error["error"]
    assert [e["kind"] for e in events].count("log_error") == 1      # said once, not per sample
    log = last["log"]
    assert log["problem"] and log["written"] == 0 and log["lost"] >= 2 * published
    assert log["bytes_used"] == 0 and log["bytes_free"] is None      # no directory to measure
