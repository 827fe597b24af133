"""`wrenchd patient-gap` as a real subprocess on the committed paper-scale cells: one trial,
the patient's own 30 s of free motion."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from wrenchd.service.studies.reproduction_cells import load_cell
from wrenchd.service.studies.reproduction_config import PAPER

RUN = Path(__file__).resolve().parents[3] / "reports" / "paper-scale"


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "wrenchd", "patient-gap", *args],
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})


def test_one_trial_against_its_own_patient(tmp_path):
    done = _run("--run", str(RUN), "--trials", "1", "--lengths", "30", "--max-epochs", "5",
                "--step1-trials", "2", "--threads", "1", "--out", str(tmp_path))
    assert done.returncode == 0, done.stderr
    r = json.loads((tmp_path / "results.json").read_text())
    rows = r["per_trial"]
    assert set(rows) == {"oracle (raw)", "Seal", "Troc (other patients)",
                         "Base+Corr (other patients)", "Seal+Corr (other patients)",
                         "Seal+Xfer (other patients)", "own Corr (30 s)",
                         "wrenchd online (30 s)", "wrenchd online, net only (30 s)"}
    assert all(len(row["rmse"]) == 1 for row in rows.values())
    # the run's figures for the trial are its cell's, as the paper-scale report has them
    cell = load_cell(RUN / "cells", PAPER, 0, 1013.0)
    expected = cell.scores.contact["Seal+Xfer"]["truth"]["rmse"][0, :3].mean()
    assert rows["Seal+Xfer (other patients)"]["rmse"][0] == expected
    # nothing beats the simulator's noise-free torque: every row sits above the floor
    floor = rows["oracle (raw)"]["rmse"][0]
    assert 0.05 < floor < 0.3
    assert min(row["rmse"][0] for name, row in rows.items() if name != "oracle (raw)") > floor
    # the daemon's pipeline adapted on the patient's own motion before the trial (versions)
    # and its body wall physics took most of what step 1 misses (measured 0.19 N vs 1.59 N)
    online = rows["wrenchd online (30 s)"]
    assert online["version_at_trial"][0] >= 1
    assert online["rmse"][0] < 0.5 * rows["Seal"]["rmse"][0]
    s = r["summary"]["Seal"]
    assert np.isclose(s["ratio_raw_floor"], rows["Seal"]["rmse"][0] / floor)
    # step 1 in its domain: Base's free space has no seal nor wall, so whose patient it is
    # changes nothing; Seal's seal is the patient's
    step1 = r["step1"]
    base = [step1[f"Base: {p}"]["rmse"] for p in (
        "unseen patients", "its training patients, the same motion",
        "the fixed default patient, the same motion")]
    assert len(base[0]) == 2 and base[0] == base[1] == base[2]
    seal = [step1[f"Seal: {p}"]["rmse"] for p in (
        "unseen patients", "its training patients, the same motion")]
    assert seal[0] != seal[1]
    assert all(row["ratio_raw_floor"] > 1.0 for row in step1.values())
    text = (tmp_path / "README.md").read_text()
    assert "| wrenchd online (30 s) |" in text and r["command"].startswith("wrenchd patient-gap")
    assert "| Seal: unseen patients |" in text


def test_a_folder_without_cells_is_refused(tmp_path):
    done = _run("--run", str(tmp_path), "--out", str(tmp_path / "out"))
    assert done.returncode == 2
    assert "no cells of a paper-scale run" in done.stderr
