"""Patient variation: draws inside their ranges, one per session, recorded; the fixed patient
and the motion, contacts and noise of a seed left as they are."""

import numpy as np
import pytest

from wrenchd.adapters.sim.patients import (
    REALISTIC_HANDLE_NM_PER_RAD,
    PatientRanges,
    draw_patient,
    fixed_patient,
)
from wrenchd.adapters.sim.scenarios import run_scenario, session_patient
from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.effects.seal import SealParams


def test_draws_stay_inside_the_ranges_and_spread_over_them():
    ranges = PatientRanges()
    rng = np.random.default_rng(0)
    draws = [draw_patient(ranges, rng) for _ in range(400)]
    fc = np.array([d["seal_friction"]["fc"][0] for d in draws])
    p = np.array([d["body_wall"]["pressure_mmhg"] for d in draws])
    inc = np.array([d["body_wall"]["incision_m"] for d in draws])
    for values, (lo, hi) in ((fc, ranges.seal_fc_n), (p, ranges.pressure_mmhg),
                             (inc[:, 2], ranges.incision_depth_m)):
        assert values.min() >= lo and values.max() <= hi
        assert values.max() - values.min() > 0.8 * (hi - lo)      # not stuck at one value
    assert np.abs(inc[:, :2]).max() <= ranges.incision_offset_m
    # the roll level moves with the insertion level: the default's radius ratio kept
    roll = np.array([d["seal_friction"]["fc"][1] for d in draws])
    np.testing.assert_allclose(roll / fc, SealParams().fc[1] / SealParams().fc[0], rtol=1e-12)
    with pytest.raises(ValueError, match="low <= high"):
        PatientRanges(pressure_mmhg=(15.0, 8.0))


def test_fixed_patient_is_the_default_and_variation_changes_only_the_patient():
    fixed = run_scenario("trocar-contact", 12.0, seed=3)
    again = run_scenario("trocar-contact", 12.0, seed=3)
    varied = run_scenario("trocar-contact", 12.0, seed=3, patients=PatientRanges())
    np.testing.assert_array_equal(fixed.joint_states.effort, again.joint_states.effort)
    assert fixed.metadata["patient"] == {"variation": False, "ranges": None,
                                         "draw": fixed_patient()}
    # same motion and contact times; other seal and wall torques
    np.testing.assert_array_equal(fixed.joint_states.position, varied.joint_states.position)
    np.testing.assert_array_equal(fixed.truth.in_contact, varied.truth.in_contact)
    assert not np.allclose(fixed.truth.effects["body_wall"], varied.truth.effects["body_wall"])
    assert not np.allclose(fixed.truth.effects["seal_friction"],
                           varied.truth.effects["seal_friction"])
    draw = varied.metadata["patient"]["draw"]
    assert varied.metadata["patient"]["variation"] is True
    physics = {e["name"]: e["params"] for e in varied.metadata["physics_model"]["effects"]}
    assert physics["body_wall"]["pressure_mmhg"] == pytest.approx(
        draw["body_wall"]["pressure_mmhg"])
    assert physics["seal_friction"]["fc"] == pytest.approx(draw["seal_friction"]["fc"])


def test_every_seed_is_another_patient():
    draws = [run_scenario("trocar", 2.0, seed=s, patients=PatientRanges()
                          ).metadata["patient"]["draw"] for s in range(6)]
    pressures = {round(d["body_wall"]["pressure_mmhg"], 9) for d in draws}
    assert len(pressures) == 6
    same = run_scenario("trocar", 2.0, seed=4, patients=PatientRanges())
    assert same.metadata["patient"]["draw"] == draws[4]


def test_realistic_handle_gives_contact_torques_of_the_papers_order():
    legacy = run_scenario("trocar-contact", 45.0, seed=51000)
    stiff = run_scenario("trocar-contact", 45.0, seed=51000,
                         handle_nm_per_rad=REALISTIC_HANDLE_NM_PER_RAD)
    c = legacy.truth.in_contact
    rms_legacy = np.sqrt(np.mean(legacy.truth.external_wrench[c, 3:] ** 2, axis=0))
    rms = np.sqrt(np.mean(stiff.truth.external_wrench[c, 3:] ** 2, axis=0))
    # the torque scales with the stiffness; the forces stay as they were
    np.testing.assert_allclose(rms / rms_legacy, REALISTIC_HANDLE_NM_PER_RAD / 0.05, rtol=1e-9)
    np.testing.assert_array_equal(legacy.truth.external_wrench[:, :3],
                                  stiff.truth.external_wrench[:, :3])
    # the paper's torque RMSEs are 0.06-0.12 N m: the contact torques reach that order
    assert rms.max() > 0.06 and rms_legacy.max() < 0.04
    assert stiff.metadata["scenario"]["handle_nm_per_rad"] == REALISTIC_HANDLE_NM_PER_RAD


def test_no_contact_scenario_can_record_the_sensor_channel():
    s = run_scenario("trocar", 5.0, seed=2, force_sensor=True)
    plain = run_scenario("trocar", 5.0, seed=2)
    assert plain.truth.sensor_wrench is None
    np.testing.assert_array_equal(s.joint_states.effort, plain.joint_states.effort)
    assert s.truth.sensor_wrench[:, :3].std() == pytest.approx(0.02, rel=0.1)   # noise only


def test_a_given_patient_is_that_patient_on_other_motion():
    first = run_scenario("trocar", 4.0, seed=11, patients=PatientRanges())
    draw = first.metadata["patient"]["draw"]
    same = run_scenario("trocar", 4.0, seed=11, patient=draw)
    np.testing.assert_array_equal(first.joint_states.effort, same.joint_states.effort)
    other = run_scenario("trocar", 4.0, seed=12, patient=draw)
    assert other.metadata["patient"]["draw"] == draw
    assert other.metadata["patient"]["variation"] is True
    assert not np.allclose(other.joint_states.position, first.joint_states.position)
    drawn = run_scenario("trocar", 4.0, seed=12, patients=PatientRanges())
    assert drawn.metadata["patient"]["draw"] != draw
    assert session_patient(11, PatientRanges()) == draw          # without simulating
    assert session_patient(12, PatientRanges()) == drawn.metadata["patient"]["draw"]
    with pytest.raises(ConfigError, match="excludes"):
        run_scenario("trocar", 4.0, seed=12, patient=draw, patients=PatientRanges())
