"""Candidate columns are the library's effects, linear in their parameters; merging adds them."""

import numpy as np
import pytest

from wrenchd.models.discrepancy.candidates import PAYLOAD_SITES, bristle_state, build_candidates
from wrenchd.models.discrepancy.merging import merge_effects
from wrenchd.models.discrepancy.residual import noise_floor, white_noise_level
from wrenchd.models.physics.effects import EFFECTS, Motion
from wrenchd.models.physics.effects.seal import seal_force
from wrenchd.models.physics.model import PhysicsModel


@pytest.fixture(scope="module")
def setup():
    model = PhysicsModel.from_dict({"effects": [{"name": "coulomb_friction"},
                                                {"name": "viscous_friction"}]})
    n, dt = 1200, 0.005
    t = np.arange(n) * dt
    w = 2 * np.pi * np.array([0.3, 0.25, 0.2, 0.35, 0.4, 0.45])
    amp = np.array([0.5, 0.4, 0.06, 1.2, 0.6, 0.6])
    center = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
    q = center + amp * np.sin(w * t[:, None])
    dq = amp * w * np.cos(w * t[:, None])
    ddq = -amp * w * w * np.sin(w * t[:, None])
    motion = Motion(t, q, dq, ddq, model.robot)
    rng = np.random.default_rng(0)
    residual = rng.normal(0, 0.01, (n, 6))
    cands = {c.label: c for c in build_candidates(motion, model, residual, np.full(6, 0.01))}
    return model, motion, cands


@pytest.mark.parametrize("name,params,coef", [
    ("coulomb_friction", {"fc": [0.1, 0.2, 0.3, 0.01, 0.02, 0.03]}, [0.1, 0.2, 0.3, 0.01, 0.02, 0.03]),
    ("viscous_friction", {"fv": [0.1, 0.2, 0.3, 0.01, 0.02, 0.03]}, [0.1, 0.2, 0.3, 0.01, 0.02, 0.03]),
    ("joint_offset", {"offset": [0.1, -0.2, 0.3, 0.0, 0.02, -0.03]}, [0.1, -0.2, 0.3, 0.0, 0.02, -0.03]),
    ("cable_coupling", {"motor_fc": [0.004, 0.006], "motor_fv": [0.003, 0.002]}, [0.004, 0.006, 0.003, 0.002]),
])
def test_linear_candidates_equal_the_library_effect(setup, name, params, coef):
    _, motion, cands = setup
    tau = EFFECTS[name](params).torque(motion)
    np.testing.assert_allclose(cands[name].torque(np.array(coef)), tau, atol=1e-12)
    back = cands[name].to_params(np.array(coef))
    for key, value in params.items():
        np.testing.assert_allclose(back[key], value)


def test_payload_columns_match_the_payload_effect(setup):
    _, motion, cands = setup
    tip = EFFECTS["payload_mass"]({"mass_kg": 0.15, "link": 6, "position_m": PAYLOAD_SITES[6]})
    np.testing.assert_allclose(cands["payload_mass@link6"].torque(np.array([0.15])),
                               tip.torque(motion), atol=1e-12)
    load = EFFECTS["payload_mass"]({"mass_kg": 0.2, "link": 2})
    mc = 0.2 * np.asarray(PAYLOAD_SITES[2])
    fitted = cands["payload_mass@link2"].torque(mc)
    true = load.torque(motion)
    # the first-moment columns leave out the point mass's m |c|^2 rotational inertia
    assert np.sqrt(np.mean((fitted - true) ** 2)) < 0.05 * np.sqrt(np.mean(true**2))
    back = cands["payload_mass@link2"].to_params(mc)
    assert back["mass_kg"] == pytest.approx(0.2)
    np.testing.assert_allclose(back["position_m"], PAYLOAD_SITES[2], atol=1e-12)


def test_bristle_column_is_the_seal_bristle_force_per_unit_level():
    """With sigma1 = sigma2 = 0 and no lip, the library seal force is G times the column."""
    t = np.arange(2000) * 0.001
    x = 0.01 * np.sin(2 * np.pi * 0.7 * t) + 0.002 * np.sin(2 * np.pi * 3.1 * t)
    v_step = np.diff(x, prepend=x[:1]) / 0.001
    fc, fs, vs, sigma0 = 1.3, 0.7, 0.004, 4e4
    force = seal_force(t, x, v_step, fc=fc, fs_excess=fs, vs=vs, sigma0=sigma0, sigma1=0.0,
                       sigma2=0.0, lip_amplitude=0.0, lip_stiffness=1.0, lip_velocity=1.0)
    g = fc + fs
    col = bristle_state(x, v_step, g / sigma0, fs / g, vs)
    np.testing.assert_allclose(g * col, force, atol=1e-9)


def test_merge_adds_to_an_existing_effect_and_appends_a_new_one(setup):
    model, motion, cands = setup
    coul = cands["coulomb_friction"]
    delta = np.array([0.01, 0.0, 0.1, 0.0, 0.0, 0.0])
    tip = cands["payload_mass@link6"]
    updated, notes = merge_effects(model, [(coul, coul.to_params(delta)),
                                           (tip, tip.to_params(np.array([0.1])))])
    assert notes == []
    names = [s["name"] for s in updated.to_dict()["effects"]]
    assert names == ["coulomb_friction", "viscous_friction", "payload_mass"]
    expect = model.torque(motion) + coul.torque(delta) + tip.torque(np.array([0.1]))
    np.testing.assert_allclose(updated.torque(motion), expect, atol=1e-9)


def test_noise_floor_ignores_smooth_structure_and_uses_the_model_floor():
    rng = np.random.default_rng(1)
    t = np.arange(6000) * 0.005
    r = rng.normal(0, 0.02, (6000, 6)) + 0.5 * np.sin(0.5 * t)[:, None]
    np.testing.assert_allclose(white_noise_level(r), 0.02, rtol=0.05)
    model = PhysicsModel.from_dict({"effects": [{"name": "inertial_delta", "params": {
        "identified_rms": [0.1, 0.0, 0.0, 0.0, 0.0, 0.0]}}]})
    floor = noise_floor(r, model)
    assert floor[0] == pytest.approx(0.1) and floor[1] == pytest.approx(0.02, rel=0.05)
