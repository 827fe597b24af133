"""``wrenchd compare --model BUNDLE`` on a concatenation of real recordings: each row gains
``setup_changes[]`` (free-motion tip force before and after the change), the change is
announced to the pipeline only with ``--announce``; ``recovery --session`` and ``inspect`` take
the same session; the windows and the contacts-found count on arrays whose answer is known."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wrenchd.models.series import Session
from wrenchd.service.replay.events_scored import contact_detection, setup_change_levels

CLI = [sys.executable, "-m", "wrenchd"]


def _run(*args, timeout: float = 240.0) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def bundle(wpi_data, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fit") / "bundle"
    done = _run("fit", str(wpi_data / "one_no_weight.csv"), "-o", str(out), "--quiet")
    assert done.returncode == 0, done.stderr
    return out


def test_compare_with_a_bundle_measures_the_set_up_change(bundle, wpi_data, tmp_path):
    a, b = wpi_data / "one_no_weight.csv", wpi_data / "one_205g_parallel.csv"
    spec = f"concat:{a},{b}*3"                    # the change at 30 s, 120 s in all
    out = tmp_path / "cmp"
    done = _run("compare", "--policies", "gated,frozen", "--model", str(bundle), "--sessions",
                spec, "--out", str(out))
    assert done.returncode == 0, done.stderr
    rows = json.loads((out / "compare.json").read_text())
    assert [r["policy"] for r in rows] == ["gated", "frozen"]
    for r in rows:
        assert r["session"] == spec and r["counters"]["errors"] == 0
        (c,) = r["setup_changes"]
        assert c["at_s"] == pytest.approx(5999 * 0.005)
        assert c["id"] == "recording:one_205g_parallel.csv"
        # every sample is free motion: 30 s before, the 30 s from 90 s on (to the end) less
        # the first second after the seam at 90 s
        assert c["before_samples"] == 5999 and 5780 <= c["after_samples"] <= 5800
        # tip force where the truth is zero: tenths of a newton to a few newtons, not 0
        assert 0.05 < c["before_N"] < 5.0 and 0.05 < c["after_N"] < 5.0, c
        assert c["ratio"] == pytest.approx(c["after_N"] / c["before_N"])
        assert r["setup_changes"] and not r["announced"]
        assert r["counters"]["setup_changes"] == 0                       # not announced
    # the same model before the change: the frozen policy never adapts
    frozen = rows[1]
    assert frozen["final_model_version"] == 0
    assert "set-up change" in (out / "compare.md").read_text()
    assert (out / "concat_one_no_weight.csv_one_205g_parallel.csv_3.png").is_file()


def test_compare_announces_the_change_only_when_asked(bundle, wpi_data, tmp_path):
    a, b = wpi_data / "one_no_weight.csv", wpi_data / "two.csv"
    out = tmp_path / "cmp"
    done = _run("compare", "--policies", "frozen", "--model", str(bundle), "--announce",
                "--sessions", f"concat:{a},{b}", "--out", str(out))
    assert done.returncode == 0, done.stderr
    (row,) = json.loads((out / "compare.json").read_text())
    assert row["announced"] and row["counters"]["setup_changes"] == 1
    c = row["setup_changes"][0]
    assert c["after_N"] is None and c["ratio"] is None       # the session ends before 90 s


def test_setup_change_windows_and_contacts_found_on_known_arrays():
    """A change at 100 s; the published force is 1 N before it, 3 N from 160 s on, 50 N in
    contact (left out); two episodes over 2 N, one flagged."""
    from wrenchd.models.series import GroundTruth, JointStates

    t = np.arange(0, 200.0, 0.01)
    n = len(t)
    contact = ((t >= 120) & (t < 122)) | ((t >= 170) & (t < 171)) | ((t >= 175) & (t < 176))
    force = np.where(t < 100, 1.0, np.where(t >= 160, 3.0, 2.0))
    force[contact] = 50.0
    wrench = np.zeros((n, 6))
    wrench[:, 1] = force
    zeros = np.zeros((n, 6))
    true_wrench = zeros.copy()
    true_wrench[contact, 0] = 4.0
    true_wrench[(t >= 175) & (t < 176), 0] = 1.5                           # a weak one
    truth = GroundTruth(zeros, zeros, zeros, zeros, zeros, true_wrench, contact)
    session = Session(JointStates(t, zeros, zeros, zeros), truth,
                      {"setup_changes": [{"id": "x", "t_s": 100.0}]})
    (c,) = setup_change_levels(t, wrench, np.arange(n), session)
    assert c["before_N"] == pytest.approx(1.0) and c["after_N"] == pytest.approx(3.0)
    assert c["ratio"] == pytest.approx(3.0)
    assert c["after_samples"] == 3000 - 200                 # 160-190 s less two contacts
    flagged = (t >= 121) & (t < 121.5)
    found = contact_detection(t, flagged, np.linalg.norm(true_wrench[:, :3], axis=1),
                              contact, judged_from_s=60.0)
    assert (found["episodes"], found["found"], found["missed"]) == (2, 1, 1)
    assert found["missed_episodes"][0]["start_s"] == pytest.approx(170.0)


def test_the_first_second_after_a_seam_of_recordings_is_left_out_of_the_windows():
    """A concat's seams (the joints jump there) spike the estimate: 20 N for the first second
    after each seam, at 80 s and 170 s, would dominate both windows; the measure skips them."""
    from wrenchd.models.series import JointStates
    from wrenchd.service.replay.events_scored import SEAM_SKIP_S

    t = np.arange(0, 200.0, 0.01)
    zeros = np.zeros((len(t), 6))
    force = np.where(t < 100, 1.0, 2.0)
    for seam in (80.0, 170.0):
        force[(t >= seam) & (t < seam + SEAM_SKIP_S)] = 20.0
    wrench = zeros.copy()
    wrench[:, 2] = force
    meta = {"setup_changes": [{"id": "x", "t_s": 100.0}], "seams_s": [80.0, 100.0, 170.0]}
    (c,) = setup_change_levels(t, wrench, np.arange(len(t)), Session(
        JointStates(t, zeros, zeros, zeros), None, meta))
    assert c["before_N"] == pytest.approx(1.0) and c["after_N"] == pytest.approx(2.0)
    assert c["before_samples"] == 3000 - 100 and c["after_samples"] == 3000 - 100
    # without the seams recorded, the spikes count
    (raw,) = setup_change_levels(t, wrench, np.arange(len(t)), Session(
        JointStates(t, zeros, zeros, zeros), None, {"setup_changes": meta["setup_changes"]}))
    assert raw["before_N"] > 3.0


def test_recovery_and_inspect_take_a_concat_of_recordings(bundle, wpi_data, tmp_path):
    a, b = wpi_data / "one_no_weight.csv", wpi_data / "one_205g_parallel.csv"
    spec = f"concat:{a},{b}*4"                    # the change at 30 s, 150 s in all
    out = tmp_path / "recovery.json"
    done = _run("recovery", "--model", str(bundle), "--session", spec, "--json", str(out))
    assert done.returncode == 0, done.stderr
    (row,) = json.loads(out.read_text())["rows"]
    assert row["session"] == spec and row["change_s"] == pytest.approx(5999 * 0.005)
    assert 0.05 < row["pre_n"] < 5.0 and 0.05 < row["post_n"] < 5.0
    assert row["contact_offered"] == 0                         # free motion throughout
    info = json.loads(_run("inspect", spec).stdout)
    assert info["samples"] == 5 * 5999 and info["truth"]
    assert [c["id"] for c in info["setup_changes"]] == ["recording:one_205g_parallel.csv"]
    refused = _run("recovery", "--model", str(bundle), "--session", str(a))
    assert refused.returncode == 2 and "has no truth" in refused.stderr


def test_replay_scores_an_injected_session_like_a_simulated_one(bundle, wpi_data):
    from wrenchd.service.pipeline import PipelineConfig
    from wrenchd.service.pipeline.step1 import load_free_space
    from wrenchd.service.replay.loop import replay
    from wrenchd.service.replay.metrics import replay_metrics
    from wrenchd.service.replay.policies import get_policy
    from wrenchd.service.replay.source import load_session

    a, b = wpi_data / "two.csv", wpi_data / "one_no_weight.csv"
    session = load_session(f"inject:3:concat:{a},{b}*2")    # 90 s, contacts from 60 s
    r = replay(session, load_free_space(str(bundle)),
               get_policy("gated").configure(PipelineConfig()), policy="gated")
    m = replay_metrics(r, session)
    contact = m["truth"]["force_rmse_N"]["contact"]
    assert contact is not None and 0.0 < contact < 20.0
    assert m["gate"]["recall"] is not None and m["contamination"]["offered"] > 0
    found = m["contacts_found"]
    assert found["episodes"] >= 1 and found["found"] + found["missed"] == found["episodes"]
    (change,) = m["setup_changes"]
    assert change["at_s"] == pytest.approx(5999 * 0.005) and change["before_N"] > 0


def test_a_weak_contact_under_the_gate_s_bounds_is_kept_out_of_training(bundle, wpi_data,
                                                                         tmp_path):
    """Real motion with injected contacts (seed 3): a 1.2 N contact 2 s after the calibration
    is too weak for the gate's bounds; its form (a tip force explains its residual) keeps it
    out of training, and only with the watch off does it train."""
    spec = f"inject:3:concat:{wpi_data / 'two.csv'}*4,{wpi_data / 'one_no_weight.csv'}*4"
    off = tmp_path / "off.toml"
    off.write_text("[gate]\nweak_contact_s = 0.0\n")
    rows = {}
    for name, extra in (("on", ()), ("off", ("--config", str(off)))):
        out = tmp_path / name
        done = _run("compare", "--policies", "gated", "--model", str(bundle), "--sessions",
                    spec, "--out", str(out), *extra)
        assert done.returncode == 0, done.stderr
        (rows[name],) = json.loads((out / "compare.json").read_text())
    assert rows["off"]["contamination"]["in_contact_after_calibration"] > 50
    assert rows["on"]["contamination"]["in_contact_after_calibration"] == 0
    assert rows["on"]["counters"]["held_back"] > 0 == rows["off"]["counters"]["held_back"]
    for row in rows.values():          # the detector itself does not change
        assert row["gate_detector"]["missed_over_N"] == 0
