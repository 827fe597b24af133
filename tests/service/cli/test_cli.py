"""The ``wrenchd`` command line, run as a real subprocess."""

import json
import subprocess
import sys

import pytest
from mcap.reader import make_reader

from wrenchd.adapters.messages import decode_joint_state

SCENARIOS = ["free-space", "free-space-seal", "trocar", "trocar-contact",
             "insufflation-change", "instrument-drift"]


def wrenchd(*args, check=True):
    return subprocess.run([sys.executable, "-m", "wrenchd", *args], capture_output=True,
                          text=True, check=check, timeout=300)


HEAVY = ("torch", "scipy", "river", "pinocchio", "matplotlib")


def test_light_commands_start_without_the_heavy_imports():
    """``--help``, ``announce`` and ``echo`` import none of torch, scipy, river, pinocchio: a
    notice from ``wrenchd announce`` is placed at the arm's latest sample when it arrives, so
    seconds of start-up would misplace it. Names of scenarios and policies load on use."""
    probe = f"""
import sys
from wrenchd.service.cli import main
for argv in (["announce", "--connect", "tcp/127.0.0.1:9", "--timeout", "0.1"],
             ["echo", "--connect", "tcp/127.0.0.1:9", "--status", "--timeout", "0.1"]):
    assert main(argv) == 1, argv
print(sorted(m for m in {HEAVY!r} if m in sys.modules))
"""
    run = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[-1] == "[]"
    # the lazy choices still list and check the names
    help_ = wrenchd("robot", "--help").stdout
    assert "insufflation-change" in help_ and "(default trocar-contact)" in help_
    bad = wrenchd("simulate", "--scenario", "nope", "-o", "x.mcap", check=False)
    assert bad.returncode == 2 and "invalid choice: 'nope'" in bad.stderr
    assert "'trocar-contact'" in bad.stderr
    bad = wrenchd("replay", "sim:trocar:5", "--policy", "nope", check=False)
    assert bad.returncode == 2 and "'ungated'" in bad.stderr


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_simulate_writes_an_mcap_any_reader_opens(tmp_path, scenario):
    out = tmp_path / f"{scenario}.mcap"
    wrenchd("simulate", "--scenario", scenario, "--duration", "12", "--seed", "4", "-o", str(out))
    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {ch.topic: ch for ch in summary.channels.values()}
        assert {"/psm/measured_js", "/psm/truth/torques", "/psm/truth/wrench"} <= set(topics)
        for ch in topics.values():
            assert ch.message_encoding == "cdr"
            assert summary.schemas[ch.schema_id].encoding == "ros2msg"
        counts = summary.statistics.channel_message_counts
        js_id = topics["/psm/measured_js"].id
        assert counts[js_id] == 12 * 200
        first = next(reader.iter_messages(topics=["/psm/measured_js"]))
        msg = decode_joint_state("cdr", first[2].data)
        assert len(msg.position) == 6 and msg.stamp_ns < 10**9
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert json.loads(meta["wrenchd.session"]["json"])["scenario"]["name"] == scenario


def test_simulate_is_byte_deterministic(tmp_path):
    a, b, c = (tmp_path / n for n in ("a.mcap", "b.mcap", "c.mcap"))
    for path, seed in ((a, "9"), (b, "9"), (c, "10")):
        wrenchd("simulate", "--scenario", "trocar-contact", "--duration", "10", "--seed", seed,
                "-o", str(path))
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


def test_model_file_replaces_physics_and_bad_files_are_named(tmp_path):
    model = tmp_path / "model.json"
    model.write_text(json.dumps({"effects": [{"name": "viscous_friction"},
                                             {"name": "payload_mass",
                                              "params": {"mass_kg": 0.205}}]}))
    out = tmp_path / "s.mcap"
    wrenchd("simulate", "--scenario", "free-space", "--duration", "5", "--model", str(model),
            "-o", str(out))
    info = json.loads(wrenchd("inspect", str(out)).stdout)
    assert info["effects"] == ["payload_mass", "rigid_body", "viscous_friction"]
    assert info["samples"] == 1000 and not info["truncated"]

    model.write_text(json.dumps({"effects": [{"name": "payload_mass",
                                              "params": {"mass_kg": -2}}]}))
    bad = wrenchd("simulate", "--scenario", "free-space", "--duration", "5", "--model",
                  str(model), "-o", str(out), check=False)
    assert bad.returncode == 2
    assert "mass_kg" in bad.stderr and "Traceback" not in bad.stderr


def test_effects_lists_the_vocabulary():
    out = wrenchd("effects").stdout
    for name in ("seal_friction", "body_wall", "payload_mass", "drift", "external_contact"):
        assert f"{name}:" in out


def test_bench_inference_writes_its_json(tmp_path):
    out = tmp_path / "inference.json"
    wrenchd("bench", "inference", "--duration", "3", "--json", str(out))
    result = json.loads(out.read_text())
    assert {"step_p50_us", "step_p99_us", "batch_samples_per_s"} <= set(result)
    assert 0 < result["step_p50_us"] <= result["step_p99_us"]
    assert result["batch_samples_per_s"] > 0 and result["samples"] == 600


def test_bench_arm_times_the_daemons_work_and_the_log_writers_apart(tmp_path):
    out = tmp_path / "arm.json"
    wrenchd("bench", "arm", "--duration", "2", "--json", str(out))
    result = json.loads(out.read_text())
    for stage in ("decode", "pipeline", "encode", "log", "total", "log_writer"):
        assert 0 < result[f"{stage}_p50_us"] <= result[f"{stage}_p99_us"], stage
    assert result["samples"] == 400


def test_bench_service_reports_latency_drops_and_rate_from_a_real_daemon(tmp_path):
    out = tmp_path / "service.json"
    wrenchd("bench", "service", "--duration", "3", "--rate", "200", "--json", str(out))
    r = json.loads(out.read_text())
    # the result's contract: {"e2e_p50_us", "e2e_p99_us", "dropped", "rate_hz"}
    assert 0 < r["e2e_p50_us"] <= r["e2e_p99_us"] < 1e6
    assert r["dropped"] == 0 and r["arms"] == 1 and r["adaptation"] is True
    assert r["rate_hz"] == pytest.approx(200.0, rel=0.05)
    assert r["per_arm"]["PSM1"]["received"] > 0


def test_bench_replay_times_the_replay_variants(tmp_path):
    out = tmp_path / "replay.json"
    wrenchd("bench", "replay", "--duration", "20", "--json", str(out))
    r = json.loads(out.read_text())
    assert r["samples"] == 20 * 200 and r["session"] == "sim:insufflation-change:20:3"
    for variant in ("default", "inline_adaptation", "kernel_step1", "frozen_no_adaptation"):
        assert r[variant]["samples_per_s"] > 0 and r[variant]["wall_s"] > 0
    assert r["frozen_no_adaptation"]["rounds"] == 0
    assert r["default"]["rounds"] > 0 and r["inline_adaptation"]["rounds"] > 0
    # the worker's CPU is counted where a worker ran (the default), and only there
    assert r["default"]["worker_cpu_s"] > 0 and r["default"]["cpu_s"] > 0
    assert r["inline_adaptation"]["worker_cpu_s"] == r["frozen_no_adaptation"]["worker_cpu_s"] == 0
    # time blocked on the worker: a part of the wall time where a worker ran, else none
    assert 0 <= r["default"]["blocked_on_worker_s"] <= r["default"]["wall_s"]
    assert r["inline_adaptation"]["blocked_on_worker_s"] is None
    assert r["samples_per_s"] == r["default"]["samples_per_s"]
    assert r["realtime_factor"] == pytest.approx(r["samples_per_s"] / 200.0, abs=0.01)


def test_compare_writes_the_table_json_and_a_plot_per_session(tmp_path):
    out = tmp_path / "cmp"
    run = wrenchd("compare", "--policies", "gated,frozen", "--sessions",
                  "sim:insufflation-change:20:1", "--out", str(out))
    assert "wrote" in run.stdout
    rows = json.loads((out / "compare.json").read_text())
    by_policy = {r["policy"]: r for r in rows}
    assert set(by_policy) == {"gated", "frozen"}
    assert by_policy["frozen"]["final_model_version"] == 0
    assert by_policy["gated"]["final_model_version"] > 0       # it adapted
    (drift,) = by_policy["gated"]["drifts"]
    assert drift["free_force_error_after_N"] > 0
    table, detector = (out / "compare.md").read_text().split("## The gate as a detector")
    assert table.count("sim:insufflation-change:20:1 |") == 2
    assert detector.count("sim:insufflation-change:20:1 |") == 2
    png = (out / "insufflation-change_20_1.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    bad = wrenchd("compare", "--policies", "gated,nonsense", "--sessions",
                  "sim:insufflation-change:20:1", "--out", str(out), check=False)
    assert bad.returncode == 2 and "nonsense" in bad.stderr and "Traceback" not in bad.stderr


#: ``wrenchd recovery`` writes every figure rounded to 4 decimals (half a unit: 5e-5)
HALF_UNIT = 5e-5


def ratio_of_rounded(num: float, den: float) -> tuple[float, float]:
    """``num / den`` recomputed from two 4-decimal figures, and how far it may lie from the
    command's own 4-decimal ratio of the unrounded values: each input is off by at most
    ``HALF_UNIT``, which moves the quotient by at most ``HALF_UNIT (1 + |num / den|) / (den -
    HALF_UNIT)``, and the command's ratio is itself rounded (one more ``HALF_UNIT``)."""
    ratio = num / den
    return ratio, HALF_UNIT * (1.0 + abs(ratio)) / (den - HALF_UNIT) + HALF_UNIT + 1e-12


def test_recovery_measures_each_seed_and_refuses_bad_settings(tmp_path):
    out = tmp_path / "recovery.json"
    run = wrenchd("recovery", "--seeds", "5", "--set", '{"adaptation": {"refit_shrink": 0}}',
                  "--settled", "--bins", "40", "--duration", "160", "--json", str(out))
    result = json.loads(out.read_text())
    (row,) = result["rows"]
    assert row["seed"] == 5 and row["contact_offered"] == 0 and row["offered"] > 10_000
    assert 0.05 < row["free_offered_after"] < 1.0
    # the ratio is the command's, of the unrounded levels: recomputed from the rounded ones
    # it agrees to their rounding (pre 1.3589, post 1.1812 gave 0.8693 against 0.8692)
    assert 0.5 < row["pre_n"] < 2.0
    ratio, tol = ratio_of_rounded(row["post_n"], row["pre_n"])
    assert row["ratio"] == pytest.approx(ratio, abs=tol)
    assert result["summary"][0]["within_target"] == int(row["ratio"] <= 1.10)
    assert "mean ratio" in run.stdout
    # the same seed at 20 mmHg throughout: a level of its own, the excess over it
    assert 0.5 < row["settled_post_n"] < 2.0
    excess, tol = ratio_of_rounded(row["post_n"], row["settled_post_n"])
    assert row["excess"] == pytest.approx(excess, abs=tol)
    assert "excess over settled" in run.stdout
    # per 40 s bin from the change (64 s, 40 % of 160 s) to the end: 64, 104, 144 (partial)
    assert result["change_s"] == 64.0 and row["bins_start_s"] == [64.0, 104.0, 144.0]
    assert all(0.2 < v < 3.0 for v in row["post_bins_n"] + row["settled_bins_n"])
    for got, post, settled in zip(row["excess_bins"], row["post_bins_n"],
                                  row["settled_bins_n"]):
        excess, tol = ratio_of_rounded(post, settled)
        assert got == pytest.approx(excess, abs=tol)
    # the settled series is another replay, not the change session's numbers again: its four
    # levels cannot all coincide with the change session's to 4 decimals
    assert ([row["settled_post_n"], *row["settled_bins_n"]]
            != [row["post_n"], *row["post_bins_n"]])
    assert "excess over settled per 40 s bin from 64 s" in run.stdout
    for args, word in ((["--set", "[1]"], "JSON object"),
                       (["--bins", "0"], "--bins must be a positive"),
                       (["--set", '{"gate": {"enter_sigma": -1}}'], "enter_sigma"),
                       # too short on its face: refused before simulating
                       (["--duration", "100"], "leaves 60 s after it"),
                       # long enough on its face, but contacts leave < 60 s of free motion
                       (["--duration", "110"], "session ends before 60 s of free motion")):
        bad = wrenchd("recovery", "--seeds", "5", *args, check=False)
        assert bad.returncode == 2, bad.stderr
        assert word in bad.stderr and "Traceback" not in bad.stderr
