"""Sessions made of the real WPI recordings: a concatenation's time and set-up changes, a
simulated trocar and contacts injected into real efforts (the added effort is exactly the
truth's torque, ``J^T f`` checked against the kinematics), and a rosbag2 directory that the
rosbags library writes, replayed."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from tests.support import ros2_bag_from
from wrenchd.adapters.csv_psm import read_wpi_csv
from wrenchd.adapters.sim.injection import LENGTH_S, PEAK_N, inject
from wrenchd.models.physics.kinematics import PSMKinematics
from wrenchd.models.series import Session
from wrenchd.service.replay.source import announced_changes, load_session

DT = 0.005                                   # the WPI recordings' sample spacing [s]


def test_a_concat_of_two_recordings_is_continuous_and_records_its_set_up_change(wpi_data):
    a, b = wpi_data / "one_no_weight.csv", wpi_data / "one_205g_parallel.csv"
    s = load_session(f"concat:{a}*2,{b}")
    js, n = s.joint_states, 5999
    assert len(js) == 3 * n
    steps = np.diff(js.t)
    assert np.allclose(steps, DT, atol=1e-9), (steps.min(), steps.max())
    plain, _ = read_wpi_csv(a)
    loaded, _ = read_wpi_csv(b)
    np.testing.assert_array_equal(js.effort[n:2 * n], plain.effort)      # the repeat
    np.testing.assert_array_equal(js.effort[2 * n:], loaded.effort)
    # one change, where the file changes (the repeat is none), at its first sample
    (change,) = s.metadata["setup_changes"]
    assert change["t_s"] == pytest.approx(js.t[2 * n], abs=1e-9) == pytest.approx(2 * n * DT)
    assert change["from"] == str(a) and change["to"] == str(b)
    assert s.metadata["seams_s"] == pytest.approx([n * DT, 2 * n * DT])
    assert [t for t, _ in announced_changes(s)] == pytest.approx([2 * n * DT])
    # truth: free motion throughout
    assert not s.truth.in_contact.any()
    assert not s.truth.external_wrench.any() and not s.truth.external_torque.any()
    np.testing.assert_array_equal(s.truth.internal_torque, js.effort)


def _short(wpi_data, name: str, seconds: float) -> Session:
    js, _ = read_wpi_csv(wpi_data / name)
    return Session(js.slice(0, int(seconds / DT)), None, {"source": name})


def test_inject_adds_exactly_the_trocar_and_j_transpose_f(wpi_data):
    plain = _short(wpi_data, "two.csv", 30.0)
    s = inject(plain, 4, contact_free_s=2.0, every_s=3.0)
    tr = s.truth
    added = s.joint_states.effort - plain.joint_states.effort
    trocar = tr.effects["seal_friction"] + tr.effects["body_wall"]
    np.testing.assert_allclose(added, trocar + tr.external_torque, atol=1e-12)
    np.testing.assert_allclose(tr.external_torque, tr.effects["external_contact"], atol=0)
    # the trocar acts on yaw, pitch (wall), insertion and roll (seal), never on the wrist
    assert np.all(np.abs(trocar[:, :4]).max(axis=0) > 0) and not trocar[:, 4:].any()
    np.testing.assert_allclose(tr.internal_torque, plain.joint_states.effort + trocar,
                               atol=1e-12)
    # J^T f from the kinematics, independently, on a few contact samples
    rows = np.flatnonzero(tr.in_contact)
    assert rows.size > 0
    kin = PSMKinematics()
    for i in rows[:: max(len(rows) // 7, 1)]:
        jac = kin.jacobian(plain.joint_states.position[i], frame="hybrid")
        np.testing.assert_allclose(tr.external_torque[i], jac.T @ tr.external_wrench[i],
                                   atol=1e-9)
    assert not tr.external_wrench[:, 3:].any()                   # a force at the tip only
    assert not tr.external_torque[~tr.in_contact].any()
    # the episodes as drawn: 1-6 N peaks, 0.5-4 s, free motion between, after the calibration
    episodes = s.metadata["injection"]["episodes"]
    assert episodes
    force = np.linalg.norm(tr.external_wrench[:, :3], axis=1)
    t = s.joint_states.t
    for e, nxt in zip(episodes, episodes[1:] + [None]):
        assert PEAK_N[0] <= e["peak_n"] <= PEAK_N[1]
        assert LENGTH_S[0] <= e["end_s"] - e["start_s"] <= LENGTH_S[1]
        assert np.linalg.norm(e["direction"]) == pytest.approx(1.0)
        inside = (t >= e["start_s"]) & (t < e["end_s"])
        assert force[inside].max() == pytest.approx(e["peak_n"], rel=1e-9)
        if nxt is not None:
            assert nxt["start_s"] >= e["end_s"] + 1.0
            assert not tr.in_contact[(t >= e["end_s"]) & (t < nxt["start_s"])].any()
    assert episodes[0]["start_s"] >= 3.0
    assert s.metadata["patient"]["draw"]["body_wall"]["pressure_mmhg"] > 0
    # one seed, one draw
    again = inject(plain, 4, contact_free_s=2.0, every_s=3.0)
    np.testing.assert_array_equal(again.joint_states.effort, s.joint_states.effort)
    other = inject(plain, 5, contact_free_s=2.0, every_s=3.0)
    assert other.metadata["patient"]["draw"] != s.metadata["patient"]["draw"]


def test_inject_of_a_concat_spec_keeps_its_set_up_change(wpi_data):
    a, b = wpi_data / "two.csv", wpi_data / "one_no_weight.csv"
    plain = load_session(f"concat:{a},{b}*2")
    s = load_session(f"inject:3:concat:{a},{b}*2")
    assert s.metadata["setup_changes"] == plain.metadata["setup_changes"]
    assert s.metadata["source"] == f"inject:3:concat:{a},{b}*2"
    added = s.joint_states.effort - plain.joint_states.effort
    truth_torque = (s.truth.internal_torque - plain.truth.internal_torque
                    + s.truth.external_torque)
    np.testing.assert_allclose(added, truth_torque, atol=1e-12)
    # the pipeline's minute of calibration is contact-free
    assert not s.truth.in_contact[s.joint_states.t < 60.0].any()
    assert s.truth.in_contact.any()


def test_a_rosbag2_directory_replays(wpi_data, tmp_path):
    js, _ = read_wpi_csv(wpi_data / "one_no_weight.csv")
    short = js.slice(0, 2000)                                          # 10 s
    bag = ros2_bag_from(short, tmp_path / "rosbag2_psm1")
    s = load_session(str(bag))
    np.testing.assert_allclose(s.joint_states.effort, short.effort)
    np.testing.assert_allclose(s.joint_states.t - s.joint_states.t[0], short.t, atol=1e-9)
    assert s.metadata["recording"]["kind"] == "rosbag"
    twice = load_session(f"concat:{bag}*2")
    assert len(twice.joint_states) == 4000 and not twice.metadata["setup_changes"]
    done = subprocess.run([sys.executable, "-m", "wrenchd", "replay", str(bag), "--policy",
                           "frozen", "--report", str(tmp_path / "rep")],
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    m = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    assert m["samples"] == 2000 and m["counters"]["errors"] == 0
    assert m["source"] == str(bag)
