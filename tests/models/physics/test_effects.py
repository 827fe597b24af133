"""The effect library: a contract every effect meets, and each effect's own physics."""

import json

import numpy as np
import pinocchio as pin
import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.effects import EFFECTS, Motion
from wrenchd.models.physics.effects.body_wall import BodyWall
from wrenchd.models.physics.effects.contact import ExternalContact
from wrenchd.models.physics.effects.drift import drift_factor, DriftParams
from wrenchd.models.physics.effects.payload import PayloadMass
from wrenchd.models.physics.dynamics import RigidBodyConfig, LinkInertia, RigidBodyModel
from wrenchd.models.physics.model import PhysicsModel

LIBRARY = {"coulomb_friction", "viscous_friction", "stribeck_friction", "joint_offset",
           "spring", "seal_friction", "body_wall", "payload_mass", "cable_coupling",
           "drift", "external_contact"}

# Parameters that make every effect produce a non-zero torque in the contract tests.
CONTRACT_PARAMS = {
    "joint_offset": {"offset": [0.1, -0.1, 0.3, 0.0, 0.01, 0.0]},
    "spring": {"stiffness": [0.0, 0.0, 0.0, 0.0, 0.002, 0.002]},
    "external_contact": {"episodes": [[0.5, 1.5]]},
}


@pytest.fixture(scope="module")
def robot():
    return RigidBodyModel()


def smooth_motion(robot, n=400, dt=0.005, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    f = rng.uniform(0.3, 1.0, 6)
    amp = np.array([0.4, 0.3, 0.05, 1.0, 0.5, 0.5])
    center = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
    w = 2 * np.pi * f
    q = center + amp * np.sin(w * t[:, None])
    dq = amp * w * np.cos(w * t[:, None])
    ddq = -amp * w * w * np.sin(w * t[:, None])
    return Motion(t, q, dq, ddq, robot)


def make(name, robot):
    if name == "drift":
        model = PhysicsModel.from_dict({"effects": [
            {"name": "viscous_friction"},
            {"name": "drift", "params": {"target": "viscous_friction", "param": "fv",
                                         "kind": "ramp", "factor": 2.0, "t_end_s": 1.0}}]})
        return model.effects["drift"]
    return EFFECTS[name](CONTRACT_PARAMS.get(name, {}))


def test_library_is_complete():
    assert LIBRARY <= set(EFFECTS)


@pytest.mark.parametrize("name", sorted(LIBRARY))
def test_effect_contract(name, robot):
    """Shape (N, 6), finite, non-zero, deterministic, inputs untouched, unknown keys refused."""
    effect = make(name, robot)
    motion = smooth_motion(robot)
    before = [a.copy() for a in (motion.t, motion.q, motion.dq, motion.ddq)]
    tau = effect.torque(motion)
    assert tau.shape == (len(motion), 6)
    assert np.all(np.isfinite(tau))
    assert np.abs(tau).max() > 0
    np.testing.assert_array_equal(tau, effect.torque(motion))
    for a, b in zip(before, (motion.t, motion.q, motion.dq, motion.ddq)):
        np.testing.assert_array_equal(a, b)
    if name != "drift":
        with pytest.raises(ConfigError, match=name):
            EFFECTS[name]({"no_such_parameter": 1.0})


@pytest.mark.parametrize("name", ["coulomb_friction", "viscous_friction", "stribeck_friction",
                                  "cable_coupling", "seal_friction"])
def test_dissipative_effects_take_power(name, robot):
    """Friction never gives energy back: the drive's friction power tau . dq is >= 0 on average
    and the torque flips with the direction of motion."""
    effect = make(name, robot)
    motion = smooth_motion(robot, n=2000)
    tau = effect.torque(motion)
    assert np.mean(np.sum(tau * motion.dq, axis=1)) > 0
    reverse = Motion(motion.t, motion.q, -motion.dq, motion.ddq, robot)
    if not effect.stateful:
        np.testing.assert_allclose(effect.torque(reverse), -tau, atol=1e-12)


def test_body_wall_matches_pinocchio_point_jacobian(robot):
    """tau = -J_p^T F for the shaft point at the wall, with J_p from pinocchio."""
    wall = BodyWall({"damping_ns_per_m": 0.0})
    motion = smooth_motion(robot, n=40)
    tau = wall.torque(motion)
    p = wall.params
    incision = np.array(p.incision_m)
    k = p.k0_n_per_m + p.k_per_mmhg * p.pressure_mmhg
    kin = robot.kinematics
    model = pin.Model(robot.model)          # a copy: frames are added to it below
    for i in range(0, 40, 7):
        q = motion.q[i]
        u = kin.shaft_axis(q)
        depth = u @ incision
        force = -k * (depth * u - incision)
        # frame on the insertion link at the wall's depth along the shaft
        shaft = kin.forward(q, frame="outer_insertion")
        local = shaft[:3, :3].T @ (depth * u - shaft[:3, 3])
        fid = model.addFrame(pin.Frame(f"wall{i}", model.frames[kin.shaft_id].parentJoint,
                                       pin.SE3(np.eye(3), local), pin.FrameType.OP_FRAME))
        jac = pin.computeFrameJacobian(model, model.createData(), q, fid,
                                       pin.LOCAL_WORLD_ALIGNED)[:3]
        np.testing.assert_allclose(tau[i], -jac.T @ force, atol=1e-10)
    assert np.abs(tau[:, 2:]).max() == 0.0


def test_body_wall_stiffens_with_pressure(robot):
    motion = smooth_motion(robot)
    low = BodyWall({"pressure_mmhg": 8.0, "damping_ns_per_m": 0.0}).torque(motion)
    high = BodyWall({"pressure_mmhg": 15.0, "damping_ns_per_m": 0.0}).torque(motion)
    ratio = (100 + 40 * 15) / (100 + 40 * 8)
    np.testing.assert_allclose(high, low * ratio, rtol=1e-12, atol=1e-15)


def test_payload_equals_rnea_with_added_mass():
    """A 105 g point mass on link 2 gives exactly the RNEA difference of the heavier robot."""
    base = RigidBodyModel()
    links = list(base.config.links)
    pos = np.array([0.01, 0.065, 0.165])
    mass = 0.105
    l2 = links[1]
    new_mass = l2.mass_kg + mass
    com = (l2.mass_kg * np.array(l2.com_m) + mass * pos) / new_mass
    # inertia about the new COM: parallel-axis for both bodies
    def shifted(m, c, i_c, new_c):
        d = np.asarray(c) - new_c
        return i_c + m * (d @ d * np.eye(3) - np.outer(d, d))
    ixx, ixy, iyy, ixz, iyz, izz = l2.inertia_kgm2
    i2 = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    inertia = shifted(l2.mass_kg, l2.com_m, i2, com) + shifted(mass, pos, np.zeros((3, 3)), com)
    links[1] = LinkInertia(mass_kg=new_mass, com_m=tuple(com),
                           inertia_kgm2=(inertia[0, 0], inertia[0, 1], inertia[1, 1],
                                         inertia[0, 2], inertia[1, 2], inertia[2, 2]))
    heavy = RigidBodyModel(RigidBodyConfig(links=links))
    motion = smooth_motion(base, n=50)
    expected = heavy.inverse_dynamics(motion.q, motion.dq, motion.ddq) \
        - base.inverse_dynamics(motion.q, motion.dq, motion.ddq)
    payload = PayloadMass({"mass_kg": mass, "link": 2, "position_m": tuple(pos)})
    np.testing.assert_allclose(payload.torque(motion), expected, atol=1e-10)


def test_external_contact_is_jacobian_transpose(robot):
    contact = ExternalContact({"episodes": [[0.2, 1.0]], "stiffness_n_per_m": 200.0})
    motion = smooth_motion(robot, n=300)
    wrench, flag = contact.wrench(motion)
    tau = contact.torque(motion)
    assert flag[motion.t < 0.2].sum() == 0 and flag[(motion.t > 0.2) & (motion.t < 1.0)].all()
    assert np.abs(wrench[~flag]).max() == 0 and np.abs(tau[~flag]).max() == 0
    i = np.flatnonzero(flag)[-60]
    jac = robot.kinematics.jacobian(motion.q[i])
    np.testing.assert_allclose(tau[i], jac.T @ wrench[i], atol=1e-12)
    # the force follows the tip's displacement from the grasp point: Hooke's law while the
    # spring is small (the grasp's first samples, under 1 N), saturating smoothly (tanh)
    # towards max_force_n when it is large (the sample above: a spring of about 18 N)
    rows = np.flatnonzero(flag)
    tip = robot.kinematics.forward(motion.q[rows])[:, :3, 3]
    spring = 200.0 * (tip - tip[0])                    # [N]
    size = np.linalg.norm(spring, axis=1)
    small = np.flatnonzero((size > 0.1) & (size < 1.0))
    assert len(small) >= 3
    np.testing.assert_allclose(wrench[rows[small], :3], spring[small], rtol=0.01)
    f_max = contact.params.max_force_n
    k = int(np.searchsorted(rows, i))
    assert size[k] > 2 * f_max
    np.testing.assert_allclose(wrench[i, :3], f_max * np.tanh(size[k] / f_max) * spring[k]
                               / size[k], rtol=1e-9)
    assert np.linalg.norm(wrench[:, :3], axis=1).max() <= f_max


def test_drift_factor_shapes():
    t = np.array([0.0, 5.0, 10.0, 15.0, 20.0])
    step = DriftParams(target="x", param="y", kind="step", factor=1.25, t_start_s=10.0)
    np.testing.assert_allclose(drift_factor(t, step), [1, 1, 1.25, 1.25, 1.25])
    ramp = DriftParams(target="x", param="y", kind="ramp", factor=2.0, t_start_s=5.0, t_end_s=15.0)
    np.testing.assert_allclose(drift_factor(t, ramp), [1, 1, 1.5, 2, 2])
    lin = DriftParams(target="x", param="y", kind="linear", rate_per_hour=3600.0, t_start_s=10.0)
    np.testing.assert_allclose(drift_factor(t, lin), [1, 1, 1, 6, 11])


def test_drift_contribution_is_the_change(robot):
    model = PhysicsModel.from_dict({"effects": [
        {"name": "viscous_friction"},
        {"name": "drift", "params": {"target": "viscous_friction", "param": "fv",
                                     "kind": "step", "factor": 3.0, "t_start_s": 1.0}}]})
    motion = smooth_motion(model.robot)
    torques = model.effect_torques(motion)
    late = motion.t >= 1.0
    np.testing.assert_allclose(torques["drift"][~late], 0.0)
    np.testing.assert_allclose(torques["drift"][late], 2.0 * torques["viscous_friction"][late])


def test_model_file_round_trip_and_errors(tmp_path):
    data = {"description": "test", "effects": [
        {"name": "coulomb_friction", "params": {"fc": 0.1}},
        {"name": "seal_friction", "enabled": False},
        {"name": "payload_mass", "id": "load", "params": {"mass_kg": 0.2}}]}
    model = PhysicsModel.from_dict(data)
    assert list(model.effects) == ["coulomb_friction", "load"]
    path = tmp_path / "model.json"
    model.save(path)
    again = PhysicsModel.load(path)
    assert again.to_dict() == model.to_dict()
    assert json.loads(path.read_text())["format"] == "wrenchd.physics/1"
    with pytest.raises(ConfigError, match="unknown effect 'sealfriction'"):
        PhysicsModel.from_dict({"effects": [{"name": "sealfriction"}]})
    with pytest.raises(ConfigError, match="unique"):
        PhysicsModel.from_dict({"effects": [{"name": "spring"}, {"name": "spring"}]})
    with pytest.raises(ConfigError, match="mass_kg"):
        PhysicsModel.from_dict({"effects": [{"name": "payload_mass", "params": {"mass_kg": -1}}]})
    with pytest.raises(ConfigError, match="target"):
        PhysicsModel.from_dict({"effects": [{"name": "drift", "params": {
            "target": "body_wall", "param": "pressure_mmhg"}}]})
    with pytest.raises(ConfigError, match="no numeric parameter"):
        PhysicsModel.from_dict({"effects": [{"name": "body_wall"}, {"name": "drift", "params": {
            "target": "body_wall", "param": "pressure"}}]})
    with pytest.raises(ConfigError, match="cannot read"):
        PhysicsModel.load(tmp_path / "missing.json")


def test_example_model_files_load():
    from pathlib import Path

    examples = sorted((Path(__file__).parents[3] / "deploy" / "models").glob("*.json"))
    assert examples
    for path in examples:
        model = PhysicsModel.load(path)
        assert model.effects, path
