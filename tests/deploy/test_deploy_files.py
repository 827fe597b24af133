"""deploy/: example daemon configs accepted by the real `wrenchd config`, and consistent with
the systemd unit (directories it lets the daemon write) and the router (certificate CNs); the
unit passes `systemd-analyze verify`; the container file pins what the project pins."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from tests.support import communicate_within

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
CONFIGS = sorted((DEPLOY / "config").glob("*.toml"))
UNIT = DEPLOY / "systemd" / "wrenchd@.service"


def start_config(path: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "wrenchd", "config", "--config",
                             str(path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT)


@pytest.fixture(scope="module")
def config_runs(tmp_path_factory):
    """`wrenchd config` on every example and on a broken copy, run concurrently (each process
    imports the whole package: seconds)."""
    bad = tmp_path_factory.mktemp("bad") / "bad.toml"
    bad.write_text((DEPLOY / "config" / "psm1.toml").read_text()
                   .replace('encoding = "cdr"', 'encoding = "xml"'))
    procs = {p.stem: start_config(p) for p in [*CONFIGS, bad]}
    runs = {}
    for name, proc in procs.items():
        out, err = communicate_within(proc, 300.0, f"wrenchd config ({name})")
        runs[name] = (proc.returncode, out, err)
    return runs


def test_there_is_a_config_per_arm_and_a_three_arm_one():
    assert {p.stem for p in CONFIGS} >= {"psm1", "psm2", "psm3", "three-arms"}


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_example_config_is_accepted(path, config_runs):
    rc, out, err = config_runs[path.stem]
    assert rc == 0, err
    cfg = json.loads(out)
    assert cfg["robot"] == "external"
    assert cfg["zenoh"]["mode"] == "client" and not cfg["zenoh"]["multicast_scouting"]
    for endpoint in cfg["zenoh"]["connect"]:
        assert endpoint.startswith("tls/") and "enable_mtls=true" in endpoint
    # the unit makes only /var/log/wrenchd/<instance> and /var/lib/wrenchd/<instance> writable
    assert cfg["log"]["directory"] == f"/var/log/wrenchd/{path.stem}"
    if cfg["models_dir"] is not None:
        assert cfg["models_dir"].startswith(f"/var/lib/wrenchd/{path.stem}/")
    if path.stem.startswith("psm"):
        arm = path.stem.upper()
        assert [a["name"] for a in cfg["arms"]] == [arm]
        # its certificate is the CN the router grants */PSMn/wrenchd/** to
        cert = re.search(r"connect_certificate_file=[^;]*/([^/;]+)\.pem", cfg["zenoh"]["connect"][0])
        acl = json.loads(zenoh.Config.from_file(str(DEPLOY / "zenoh" / "router.json5"))
                         .get_json("access_control"))
        subject = next(s for s in acl["subjects"] if s["id"] == f"{path.stem}-daemon")
        assert [cert.group(1)] == subject["cert_common_names"]
        rule = next(r for r in acl["rules"] if r["id"] == f"{path.stem}-daemon-out")
        assert rule["key_exprs"] == [f"*/{arm}/wrenchd/**"]
    else:
        assert [a["name"] for a in cfg["arms"]] == ["PSM1", "PSM2", "PSM3"]


def test_a_bad_value_is_refused_by_name(config_runs):
    rc, _, err = config_runs["bad"]
    assert rc != 0
    assert "arms.0.encoding" in err and "xml" in err


def test_systemd_unit():
    text = UNIT.read_text()
    for directive in ("User=wrenchd", "Restart=on-failure", "StartLimitBurst=5",
                      "NoNewPrivileges=yes", "ProtectSystem=strict", "StateDirectory=wrenchd/%i",
                      "LogsDirectory=wrenchd/%i", "LimitRTPRIO=20", "RestrictRealtime=no",
                      "ReadWritePaths=/var/log/wrenchd/%i /var/lib/wrenchd/%i",
                      "ExecStart=/opt/wrenchd/bin/wrenchd serve --config /etc/wrenchd/%i.toml"):
        assert re.search(rf"^{re.escape(directive)}$", text, re.M), directive
    analyze = shutil.which("systemd-analyze")
    if analyze is None:
        pytest.skip("systemd-analyze not installed")
    # verify an instance with the executable pointed at this checkout's wrenchd
    wrenchd = Path(sys.executable).with_name("wrenchd")
    unit = Path("/tmp") / f"wrenchd-test-{Path(sys.executable).stat().st_ino}@psm1.service"
    try:
        unit.write_text(text.replace("/opt/wrenchd/bin/wrenchd", str(wrenchd)))
        run = subprocess.run([analyze, "verify", str(unit)], capture_output=True, text=True,
                             timeout=60)
    finally:
        unit.unlink(missing_ok=True)
    assert run.returncode == 0 and not run.stderr.strip(), run.stderr


def test_containerfile():
    text = (DEPLOY / "Containerfile").read_text()
    assert re.search(r"^FROM \S*python:3\.1[1-9]-slim$", text, re.M)
    pin = re.search(r'"torch==([\d.]+)"', (ROOT / "pyproject.toml").read_text()).group(1)
    assert f"torch=={pin}" in text and "whl/cpu" in text
    users = re.findall(r"^USER (\S+)$", text, re.M)
    assert users and users[-1] not in ("root", "0")
    assert text.index(f"USER {users[-1]}") < text.index("ENTRYPOINT")
    assert re.search(r'^ENTRYPOINT \["wrenchd", "serve"\]$', text, re.M)
    for src in re.findall(r"^COPY (.+) \S+$", text, re.M):
        for part in src.split():
            assert (ROOT / part).exists(), part
