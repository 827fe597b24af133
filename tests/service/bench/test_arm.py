"""`bench arm`: the per-stage cost of one arm's work, back to back and paced at 1 kHz."""

from pathlib import Path

from wrenchd.service.bench.run import PACED_BLOCK, bench_arm_thread


def test_stages_and_both_pacings_are_reported():
    out = bench_arm_thread(duration_s=6.0)                  # 1 200 samples at 200 Hz
    assert out["samples"] == 1200
    for stage in ("decode", "pipeline", "encode", "log", "total", "log_writer"):
        assert 0.0 < out[f"{stage}_p50_us"] <= out[f"{stage}_p99_us"]
    # after the warm-up block, blocks alternate: tight, then paced (the last one short)
    assert out["tight"]["samples"] == PACED_BLOCK
    assert out["paced"]["samples"] == 1200 - 2 * PACED_BLOCK
    for mode in ("tight", "paced"):
        assert 0.0 < out[mode]["wall_p50_us"] <= out[mode]["wall_p99_us"]
        assert out[mode]["thread_cpu_mean_us"] > 0.0 and out[mode]["thread_cpu_p50_us"] > 0.0


def test_a_lab_s_bundle_on_its_own_recording(wpi_data):
    """``--model`` and ``--recording``: a fitted bundle served on a real recording, played
    again from its start to last the duration (30 s of 200 Hz twice for 40 s)."""
    bundle = Path(__file__).resolve().parents[3] / "reports" / "real-robot" / "bundle"
    out = bench_arm_thread(duration_s=40.0, model=str(bundle),
                           recording=str(wpi_data / "two.csv"))
    assert out["samples"] == 2 * 5999
    assert 0.0 < out["pipeline_p50_us"] <= out["pipeline_p99_us"]
