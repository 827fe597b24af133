"""The simulated PSM and its scenarios: ground truth that adds up, determinism, workspaces."""

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import SCENARIOS, run_scenario
from wrenchd.adapters.sim.simulator import SimulatorConfig
from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.model import PhysicsModel

REQUIRED = {"free-space", "free-space-seal", "trocar", "trocar-contact",
            "insufflation-change", "instrument-drift"}


@pytest.fixture(scope="module")
def sessions():
    return {name: run_scenario(name, 40.0, seed=11) for name in sorted(REQUIRED)}


def test_all_scenarios_exist(sessions):
    assert REQUIRED <= set(SCENARIOS)
    for name, s in sessions.items():
        assert len(s.joint_states) == 8000, name                       # 40 s at 200 Hz
        np.testing.assert_allclose(np.diff(s.joint_states.t), 0.005, atol=1e-12)
        assert s.metadata["scenario"]["name"] == name


def test_effort_is_internal_plus_external_plus_noise(sessions):
    s = sessions["trocar-contact"]
    truth = s.truth
    noise = s.joint_states.effort - truth.internal_torque - truth.external_torque
    expected = np.array(SimulatorConfig().sensors.effort_noise_std)
    np.testing.assert_allclose(noise.std(axis=0), expected, rtol=0.05)
    assert np.abs(noise.mean(axis=0)).max() < 4 * expected.max() / np.sqrt(len(noise))
    internal = sum(v for k, v in truth.effects.items() if k != "external_contact")
    np.testing.assert_allclose(internal, truth.internal_torque, atol=1e-12)
    np.testing.assert_allclose(truth.effects["external_contact"], truth.external_torque, atol=1e-12)


def test_effect_sets_match_the_scenario(sessions):
    has = {name: set(s.truth.effects) for name, s in sessions.items()}
    assert "seal_friction" not in has["free-space"] and "body_wall" not in has["free-space"]
    assert "seal_friction" in has["free-space-seal"] and "body_wall" not in has["free-space-seal"]
    for name in ("trocar", "trocar-contact", "insufflation-change", "instrument-drift"):
        assert {"seal_friction", "body_wall"} <= has[name], name
    assert "insufflation_step" in has["insufflation-change"]
    assert {"seal_wear", "wrist_wear"} <= has["instrument-drift"]


def test_insufflation_high_is_the_change_session_at_the_new_pressure_throughout():
    """Same seed: the same motion, contacts and noise; the body wall's torque as the change
    session's after its step, before it as well (the reference of ``wrenchd recovery``)."""
    change = run_scenario("insufflation-change", 80.0, seed=5)
    high = run_scenario("insufflation-high", 80.0, seed=5)
    np.testing.assert_array_equal(change.joint_states.position, high.joint_states.position)
    assert change.truth.in_contact.any()                       # contacts after 60 s
    np.testing.assert_array_equal(change.truth.in_contact, high.truth.in_contact)
    step = change.joint_states.t >= 32.0                       # the step at 40 % of 80 s

    def wall(s):
        return s.truth.effects["body_wall"] + s.truth.effects["insufflation_step"]
    np.testing.assert_allclose(wall(change)[step], wall(high)[step], atol=1e-9)
    ratio = np.abs(wall(high)[~step, :2]).sum() / np.abs(wall(change)[~step, :2]).sum()
    assert ratio == pytest.approx((100 + 40 * 20) / (100 + 40 * 12), rel=0.05)  # k(p), N/m


def test_contacts_only_where_expected(sessions):
    for name in ("free-space", "free-space-seal", "trocar"):
        assert not sessions[name].truth.in_contact.any(), name
        assert sessions[name].truth.sensor_wrench is None
    s = sessions["trocar-contact"]
    frac = s.truth.in_contact.mean()
    assert 0.1 < frac < 0.6
    force = np.linalg.norm(s.truth.external_wrench[:, :3], axis=1)
    assert force[~s.truth.in_contact].max() == 0.0
    assert 1.0 < force.max() <= 8.0                                   # N
    sensor_err = s.truth.sensor_wrench - s.truth.external_wrench
    assert sensor_err[:, :3].std() == pytest.approx(0.02, rel=0.1)


def test_insufflation_step_happens_at_forty_percent(sessions):
    s = sessions["insufflation-change"]
    step = s.truth.effects["insufflation_step"]
    t = s.joint_states.t
    assert np.abs(step[t < 16.0]).max() == 0.0
    # 12 -> 20 mmHg (the upper end of clinical insufflation) raises the wall stiffness from
    # 580 to 900 N/m: +55 % of its torque
    late = t >= 16.0
    ratio = np.abs(step[late]).max() / np.abs(s.truth.effects["body_wall"][late]).max()
    assert ratio == pytest.approx(320 / 580, rel=0.15)


def test_instrument_drift_grows_seal_friction(sessions):
    s = sessions["instrument-drift"]
    wear = s.truth.effects["seal_wear"][:, 2]
    seal = s.truth.effects["seal_friction"][:, 2]
    t = s.joint_states.t
    early, late = t < 4.0, t > 36.0
    assert np.abs(wear[early]).max() == 0.0
    ratio = np.abs(seal[late] + wear[late]).mean() / np.abs(seal[late]).mean()
    assert ratio == pytest.approx(1.6, rel=0.1)


def test_workspaces_respected_and_covered(sessions):
    for name, s in sessions.items():
        ws = SCENARIOS[name].workspace
        q = s.truth.position
        assert np.all(q >= np.array(ws.lower) - 1e-9) and np.all(q <= np.array(ws.upper) + 1e-9)
        # each joint covers most of its range even in 40 s
        span = (q.max(0) - q.min(0)) / (np.array(ws.upper) - np.array(ws.lower))
        assert span.min() > 0.4, (name, span)


def test_velocity_is_an_encoder_estimate(sessions):
    s = sessions["free-space"]
    err = s.joint_states.velocity - s.truth.velocity
    scale = s.truth.velocity.std(axis=0)
    assert np.all(np.abs(err).max(axis=0) > 0)                       # not the true velocity
    assert np.all(err.std(axis=0) < 0.1 * scale)                      # but close to it
    res = np.array(SimulatorConfig().sensors.encoder_resolution)
    steps = s.joint_states.position / res
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)     # quantised positions


def test_same_seed_same_data_other_seed_other_data():
    a = run_scenario("trocar-contact", 15.0, seed=5)
    b = run_scenario("trocar-contact", 15.0, seed=5)
    c = run_scenario("trocar-contact", 15.0, seed=6)
    np.testing.assert_array_equal(a.joint_states.effort, b.joint_states.effort)
    np.testing.assert_array_equal(a.truth.external_wrench, b.truth.external_wrench)
    assert not np.allclose(a.joint_states.position, c.joint_states.position)


def test_custom_model_replaces_physics():
    model = PhysicsModel.from_dict({"effects": [
        {"name": "payload_mass", "params": {"mass_kg": 0.2}},
        {"name": "external_contact"}]})
    s = run_scenario("trocar-contact", 30.0, seed=2, model=model)
    assert set(s.truth.effects) == {"rigid_body", "payload_mass", "external_contact"}
    assert s.truth.in_contact.any()                     # the scenario's contacts were put in
    assert s.metadata["scenario"]["custom_model"] is True


def test_rates_are_configurable():
    s = run_scenario("free-space", 2.0, seed=1,
                     config=SimulatorConfig(internal_rate_hz=2000, publish_rate_hz=500))
    assert len(s.joint_states) == 1000
    with pytest.raises(ValueError, match="integer multiple"):
        SimulatorConfig(internal_rate_hz=1000, publish_rate_hz=300)
    with pytest.raises(ConfigError, match="unknown scenario"):
        run_scenario("mars", 1.0, seed=0)
    with pytest.raises(ConfigError, match="duration"):
        run_scenario("trocar", 0.0, seed=0)
