"""``wrenchd real-robot --quick`` on the real WPI recordings: every part of the report runs
(newtons, known loads, a set-up change under two policies, an injected session)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def test_the_real_robot_report_runs_end_to_end(wpi_data, tmp_path):
    out = tmp_path / "real-robot"
    done = subprocess.run([sys.executable, "-m", "wrenchd", "real-robot", "--quick", "--data",
                           str(wpi_data), "--out", str(out)],
                          check=False, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    r = json.loads((out / "report.json").read_text())
    tip = r["step1"]["test_file"]["tip_force_N"]
    assert {"measured_cf", "ls", "ls_causal", "hybrid"} <= set(tip)
    # Least squares is deterministic; the raw effort is what the dVRK itself publishes.
    assert tip["ls"]["rms"] == pytest.approx(1.563, rel=0.02)
    assert tip["hybrid"]["rms"] < tip["measured_cf"]["rms"] / 3
    loads = r["step1"]["known_loads"]
    assert [round(x["mass_kg"], 3) for x in loads] == [0.105, 0.205, 0.105, 0.205]
    assert [round(x["rate_hz"]) for x in loads] == [200, 200, 100, 100]
    # the full-speed loads, least squares on their photographed point (measured 94 g, 211 g)
    assert 0.085 < loads[0]["models"]["ls"]["fitted_mass_kg"] < 0.105
    assert 0.195 < loads[1]["models"]["ls"]["fitted_mass_kg"] < 0.225
    # the two pairs of runs on one path, each differing by 100 g (the efforts alone: 118, 112 g)
    pairs = r["step1"]["known_load_pairs"]
    assert [p["rate_hz"] for p in pairs] == [pytest.approx(200.0), pytest.approx(100.0)]
    for p in pairs:
        assert p["expected_difference_kg"] == pytest.approx(0.1)
        assert 0.105 < p["fitted_difference_kg"]["effort"] < 0.125
    # the served pipeline on two.csv: the correction net's calibration minute, then after it
    gated, frozen = r["served"]
    assert (gated["policy"], frozen["policy"]) == ("gated", "frozen")
    assert gated["after"]["samples"] > 5000 and frozen["after"]["rms"] > 0.5
    policies = [row["policy"] for row in r["setup_change"]]
    assert policies == ["gated", "frozen"]
    for row in r["setup_change"]:
        (change,) = row["setup_changes"]
        assert change["at_s"] == pytest.approx(30.0, abs=0.01)
        assert change["before_N"] is not None and change["before_N"] > 0.0
    frozen = r["setup_change"][1]
    assert frozen["final_model_version"] == 0
    # the after window's reference: step 1 fitted on each run's first 20 s, scored on the rest
    ref = r["setup_change_reference"]["files"]
    assert set(ref) == {"one_no_weight.csv", "one_205g_parallel.csv"}
    for v in ref.values():
        assert 0.1 < v["rms"] < 2.0 and v["p95"] > v["rms"]
    (injected,) = r["injected"]
    assert injected["session"].startswith("inject:3:concat:")
    assert "contamination" in injected and "false_force_N" in injected
    text = (out / "report.md").read_text()
    for title in ("Newtons at the tip", "Known loads", "The served estimate", "A real set-up change",
                  "simulated trocar and contacts"):
        assert title in text
    assert (out / "bundle" / "manifest.json").is_file()
    assert list((out / "setup-change").glob("*.png")) and (out / "injected" / "compare.json").is_file()
