"""Rigid-body dynamics: regressor against RNEA, physical sanity."""

import numpy as np
import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.dynamics import RigidBodyConfig, RigidBodyModel
from wrenchd.models.physics.kinematics import PSM_LOWER, PSM_UPPER


@pytest.fixture(scope="module")
def robot():
    return RigidBodyModel()


def random_motion(n, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(PSM_LOWER * 0.9, PSM_UPPER * 0.9, (n, 6))
    return q, rng.normal(0, 1.0, (n, 6)), rng.normal(0, 3.0, (n, 6))


def test_regressor_times_parameters_equals_rnea(robot):
    q, dq, ddq = random_motion(50)
    y = robot.regressor(q, dq, ddq)
    assert y.shape == (50, 6, 60)
    tau = robot.inverse_dynamics(q, dq, ddq)
    np.testing.assert_allclose(y @ robot.parameters + robot.armature_torque(ddq), tau, atol=1e-10)


def test_gravity_is_rnea_at_rest(robot):
    q, _, _ = random_motion(10, seed=1)
    zero = np.zeros_like(q)
    np.testing.assert_allclose(robot.gravity(q), robot.inverse_dynamics(q, zero, zero), atol=1e-12)


def test_mass_matrix_is_symmetric_positive(robot):
    """Torque is linear in acceleration with a symmetric positive-definite inertia matrix."""
    q, dq, _ = random_motion(5, seed=2)
    for qi in q:
        base = robot.inverse_dynamics(qi, np.zeros(6), np.zeros(6))[0]
        m = np.stack([robot.inverse_dynamics(qi, np.zeros(6), e)[0] - base
                      for e in np.eye(6)], axis=1)
        np.testing.assert_allclose(m, m.T, atol=1e-12)
        assert np.all(np.linalg.eigvalsh(m) > 0)


def test_no_gravity_without_gravity():
    robot = RigidBodyModel(RigidBodyConfig(gravity_mps2=(0.0, 0.0, 0.0)))
    q, _, _ = random_motion(5)
    np.testing.assert_allclose(robot.gravity(q), 0.0, atol=1e-15)


def test_config_validation_names_the_value():
    with pytest.raises(ValueError, match="armature"):
        RigidBodyConfig(armature=(0.1, 0.1))
    # read from a model file, the same mistake is a ConfigError naming the field
    from wrenchd.models.physics.model import PhysicsModel

    with pytest.raises(ConfigError, match="rigid_body.armature"):
        PhysicsModel.from_dict({"rigid_body": {"armature": [0.1, 0.1]}, "effects": []})
    with pytest.raises(ConfigError, match="rigid_body.links"):
        PhysicsModel.from_dict({"rigid_body": {"links": []}, "effects": []})
