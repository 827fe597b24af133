"""deploy/zenoh/psm1-router.toml: the PSM1 daemon is the bedside router, its zenoh settings
router.json5 passed through [zenoh] config_file; deploy/zenoh/viewer.json5: a consumer's zenoh
file for `wrenchd echo --zenoh-config`. Run from the examples themselves (paths moved to a
throw-away CA and a loopback port): the daemon's session is a TLS router whose access control
admits the robot's joint states and serves the daemon's wrenches and status to consumers
only."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

from wrenchd.adapters.messages import encode_wrench
from wrenchd.adapters.zenoh_io import open_session
from wrenchd.service.runtime.settings import load_settings
from tests.deploy.test_router_acl import EC_KEY, client, openssl
from tests.support import free_port

ZENOH = Path(__file__).resolve().parents[2] / "deploy" / "zenoh"
SETTINGS = ZENOH / "psm1-router.toml"
CNS = ("or-router-1", "dvrk-psm1", "viewer", "intruder")


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A CA and one certificate per CN (SAN 127.0.0.1 and localhost), PEM files."""
    d = tmp_path_factory.mktemp("pki-embedded")
    openssl("req", "-x509", *EC_KEY, "-days", "2", "-subj", "/CN=or-ca",
            "-keyout", "ca-key.pem", "-out", "ca.pem", cwd=d)
    (d / "san.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    for cn in CNS:
        openssl("req", *EC_KEY, "-subj", f"/CN={cn}", "-keyout", f"{cn}-key.pem",
                "-out", f"{cn}.csr", cwd=d)
        openssl("x509", "-req", "-in", f"{cn}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
                "-CAcreateserial", "-days", "2", "-extfile", "san.ext", "-out", f"{cn}.pem",
                cwd=d)
    return d


def local(path: Path, pki_dir: Path, port: int, tmp: Path, **more: str) -> Path:
    """A copy of a deploy file under ``tmp``: /etc/wrenchd/tls/ moved to ``pki_dir``, port 7447
    to loopback ``port``, and each of ``more`` replaced by its value."""
    text = (path.read_text().replace("/etc/wrenchd/tls/", f"{pki_dir}/")
            .replace('"tls/0.0.0.0:7447"', f'"tls/127.0.0.1:{port}"')
            .replace('"tls/localhost:7447"', f'"tls/127.0.0.1:{port}"'))
    for old, new in more.items():
        text = text.replace(old, new)
    (tmp / path.name).write_text(text)
    return tmp / path.name


def test_the_example_passes_the_router_file_through():
    zenoh = tomllib.loads(SETTINGS.read_text())["zenoh"]
    assert zenoh["config_file"] == "/etc/wrenchd/zenoh/router.json5"
    assert "mode" not in zenoh and "listen" not in zenoh          # the file's: router, TLS


def test_the_daemon_as_router_enforces_the_files_access_control(pki, tmp_path):
    port = free_port()
    router = local(ZENOH / "router.json5", pki, port, tmp_path)
    settings = load_settings(local(SETTINGS, pki, port, tmp_path,
                                   **{"/etc/wrenchd/zenoh/router.json5": str(router)}))
    conf = settings.zenoh.to_zenoh()
    assert json.loads(conf.get_json("mode")) == "router"
    assert json.loads(conf.get_json("access_control/default_permission")) == "deny"
    assert json.loads(conf.get_json("transport/link/tls/listen_certificate")) == \
        str(pki / "or-router-1.pem")                     # the key table over the file
    assert json.loads(conf.get_json("connect/retry"))["period_max_ms"] == 1000
    viewer = local(ZENOH / "viewer.json5", pki, port, tmp_path)
    (tmp_path / "intruder").mkdir()
    intruder_file = local(ZENOH / "viewer.json5", pki, port, tmp_path / "intruder",
                          **{"/viewer": "/intruder"})
    wrench = encode_wrench("json", 1_000_000_000, np.array([1.0, 2.0, 3.0, 0.0, 0.0, 0.0]),
                           "PSM1_base")

    got: dict[str, list[str]] = {"daemon": [], "robot": []}
    seen = threading.Condition()

    def keep(who):
        def on_sample(sample) -> None:
            with seen:
                got[who].append(f"{sample.key_expr}={sample.payload.to_string()}")
                seen.notify_all()
        return on_sample

    def status(query) -> None:
        query.reply(query.key_expr, json.dumps({"arm": "PSM1", "from": "the router's daemon"}))

    def echo(zfile: Path, *args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "wrenchd", "echo", "--zenoh-config",
                               str(zfile), *args], capture_output=True, text=True, timeout=60)

    daemon = open_session(settings.zenoh)
    sessions, undeclare = [], []
    try:
        undeclare.append(daemon.declare_subscriber("dvrk/PSM1/measured_js", keep("daemon")))
        undeclare.append(daemon.declare_queryable("dvrk/PSM1/wrenchd/status", status))
        for cn in ("dvrk-psm1", "intruder"):
            sessions.append(client(pki, cn, port))
        robot, intruder = sessions
        # the robot may not read the wrenches: its subscription is denied
        undeclare.append(robot.declare_subscriber("dvrk/*/wrenchd/**", keep("robot")))
        time.sleep(1.0)                                  # declarations reach the router
        watching = subprocess.Popen(
            [sys.executable, "-m", "wrenchd", "echo", "--zenoh-config", str(viewer),
             "--every", "1", "--count", "3", "--timeout", "30"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            answered = echo(viewer, "--status", "--timeout", "10")
            refused = echo(intruder_file, "--status", "--timeout", "2")
            for _ in range(3):
                robot.put("dvrk/PSM1/measured_js", "robot")
                intruder.put("dvrk/PSM1/measured_js", "intruder")
            with seen:
                seen.wait_for(lambda: got["daemon"], timeout=10.0)
            deadline = time.monotonic() + 30.0
            while watching.poll() is None and time.monotonic() < deadline:
                daemon.put("dvrk/PSM1/wrenchd/measured_cf", wrench)
                time.sleep(0.1)
            out, err = watching.communicate(timeout=30)
        finally:
            if watching.poll() is None:
                watching.kill()
                watching.communicate()
    finally:
        for entity in undeclare:
            entity.undeclare()
        for s in sessions:
            s.close()
        daemon.close()
    assert answered.returncode == 0, answered.stderr
    assert json.loads(answered.stdout) == {"arm": "PSM1", "from": "the router's daemon"}
    assert refused.returncode == 1 and "no answer" in refused.stdout, refused.stderr
    assert set(got["daemon"]) == {"dvrk/PSM1/measured_js=robot"}
    assert got["robot"] == []
    assert watching.returncode == 0, err
    printed = [x for x in out.splitlines() if x.startswith("t=")]
    assert len(printed) == 3 and all("F=[  1.00   2.00   3.00] N" in x for x in printed), out
    assert out.splitlines()[-1] == "wrenchd echo: 3 wrenches"
