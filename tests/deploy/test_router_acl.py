"""deploy/zenoh/router.json5 loads in zenoh-python and, run as a real router on loopback with
certificates from a throw-away CA, lets only the right certificate publish each key."""

import json
import subprocess
import time
from pathlib import Path

import pytest
import zenoh

from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.service.runtime.settings import load_settings
from tests.support import free_port

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
ROUTER = DEPLOY / "zenoh" / "router.json5"
EC_KEY = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
CNS = ["or-router-1", "wrenchd-psm1", "dvrk-psm1", "haptics", "intruder"]


def openssl(*args, cwd):
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A CA and one certificate per CN (SAN 127.0.0.1 and localhost), PEM files."""
    d = tmp_path_factory.mktemp("pki")
    openssl("req", "-x509", *EC_KEY, "-days", "2", "-subj", "/CN=or-ca",
            "-keyout", "ca-key.pem", "-out", "ca.pem", cwd=d)
    (d / "san.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    for cn in CNS:
        openssl("req", *EC_KEY, "-subj", f"/CN={cn}", "-keyout", f"{cn}-key.pem", "-out", f"{cn}.csr", cwd=d)
        openssl("x509", "-req", "-in", f"{cn}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
                "-CAcreateserial", "-days", "2", "-extfile", "san.ext", "-out", f"{cn}.pem", cwd=d)
    return d


def test_router_config_is_accepted_by_zenoh():
    conf = zenoh.Config.from_file(str(ROUTER))
    acl = json.loads(conf.get_json("access_control"))
    assert acl["enabled"] and acl["default_permission"] == "deny"
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    assert json.loads(conf.get_json("mode")) == "router"
    # every policy names defined rules and subjects
    rules = {r["id"] for r in acl["rules"]}
    subjects = {s["id"] for s in acl["subjects"]}
    for policy in acl["policies"]:
        assert set(policy["rules"]) <= rules and set(policy["subjects"]) <= subjects


def client(pki, cn, port):
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    endpoint = (f"tls/127.0.0.1:{port}#root_ca_certificate_file={pki / 'ca.pem'};"
                f"connect_certificate_file={pki / (cn + '.pem')};"
                f"connect_private_key_file={pki / (cn + '-key.pem')};enable_mtls=true")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(conf)


def daemon_session(pki, port):
    """The daemon's own zenoh settings from deploy/config/psm1.toml, paths moved to the test
    CA: the TLS endpoint the example config ships is the one the router admits."""
    zc = load_settings(DEPLOY / "config" / "psm1.toml").zenoh
    connect = [e.replace("/etc/wrenchd/tls/", f"{pki}/").replace("localhost:7447",
                                                                  f"127.0.0.1:{port}")
               for e in zc.connect]
    return open_session(ZenohConfig(mode=zc.mode, connect=connect,
                                    multicast_scouting=zc.multicast_scouting))


def open_router(pki: Path, port: int):
    """The deployed router configuration, listening on loopback ``port`` with the test PKI's
    ``or-router-1`` certificate (mTLS): a real router session."""
    conf = zenoh.Config.from_file(str(ROUTER))
    conf.insert_json5("listen/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    for key, name in (("root_ca_certificate", "ca.pem"), ("listen_certificate", "or-router-1.pem"),
                      ("listen_private_key", "or-router-1-key.pem"),
                      ("connect_certificate", "or-router-1.pem"),
                      ("connect_private_key", "or-router-1-key.pem")):
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(str(pki / name)))
    return zenoh.open(conf)


def test_only_the_daemon_and_the_robot_publish_their_keys(pki):
    port = free_port()
    router = open_router(pki, port)
    sessions = {}
    try:
        sessions["wrenchd-psm1"] = daemon_session(pki, port)
        for cn in ("dvrk-psm1", "haptics", "intruder"):
            sessions[cn] = client(pki, cn, port)
        got: list[tuple[str, str, str]] = []       # (receiver, key, payload)

        def seen(receiver):
            return lambda s: got.append((receiver, str(s.key_expr), s.payload.to_string()))

        # subscriptions must lie inside the granted trees: a declaration of dvrk/** is denied
        subs = [sessions[cn].declare_subscriber(key, seen(cn)) for cn, key in (
            ("haptics", "dvrk/*/wrenchd/**"), ("haptics", "dvrk/*/measured_js"),
            ("wrenchd-psm1", "dvrk/PSM1/measured_js"), ("intruder", "dvrk/*/wrenchd/**"),
            ("intruder", "dvrk/*/measured_js"), ("haptics", "dvrk/*/setup"),
            ("wrenchd-psm1", "dvrk/PSM1/setup"))]
        time.sleep(1.0)
        attempts = [
            ("wrenchd-psm1", "dvrk/PSM1/wrenchd/measured_cf", True),
            ("wrenchd-psm1", "dvrk/PSM1/wrenchd/events", True),
            ("dvrk-psm1", "dvrk/PSM1/measured_js", True),
            ("intruder", "dvrk/PSM1/wrenchd/measured_cf", False),
            ("intruder", "dvrk/PSM1/measured_js", False),
            ("dvrk-psm1", "dvrk/PSM1/wrenchd/measured_cf", False),
            ("wrenchd-psm1", "dvrk/PSM1/measured_js", False),
            ("wrenchd-psm1", "dvrk/PSM2/wrenchd/measured_cf", False),
            ("haptics", "dvrk/PSM1/wrenchd/measured_cf", False),
            # set-up changes come from the robot's side, like its joint states
            ("dvrk-psm1", "dvrk/PSM1/setup", True),
            ("intruder", "dvrk/PSM1/setup", False),
            ("wrenchd-psm1", "dvrk/PSM1/setup", False),
            ("dvrk-psm1", "dvrk/PSM2/setup", False),
        ]
        for i, (cn, key, _) in enumerate(attempts):
            for _ in range(3):
                sessions[cn].put(key, f"{i}:{cn}")
        time.sleep(1.5)
        for s in subs:
            s.undeclare()
    finally:
        for s in sessions.values():
            s.close()
        router.close()
    # a session delivers its own puts to its own subscribers without the router: not counted
    delivered = {p.split(":")[0] for r, _, p in got if r == "haptics" and p.split(":")[1] != r}
    for i, (cn, key, allowed) in enumerate(attempts):
        assert (str(i) in delivered) == allowed, (cn, key, allowed, sorted(got))
    # the daemon hears its robot; the intruder hears nothing (its subscriptions are denied)
    assert ("wrenchd-psm1", "dvrk/PSM1/measured_js", "2:dvrk-psm1") in got
    assert ("wrenchd-psm1", "dvrk/PSM1/setup", "9:dvrk-psm1") in got
    assert not [g for g in got if g[0] == "intruder" and not g[2].endswith(":intruder")]
