"""``wrenchd identify`` and ``wrenchd discrepancy`` as real subprocesses.

Real data (skipped without the WPI recordings): identify on one_no_weight.csv, discrepancy
against one_205g_parallel.csv. Simulated data: an MCAP session with a hidden payload.
"""

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from tests.support import readline_within, stop_within

from wrenchd.models.physics.model import PhysicsModel



def wrenchd(*args, check=True):
    env = dict(os.environ, OMP_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "wrenchd", *args], capture_output=True,
                          text=True, check=check, timeout=300, env=env)


def test_real_load_is_localised_named_and_the_gap_shrinks(tmp_path, wpi_data):
    model = tmp_path / "ident.json"
    wrenchd("identify", "--measured", str(wpi_data / "one_no_weight.csv"), "-o", str(model))
    ident = PhysicsModel.load(model)
    assert {"inertial_delta", "coulomb_friction", "viscous_friction", "joint_offset"} <= set(ident.effects)
    out = tmp_path / "out.json"
    report = tmp_path / "report"
    wrenchd("discrepancy", "--model", str(model), "--measured", str(wpi_data / "one_205g_parallel.csv"),
            "--report", str(report), "--json", str(out))
    res = json.loads(out.read_text())
    # the contract
    assert set(res) >= {"disagreements", "effects", "gap", "updated_model"}
    assert res["gap"]["heldout"] is True and len(res["gap"]["before_rmse"]) == 6
    # the load acts on yaw and pitch (link 2 is upstream of insertion): only they disagree
    assert sorted(d["joint"] for d in res["disagreements"]) == [1, 2]
    assert all(d["rmse"] > d["noise_floor"] for d in res["disagreements"])
    first = res["effects"][0]
    assert first["name"] == "payload_mass" and first["joints"] == [1, 2]
    assert first["evidence"]["delta_bic"] < -100 and first["evidence"]["stability"] >= 0.9
    assert 0.1 < first["params"]["mass_kg"] < 0.4          # 205 g, through an assumed lever arm
    before, after = res["gap"]["before_rmse"], res["gap"]["after_rmse"]
    assert after[0] < 0.7 * before[0] and after[1] < 0.8 * before[1]
    updated = PhysicsModel.load(res["updated_model"])
    assert "payload_mass" in {e.name for e in updated.effects.values()}
    assert (report / "report.md").is_file() and (report / "gap.png").stat().st_size > 1000
    text = (report / "report.md").read_text()
    assert "payload_mass" in text
    # the position was free: the report says the data fix the first moment, not the mass
    moment = np.linalg.norm([first["coefficients"][k] for k in ("m_cx", "m_cy", "m_cz")])
    assert f"|m c| = {1000 * moment:.1f} g m" in text
    assert f"15 cm: {1000 * moment / 0.15:.0f} g" in text


def test_hidden_payload_in_an_mcap_session_and_bad_input(tmp_path):
    given = tmp_path / "given.json"
    given.write_text(json.dumps({"effects": [{"name": "coulomb_friction"},
                                             {"name": "viscous_friction"}]}))
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"effects": [
        {"name": "coulomb_friction"}, {"name": "viscous_friction"},
        {"name": "payload_mass", "params": {"mass_kg": 0.15, "link": 6, "position_m": [0, 0, 0]}}]}))
    session = tmp_path / "s.mcap"
    wrenchd("simulate", "--scenario", "free-space", "--duration", "12", "--seed", "3",
            "--model", str(truth), "-o", str(session))
    out = tmp_path / "out.json"
    proc = wrenchd("discrepancy", "--model", str(given), "--measured", str(session),
                   "--report", str(tmp_path / "r"), "--json", str(out))
    res = json.loads(out.read_text())
    assert [e["label"] for e in res["effects"]] == ["payload_mass@link6"], proc.stdout
    assert res["effects"][0]["params"]["mass_kg"] == pytest.approx(0.15, rel=0.1)
    assert "named: payload_mass@link6" in proc.stdout
    bad = wrenchd("discrepancy", "--model", str(tmp_path / "missing.json"), "--measured",
                  str(session), "--report", str(tmp_path / "r2"), "--json", str(tmp_path / "o2.json"),
                  check=False)
    assert bad.returncode == 2 and "cannot read physics model" in bad.stderr


def test_a_payload_at_a_given_point_gets_its_absolute_mass(tmp_path):
    """A hidden 150 g on the pitch link at a known point: ``--payload-at`` with that point
    gives its mass (the residual is the payload's torque plus the simulator's noise); a bad
    point is refused before any work."""
    given = tmp_path / "given.json"
    given.write_text(json.dumps({"effects": [{"name": "coulomb_friction"},
                                             {"name": "viscous_friction"}]}))
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"effects": [
        {"name": "coulomb_friction"}, {"name": "viscous_friction"},
        {"name": "payload_mass", "params": {"mass_kg": 0.15, "link": 2,
                                            "position_m": [0.0, 0.065, 0.165]}}]}))
    session = tmp_path / "s.mcap"
    wrenchd("simulate", "--scenario", "free-space", "--duration", "12", "--seed", "4",
            "--model", str(truth), "-o", str(session))
    out = tmp_path / "out.json"
    proc = wrenchd("discrepancy", "--model", str(given), "--measured", str(session),
                   "--report", str(tmp_path / "r"), "--json", str(out),
                   "--payload-at", "outer_pitch:0,0.065,0.165",
                   "--payload-at", "outer_pitch:0.1,0,0")
    right, wrong = json.loads(out.read_text())["payload_at"]
    assert right["mass_kg"] == pytest.approx(0.15, rel=0.05), proc.stdout
    assert right["joints"] == [1, 2]
    assert all(a < 0.5 * b for a, b in zip(right["rmse_after"], right["rmse_before"]))
    # a point elsewhere on the link explains almost nothing of it
    assert wrong["rmse_after"][0] > 0.9 * wrong["rmse_before"][0]
    assert "Payloads at given points" in (tmp_path / "r" / "report.md").read_text()
    bad = wrenchd("discrepancy", "--model", str(given), "--measured", str(session),
                  "--report", str(tmp_path / "r2"), "--json", str(tmp_path / "o2.json"),
                  "--payload-at", "forearm:0,0,0", check=False)
    assert bad.returncode == 2 and "forearm" in bad.stderr and not (tmp_path / "r2").exists()


def _strict(text: str):
    """JSON as any strict parser reads it: NaN and Infinity refused."""
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def test_discrepancy_sweep_writes_the_study_in_strict_json(tmp_path):
    out = tmp_path / "sweep"
    run = wrenchd("discrepancy-sweep", "--seeds", "1", "--none-seeds", "1", "--pairs-seeds", "0",
                  "--duration", "10", "--effects", "payload_mass", "--out", str(out))
    study = _strict((out / "hidden-effects.json").read_text())
    runs = {tuple(r["hidden"]): r for r in study["runs"]}
    assert set(runs) == {(), ("payload_mass",)}
    assert runs[()]["named"] == [] and runs[("payload_mass",)]["named"][0] == "payload_mass"
    s = study["summary"]
    assert s["recall"] == 1.0 and s["false_positive_rate"] == 0.0
    assert s["pairs_passed"] is None                  # no pairs asked for: no rate, not NaN
    assert "--pairs-seeds 0" in (out / "hidden-effects.md").read_text()
    assert "recall 100.0 %" in run.stdout


def test_discrepancy_real_names_the_load_on_both_loaded_runs(tmp_path, wpi_data):
    out = tmp_path / "real"
    wrenchd("discrepancy-real", "--data", str(wpi_data), "--out", str(out))
    summary = _strict((out / "summary.json").read_text())
    for run in ("one_105g_parallel.csv", "one_205g_parallel.csv"):
        assert summary["named"][run][0].startswith("payload_mass")
        assert summary["disagreeing_joints"][run] == [1, 2]      # yaw and pitch
        assert summary["excess_shrink"][run] > 0.3
    # more load, more fitted mass (the ratio itself is off: README, "Finding the missing physics")
    assert 0 < summary["mass_kg"]["105g"] < summary["mass_kg"]["205g"]
    assert (out / "one_205g_parallel" / "report.md").is_file()
    assert PhysicsModel.load(out / "identified_model.json").effects


@pytest.mark.parametrize("extra", [["--cells"], ["--effects", "joint_offset"]])
def test_a_study_stops_between_runs_on_a_signal_and_writes_nothing(tmp_path, extra):
    """SIGINT stops `discrepancy-sweep` (either study) after the run in progress: exit
    130, the stop said on stderr, no partial report."""
    proc = subprocess.Popen([sys.executable, "-m", "wrenchd", "discrepancy-sweep", *extra,
                             "--seeds", "3", "--none-seeds", "3", "--out", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert readline_within(proc, 120.0, "the study").startswith("[1/")
    _, err = stop_within(proc, 60.0, "the study", signal.SIGINT)
    assert proc.returncode == 128 + signal.SIGINT, err
    assert "stopped by SIGINT" in err
    assert not list(tmp_path.iterdir())
