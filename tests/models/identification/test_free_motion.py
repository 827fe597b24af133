"""Identification: base columns, the inertial_delta effect, and a fit on simulated free motion."""

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import FREE_SPACE_WORKSPACE
from wrenchd.adapters.sim.simulator import simulate
from wrenchd.adapters.sim.trajectory import FourierTrajectory
from wrenchd.models.errors import ConfigError
from wrenchd.models.identification.base_parameters import structural_base
from wrenchd.models.identification.differentiation import smoothed_acceleration, zero_phase_velocity
from wrenchd.models.identification.free_motion import identify_free_motion
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.physics.effects import EFFECTS, Motion
from wrenchd.models.physics.effects.inertial import column_index, column_name, inertial_columns
from wrenchd.models.physics.model import PhysicsModel


def _motion(robot, n=300, seed=1):
    rng = np.random.default_rng(seed)
    lo, hi = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    q = rng.uniform(lo, hi, (n, 6))
    dq, ddq = rng.normal(0, 1, (2, n, 6))
    return Motion(np.arange(n) * 0.005, q, dq, ddq, robot)


def test_base_columns_reproduce_the_nominal_rigid_body_exactly():
    """The nominal torques lie in the span of the base columns (least squares residual ~0)."""
    robot = RigidBodyModel()
    base = structural_base(robot)
    inertial = [i for i in base if i < 66]
    motion = _motion(robot)
    cols = inertial_columns(motion)
    tau = robot.inverse_dynamics(motion.q, motion.dq, motion.ddq)
    x = cols[:, :, inertial].reshape(-1, len(inertial))
    beta, *_ = np.linalg.lstsq(x, tau.reshape(-1), rcond=None)
    assert np.max(np.abs(x @ beta - tau.reshape(-1))) < 1e-9 * np.max(np.abs(tau))
    assert 30 <= len(inertial) < 66                     # fewer than all: some are not identifiable


def test_inertial_delta_is_the_regressor_times_its_values_and_names_round_trip():
    robot = RigidBodyModel()
    motion = _motion(robot, 50)
    names = ["link2.mx", "joint3.armature", "link6.izz"]
    assert [column_name(column_index(n)) for n in names] == names
    effect = EFFECTS["inertial_delta"]({"columns": names, "delta": [0.1, 0.2, -0.3]})
    cols = inertial_columns(motion)[:, :, [column_index(n) for n in names]]
    np.testing.assert_allclose(effect.torque(motion), cols @ np.array([0.1, 0.2, -0.3]))
    with pytest.raises(ConfigError, match="inertial_delta"):
        EFFECTS["inertial_delta"]({"columns": ["link7.m"], "delta": [1.0]})
    with pytest.raises(ConfigError, match="same length"):
        EFFECTS["inertial_delta"]({"columns": ["link1.m"], "delta": [1.0, 2.0]})


def test_zero_phase_velocity_removes_the_lag_of_the_simulated_estimate():
    model = PhysicsModel.from_dict({"effects": []})
    traj = FourierTrajectory(FREE_SPACE_WORKSPACE, np.random.default_rng(3), 10.0, freq_hz=(0.05, 0.4))
    s = simulate(model, traj, 10.0, np.random.SeedSequence(3))
    js, truth = s.joint_states, s.truth
    v, used = zero_phase_velocity(js.t, js.position, js.velocity)
    assert used.all()
    err_new = np.sqrt(np.mean((v - truth.velocity) ** 2, axis=0))
    err_old = np.sqrt(np.mean((js.velocity - truth.velocity) ** 2, axis=0))
    assert np.all(err_new < 0.3 * err_old)
    acc = smoothed_acceleration(js.t, v)
    rel = np.sqrt(np.mean((acc - truth.acceleration) ** 2)) / np.sqrt(np.mean(truth.acceleration**2))
    assert rel < 0.05


def test_identification_recovers_friction_and_predicts_held_out_data_to_the_noise():
    """Simulated free motion with a heavier link 3 and known friction: the identified model
    explains held-out data down to the simulated effort noise and finds the friction."""
    fc = [0.08, 0.05, 0.6, 0.004, 0.006, 0.004]
    fv = [0.12, 0.3, 1.5, 0.003, 0.008, 0.005]
    truth_cfg = PhysicsModel().config.rigid_body.model_dump(mode="json")
    truth_cfg["links"][2]["mass_kg"] = 0.25               # differs from the nominal 0.05 kg
    truth = PhysicsModel.from_dict({"rigid_body": truth_cfg, "effects": [
        {"name": "coulomb_friction", "params": {"fc": fc}},
        {"name": "viscous_friction", "params": {"fv": fv}}]})
    traj = FourierTrajectory(FREE_SPACE_WORKSPACE, np.random.default_rng(5), 20.0, freq_hz=(0.05, 0.4))
    js = simulate(truth, traj, 20.0, np.random.SeedSequence(5)).joint_states
    ident = identify_free_motion(js.t, js.position, js.velocity, js.effort)
    noise = np.array([0.015, 0.015, 0.05, 0.0008, 0.002, 0.002])   # the simulator's effort noise
    assert np.all(ident.heldout_rms < 1.3 * noise), ident.heldout_rms
    got = ident.model.effects["coulomb_friction"].params.fc
    for j in range(3):                                 # the large joints: within 10 %
        assert abs(got[j] - fc[j]) < 0.1 * fc[j], (j, got, fc)
    got_v = ident.model.effects["viscous_friction"].params.fv
    for j in range(3):
        assert abs(got_v[j] - fv[j]) < 0.1 * fv[j], (j, got_v, fv)
    again = PhysicsModel.from_dict(ident.model.to_dict())   # the file round-trips
    assert again.to_dict() == ident.model.to_dict()
