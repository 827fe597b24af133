"""The soak benchmark, short: the daemon as a real subprocess fed at 200 Hz over loopback
zenoh for a few seconds; every joint state gets its wrench and memory is sampled."""

import math
import tomllib
from pathlib import Path

import pytest

from wrenchd.service.bench.daemon_latency import _config, bench_service


def test_short_soak_drops_nothing_and_reports_memory():
    r = bench_service(n_arms=1, rate_hz=200.0, duration_s=6.0, warmup_s=2.0)
    assert r["dropped"] == 0
    assert r["rate_hz"] == 200.0
    arm = r["per_arm"]["PSM1"]
    assert arm["received"] == int(8.0 * 200)
    assert all(math.isfinite(r[k]) for k in ("rss_start_mb", "rss_end_mb", "e2e_p50_us"))
    assert 50.0 < r["rss_start_mb"] < 8000.0            # the daemon and its worker, in MB
    assert "stages" not in r                            # nothing timed unless asked


def test_the_daemon_bench_in_cdr_gets_every_wrench_back():
    """bench service --encoding cdr: the robot side publishes ROS 2 CDR joint states, the
    daemon's arms read and answer CDR, and every wrench is matched by its stamp."""
    r = bench_service(n_arms=1, rate_hz=200.0, duration_s=2.0, warmup_s=1.0, encoding="cdr")
    assert r["encoding"] == "cdr" and r["dropped"] == 0
    assert r["per_arm"]["PSM1"]["received"] == 600


@pytest.mark.parametrize("encoding", ["json", "cdr"])
def test_the_floor_bench_answers_every_joint_state_without_estimating(encoding):
    """bench floor: the same bench against the daemon's plumbing alone (two arms), in either
    wire encoding."""
    r = bench_service(n_arms=2, rate_hz=200.0, duration_s=3.0, warmup_s=1.0, floor=True,
                      encoding=encoding)
    assert r["daemon"].startswith("bench floor") and r["dropped"] == 0
    assert r["encoding"] == encoding
    assert [a["received"] for a in r["per_arm"].values()] == [800, 800]
    assert math.isfinite(r["e2e_p99_us"]) and r["daemon_cpu_us_per_sample"] > 0


def test_stages_count_every_sample_of_every_arm():
    """bench service --stages: the daemon times its stages; each joint state is decoded, and
    published and logged, once (two arms stepped together or one by one)."""
    r = bench_service(n_arms=2, rate_hz=200.0, duration_s=1.5, warmup_s=0.5, stages=True)
    assert r["dropped"] == 0
    stages = r["stages"]
    assert stages["decode"]["calls"] == stages["publish and log"]["calls"] == 2 * 400
    assert stages["intake"]["calls"] > 0 and stages["housekeeping"]["calls"] > 0
    for stage in stages.values():
        assert stage["total_s"] > 0.0 and stage["us_per_call"] > 0.0


def test_a_bundle_served_on_a_real_recording(wpi_data, tmp_path):
    """bench service --model BUNDLE --recording FILE: every arm's config names the bundle,
    and the daemon serves it on the recording, played again from its start (here 4 s of a
    30 s file at its own 200 Hz)."""
    bundle = Path(__file__).resolve().parents[3] / "reports" / "real-robot" / "bundle"
    _config(tmp_path / "bench.toml", "tcp/127.0.0.1:1", ["PSM1", "PSM2"], tmp_path,
            model=str(bundle))
    arms = tomllib.loads((tmp_path / "bench.toml").read_text())["arms"]
    assert [a["model"] for a in arms] == [str(bundle)] * 2
    r = bench_service(n_arms=1, rate_hz=200.0, duration_s=3.0, warmup_s=1.0,
                      model=str(bundle), recording=str(wpi_data / "two.csv"))
    assert r["dropped"] == 0 and r["per_arm"]["PSM1"]["received"] == 800
