"""bench ratio, short: the floor and the daemon as real subprocesses one after the other, the
daemon's figures split at a given time, the ratios those runs give."""

import math

import pytest

from wrenchd.service.bench.ratio import bench_ratio, pair_ratios


def test_a_pair_gives_ratios_overall_and_per_phase():
    r = bench_ratio(n_arms=1, rate_hz=200.0, duration_s=6.0, pairs=1, split_s=5.0,
                    warmup_s=2.0)
    (run,) = r["runs"]
    assert run["floor"]["daemon"].startswith("bench floor") and r["dropped"] == 0
    # both measured alike: the same class for the floor and the daemon, and for the bench's
    # own callbacks (each run in a process whose zenoh threads it made itself)
    assert run["floor"]["realtime_priority"] == "auto"
    assert run["floor"]["bench_realtime_priority"] == run["daemon"]["bench_realtime_priority"]
    expected = ["normal"] if run["daemon"]["bench_realtime_priority"] is None else ["fifo"]
    for w in ("floor", "daemon"):
        assert run[w]["bench_zenoh_thread_classes"] == expected
    phases = run["daemon"]["phases"]
    assert phases["split_s"] == 5.0
    for name in ("before", "after"):
        assert math.isfinite(phases[name]["e2e_p99_us"])
        assert phases[name]["daemon_cpu_us_per_sample"] > 0
    assert r["ratio_p99"] == pytest.approx(
        run["daemon"]["e2e_p99_us"] / run["floor"]["e2e_p99_us"])
    assert r["after"]["ratio_cpu"] == pytest.approx(
        phases["after"]["daemon_cpu_us_per_sample"] / run["floor"]["daemon_cpu_us_per_sample"])
    assert len(r["load_average_1min"]) == len(r["steal_cpu_s"]) == 2


def test_ratios_without_a_phase_or_a_floor_figure():
    floor = {"e2e_p99_us": 500.0, "daemon_cpu_us_per_sample": 0.0}
    daemon = {"e2e_p99_us": 1000.0, "daemon_cpu_us_per_sample": 300.0, "phases": None}
    assert pair_ratios(floor, daemon) == {"ratio_p99": 2.0, "ratio_cpu": None,
                                          "ratio_p99_without_steal": None}
    with pytest.raises(ValueError):
        bench_ratio(pairs=0)
