"""Every result file says where it came from: ``service/provenance.py`` through a real writer."""

import datetime as dt
import importlib.metadata
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from wrenchd.service.provenance import PACKAGES, PROVENANCE_KEY, RunMeter, steal_ticks

ROOT = Path(__file__).resolve().parents[2]


def _head() -> str | None:
    if shutil.which("git") is None:
        return None
    done = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                          text=True, check=False, timeout=60)
    return done.stdout.strip() if done.returncode == 0 else None


def test_a_bench_json_carries_the_provenance_of_its_run(tmp_path):
    out = tmp_path / "inference.json"
    heads = {_head()}
    before = dt.datetime.now(dt.UTC).replace(microsecond=0)
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-m", "wrenchd", "bench", "inference", "--duration", "2",
                    "--json", str(out)], check=True, capture_output=True, text=True,
                   timeout=300, cwd=ROOT)
    elapsed_s = time.monotonic() - t0
    heads.add(_head())                    # others may commit meanwhile: either HEAD is right
    after = dt.datetime.now(dt.UTC)
    result = json.loads(out.read_text())
    assert result["samples"] == 400                      # the bench's own numbers are there
    p = result[PROVENANCE_KEY]
    assert p["argv"][1:] == ["bench", "inference", "--duration", "2", "--json", str(out)]
    if heads == {None}:
        assert p["git_commit"] is None and p["git_dirty"] is None
    else:
        assert p["git_commit"] in heads and len(p["git_commit"]) == 40
        assert isinstance(p["git_dirty"], bool)
    assert before <= dt.datetime.fromisoformat(p["date_utc"]) <= after
    load = p["load_average"]
    assert len(load) == 3 and all(isinstance(x, float) and x >= 0.0 for x in load)
    # measured over the bench itself: shorter than the whole subprocess, longer than nothing
    assert 0.0 < p["run_wall_s"] < elapsed_s
    assert p["steal_cpu_s"] >= 0.0 and 0.0 <= p["steal_share"] <= 1.0
    assert p["steal_cpu_s"] <= p["run_wall_s"] * os.cpu_count() + 0.02      # 2 ticks of slack
    assert p["cpu_count"] == os.cpu_count() and p["machine"] == platform.machine()
    assert p["python"] == platform.python_version()
    assert set(p["packages"]) == set(PACKAGES)
    for name, version in p["packages"].items():
        assert version == importlib.metadata.version(name)


def test_without_git_the_record_says_so_and_the_rest_is_there(tmp_path):
    """A machine without git (PATH without it): commit and dirtiness are null, not a crash."""
    probe = ("import json; from wrenchd.service.provenance import provenance; "
             "print(json.dumps(provenance(['x'])))")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=60, cwd=tmp_path, env={**os.environ, "PATH": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    p = json.loads(done.stdout)
    assert p["git_commit"] is None and p["git_dirty"] is None
    assert p["argv"] == ["x"] and len(p["load_average"]) == 3


@pytest.mark.skipif(not Path("/proc/stat").exists(), reason="Linux /proc only")
def test_the_steal_counter_is_the_kernels():
    def field() -> int:
        return int(Path("/proc/stat").read_text().splitlines()[0].split()[8])

    a = field()
    mine = steal_ticks()
    b = field()
    assert a <= mine <= b                         # a cumulative counter, read between the two
    meter = RunMeter()
    time.sleep(0.2)
    m = meter.measure()
    assert 0.2 <= m["run_wall_s"] < 5.0
    assert m["steal_cpu_s"] >= 0.0 and 0.0 <= m["steal_share"] <= 1.0
