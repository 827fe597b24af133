"""Every example daemon config's certificate is one the router's access control knows, and it
grants exactly that config's arms: read from the files, then enforced by a real router.

The certificate's common name is the file name of ``connect_certificate_file`` in the TLS
endpoint (``/etc/wrenchd/tls/<cn>.pem``, the convention of deploy/README.md).
"""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

import pytest
import zenoh

from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.service.runtime.settings import load_settings
from tests.deploy.test_router_acl import EC_KEY, open_router, openssl
from tests.support import free_port

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
ROUTER = DEPLOY / "zenoh" / "router.json5"
CONFIGS = sorted((DEPLOY / "config").glob("*.toml"))
ALL_ARMS = ("PSM1", "PSM2", "PSM3")
DAEMON_MESSAGES = {"put", "declare_queryable", "reply", "liveliness_token"}


def certificate_cn(endpoint: str) -> str:
    found = re.search(r"connect_certificate_file=[^;#]*/([^/;]+)\.pem", endpoint)
    assert found, f"no connect_certificate_file in {endpoint}"
    return found.group(1)


def acl() -> dict:
    return json.loads(zenoh.Config.from_file(str(ROUTER)).get_json("access_control"))


def granted(cn: str) -> list[dict]:
    """The allow rules of every policy whose subjects carry ``cn``."""
    a = acl()
    subjects = {s["id"] for s in a["subjects"] if cn in s.get("cert_common_names", [])}
    names = {r for p in a["policies"] if subjects & set(p["subjects"]) for r in p["rules"]}
    return [r for r in a["rules"] if r["id"] in names and r["permission"] == "allow"]


def publishes(rules: list[dict], key: str) -> bool:
    return any("ingress" in r["flows"] and "put" in r["messages"] and key in r["key_exprs"]
               for r in rules)


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_config_certificate_is_an_acl_subject_granted_its_arms(path):
    settings = load_settings(path)
    arms = {a.name for a in settings.arms}
    assert settings.zenoh.connect, "a deployed daemon connects to its router"
    for endpoint in settings.zenoh.connect:
        cn = certificate_cn(endpoint)
        rules = granted(cn)
        assert rules, f"{path.name}: certificate CN {cn!r} is no subject of {ROUTER.name}"
        for arm in ALL_ARMS:
            tree = f"*/{arm}/wrenchd/**"
            assert publishes(rules, tree) == (arm in arms), (path.name, cn, arm)
            if arm in arms:                      # wrench, events, status replies, token
                rule = next(r for r in rules if tree in r["key_exprs"])
                assert DAEMON_MESSAGES <= set(rule["messages"]), rule
        assert not any(publishes(rules, k) for k in ("*/*/measured_js",
                                                     *(f"*/{a}/measured_js" for a in ALL_ARMS)))


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A throw-away CA; a certificate for the router, a consumer and every config's CN."""
    cns = {"or-router-1", "haptics"} | {certificate_cn(e) for p in CONFIGS
                                         for e in load_settings(p).zenoh.connect}
    d = tmp_path_factory.mktemp("pki-configs")
    openssl("req", "-x509", *EC_KEY, "-days", "2", "-subj", "/CN=or-ca",
            "-keyout", "ca-key.pem", "-out", "ca.pem", cwd=d)
    (d / "san.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n")
    for cn in sorted(cns):
        openssl("req", *EC_KEY, "-subj", f"/CN={cn}", "-keyout", f"{cn}-key.pem",
                "-out", f"{cn}.csr", cwd=d)
        openssl("x509", "-req", "-in", f"{cn}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
                "-CAcreateserial", "-days", "2", "-extfile", "san.ext", "-out", f"{cn}.pem",
                cwd=d)
    return d


def session_of(settings, pki: Path, port: int):
    """A session with a config's own zenoh settings, certificate paths moved to the test CA."""
    zc = settings.zenoh
    connect = [e.replace("/etc/wrenchd/tls/", f"{pki}/").replace("localhost:7447",
                                                                  f"127.0.0.1:{port}")
               for e in zc.connect]
    return open_session(zc.model_copy(update={"connect": connect}))


def test_a_real_router_lets_each_config_publish_its_arms_only(pki):
    port = free_port()
    router = open_router(pki, port)
    sessions, got, sub = {}, [], None
    try:
        consumer = ZenohConfig(mode="client", connect=[
            f"tls/127.0.0.1:{port}#root_ca_certificate_file={pki / 'ca.pem'};"
            f"connect_certificate_file={pki / 'haptics.pem'};"
            f"connect_private_key_file={pki / 'haptics-key.pem'};enable_mtls=true"])
        sessions["haptics"] = open_session(consumer)
        sub = sessions["haptics"].declare_subscriber(
            "dvrk/*/wrenchd/**", lambda s: got.append(s.payload.to_string()))
        settings = {p.stem: load_settings(p) for p in CONFIGS}
        for name, s in settings.items():
            sessions[name] = session_of(s, pki, port)
        time.sleep(1.0)
        for name, s in settings.items():
            for arm in ALL_ARMS:
                for _ in range(3):
                    sessions[name].put(f"{s.prefix}/{arm}/wrenchd/measured_cf", f"{name}:{arm}")
        time.sleep(1.5)
    finally:
        if sub is not None:
            sub.undeclare()
        for s in sessions.values():
            s.close()
        router.close()
    for name, s in settings.items():
        mine = {a.name for a in s.arms}
        for arm in ALL_ARMS:
            assert (f"{name}:{arm}" in got) == (arm in mine), (name, arm, sorted(set(got)))
