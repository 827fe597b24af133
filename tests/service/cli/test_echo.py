"""``wrenchd echo`` against a real daemon: three processes and this one on loopback zenoh."""

from __future__ import annotations

import importlib.util
import json
import re
import signal
import subprocess
import sys

from wrenchd.adapters.zenoh_config import ZenohConfig
from wrenchd.adapters.zenoh_io import open_session
from tests.support import communicate_within, expect_line, free_port, stop_within, write_config

CLI = [sys.executable, "-m", "wrenchd"]


def test_echo_prints_live_wrenches_events_and_status(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp_path / "wrenchd.toml", endpoint, "json", tmp_path / "logs")
    daemon = subprocess.Popen([*CLI, "serve", "--config", str(config)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    echo = None
    try:
        expect_line(daemon, "dvrk/PSM2/measured_js", 120.0, "the daemon")
        echo = subprocess.Popen([*CLI, "echo", "--arm", "PSM2", "--connect", endpoint,
                                 "--count", "500", "--every", "1", "--events", "--timeout", "90"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        expect_line(echo, "listening on 'dvrk/PSM2/wrenchd/measured_cf'", 60.0, "wrenchd echo")
        robot = subprocess.run(
            [*CLI, "robot", "--scenario", "trocar", "--seed", "2", "--arm", "PSM2",
             "--duration", "3", "--connect", endpoint, "--out-dir", str(tmp_path / "robot"),
             "--quiet"], capture_output=True, text=True, timeout=120)
        assert robot.returncode == 0, robot.stderr
        out, err = communicate_within(echo, 60.0, "wrenchd echo")
        assert echo.returncode == 0, err
        # wrenchd announce: a set-up change notice the daemon takes (status shows it)
        told = subprocess.run([*CLI, "announce", "--arm", "PSM2", "--connect", endpoint,
                               "--pressure", "18", "--note", "pressure up"],
                              capture_output=True, text=True, timeout=60)
        # stamped on another clock (1000 s; the robot's ran 3 s): the daemon refuses it, and
        # announce says why
        foreign = subprocess.run([*CLI, "announce", "--arm", "PSM2", "--connect", endpoint,
                                  "--at", "1000"], capture_output=True, text=True, timeout=60)
        status = subprocess.run([*CLI, "echo", "--arm", "PSM2", "--connect", endpoint,
                                 "--status", "--timeout", "10"], capture_output=True, text=True,
                                timeout=60)
    finally:
        if echo is not None and echo.poll() is None:
            echo.kill()
        _, daemon_err = stop_within(daemon, 60.0, "the daemon", signal.SIGINT)
    line = re.compile(r"t=\s*[\d.]+ s  F=\[.*\] N  \|F\|=\s*[\d.]+ N  T=\[.*\] N m  "
                      r"(free|contact) v\d+")
    printed = [x for x in out.splitlines() if x.startswith("t=")]
    assert len(printed) == 500 and all(line.match(x) for x in printed), printed[:3]
    stamps = [float(x.split()[0][2:] or x.split()[1]) for x in printed]
    assert stamps == sorted(stamps)
    # the calibration's start (first sample) or end (2 s in, within the 500 wrenches): echo's
    # event subscription reaches the daemon asynchronously and may miss the very first sample
    assert any(x.startswith("event: ") and ('"calibrating"' in x or '"calibrated"' in x)
               for x in out.splitlines())
    assert out.splitlines()[-1] == "wrenchd echo: 500 wrenches"
    assert status.returncode == 0, status.stderr
    answer = json.loads(status.stdout)
    assert answer["counters"]["estimated"] >= 500 and answer["arm"] == "PSM2"
    # an external robot served the shipped simulator-trained step 1: said at start and in status
    model = answer["model"]
    assert model["spec"] == "seal" and model["origin"] == "simulator" and len(model["digest"]) == 64
    assert model["warning"] == "a simulator-trained step 1 serves a real arm"
    assert model["kernels"] == ("numba" if importlib.util.find_spec("numba") else "numpy")
    assert "trained on the simulator" in daemon_err
    assert told.returncode == 0, told.stderr
    assert "sent" in told.stdout and "dvrk/PSM2/setup" in told.stdout
    assert "accepted: the change is at t = " in told.stdout and "carry-over on" in told.stdout
    assert foreign.returncode == 1, foreign.stderr
    assert "refused: set-up change stamped 1000.000 s" in foreign.stdout
    assert "not the robot's clock?" in foreign.stdout
    assert answer["counters"]["setup_changes"] == 1
    assert answer["counters"]["error_kinds"] == {"setup": 1}
    assert answer["setup"]["pressure_mmhg"] == 18.0 and answer["setup"]["note"] == "pressure up"


def test_echo_says_when_no_daemon_answers():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    status = subprocess.run([*CLI, "echo", "--connect", endpoint, "--status", "--timeout", "1"],
                            capture_output=True, text=True, timeout=60)
    assert status.returncode == 1
    assert "no answer from 'dvrk/PSM1/wrenchd/status' within 1 s" in status.stdout
    quiet = subprocess.run([*CLI, "echo", "--connect", endpoint, "--timeout", "1"],
                           capture_output=True, text=True, timeout=60)
    assert quiet.returncode == 1 and "wrenchd echo: 0 wrenches" in quiet.stdout


def test_announce_says_when_no_daemon_listens_and_refuses_bad_values():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    told = subprocess.run([*CLI, "announce", "--connect", endpoint, "--timeout", "1"],
                          capture_output=True, text=True, timeout=60)
    assert told.returncode == 1
    assert "no daemon subscribed to 'dvrk/PSM1/setup'" in told.stdout
    bad = subprocess.run([*CLI, "announce", "--pressure", "250"], capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode != 0 and "--pressure must be in [0, 100]" in bad.stderr + bad.stdout


def test_announce_falls_back_on_the_status_when_no_event_comes_back(tmp_path):
    """A daemon whose events go elsewhere (its own [arms.keys]): announce learns from the
    status counters whether the notice was taken (a stamped one) or refused (an unstamped one
    before the arm's first sample: the daemon cannot place it)."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp_path / "wrenchd.toml", endpoint, "json", tmp_path / "logs")
    config.write_text(config.read_text() + '[arms.keys]\nevents = "elsewhere/events"\n')
    daemon = subprocess.Popen([*CLI, "serve", "--config", str(config)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        expect_line(daemon, "dvrk/PSM2/measured_js", 120.0, "the daemon")
        runs = [subprocess.run([*CLI, "announce", "--arm", "PSM2", "--connect", endpoint,
                                "--timeout", "2", *at], capture_output=True, text=True,
                               timeout=60) for at in (["--at", "0.5"], [])]
    finally:
        _, err = stop_within(daemon, 60.0, "the daemon", signal.SIGINT)
    assert daemon.returncode == 0, err
    taken, refused = runs
    assert taken.returncode == 0, taken.stdout + taken.stderr
    assert "accepted (the daemon's status counts it" in taken.stdout
    assert refused.returncode == 1, refused.stdout + refused.stderr
    assert "refused (the daemon's status counts a set-up error" in refused.stdout


def test_echo_joins_through_a_zenoh_config_file_and_names_a_bad_one(tmp_path):
    """The file's connect endpoint reaches the echo process (no --connect): it finds this
    process's status queryable there; a bad file is refused by name, with no traceback."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    zfile = tmp_path / "echo.json5"
    zfile.write_text(f'{{ mode: "client", connect: {{ endpoints: ["{endpoint}"] }} }}')

    def answer(query) -> None:
        query.reply(query.key_expr, json.dumps({"arm": "PSM1", "served": "by the test"}))

    session = open_session(ZenohConfig(listen=[endpoint]))
    try:
        queryable = session.declare_queryable("dvrk/PSM1/wrenchd/status", answer)
        try:
            status = subprocess.run([*CLI, "echo", "--zenoh-config", str(zfile), "--status",
                                     "--timeout", "10"], capture_output=True, text=True,
                                    timeout=60)
        finally:
            queryable.undeclare()
    finally:
        session.close()
    assert status.returncode == 0, status.stderr
    assert json.loads(status.stdout) == {"arm": "PSM1", "served": "by the test"}

    zfile.write_text('{ mode: "client", conect: {} }')
    for verb in (["echo", "--status"], ["announce"]):
        bad = subprocess.run([*CLI, *verb, "--zenoh-config", str(zfile)], capture_output=True,
                             text=True, timeout=60)
        assert bad.returncode == 2, bad.stderr
        assert f"config_file '{zfile}': refused by zenoh: unknown field `conect`" in bad.stderr
        assert "Traceback" not in bad.stderr
