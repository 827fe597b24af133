"""A point mass on a PSM link: its joint torques against pinocchio and against physics."""

from __future__ import annotations

import numpy as np
import pytest
from wrenchd.models.errors import DataError
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.physics.kinematics import PSMKinematics
from wrenchd.models.physics.point_load import (
    LINKS,
    link_poses,
    point_load_torque,
    point_positions,
)


def _trajectory(n: int = 400, dt: float = 0.005) -> tuple[np.ndarray, float]:
    t = np.arange(n) * dt
    q = np.zeros((n, 6))
    q[:, 0] = 0.4 * np.sin(2.1 * t) - 0.2
    q[:, 1] = 0.5 * np.sin(1.3 * t + 0.4)
    q[:, 2] = 0.12 + 0.05 * np.sin(1.7 * t)
    q[:, 3] = 0.8 * np.sin(0.9 * t)
    return q, dt


def test_a_serial_link_point_mass_matches_pinocchio_gravity():
    """Static torques of 1 kg on the pitch link equal the rigid-body gravity torque of a
    model whose only mass is that point."""
    q, _ = _trajectory(50)
    point = np.array([0.03, -0.05, 0.02])
    ours = point_load_torque(q, "outer_pitch", point)
    model = RigidBodyModel()
    # The regressor's pitch-link gravity columns: mass, then first moments m c.
    zeros = np.zeros_like(q)
    cols = model.regressor(q, zeros, zeros)[:, :, 10:14]
    expected = cols @ np.concatenate([[1.0], point])
    np.testing.assert_allclose(ours, expected, atol=1e-6)


def test_static_torque_is_the_gradient_of_the_potential_energy():
    q, _ = _trajectory(30)
    point = np.array([0.165, -0.02, 0.01])
    tau = point_load_torque(q, "parallel_upper", point)
    h = 1e-5
    for j in range(6):
        step = np.zeros(6)
        step[j] = h
        height = (point_positions(q + step, "parallel_upper", point)[:, 2]
                  - point_positions(q - step, "parallel_upper", point)[:, 2]) / (2 * h)
        np.testing.assert_allclose(tau[:, j], 9.81 * height, atol=1e-6)
    # The parallelogram's upper link moves with yaw and pitch only.
    assert np.abs(tau[:, 2:]).max() == 0.0 and np.abs(tau[:, :2]).max() > 0.1


def test_the_upper_link_translates_and_a_point_along_it_changes_nothing():
    """It keeps its orientation in the yaw frame whatever the pitch; its x axis stays parallel
    to the yaw axis, so a load's position along the link does not change its torques."""
    q, dt = _trajectory()
    poses = link_poses(q, "parallel_upper")
    yaw = link_poses(q, "outer_yaw")
    relative = np.einsum("nji,njk->nik", yaw[:, :3, :3], poses[:, :3, :3])
    np.testing.assert_allclose(relative, np.broadcast_to(relative[0], relative.shape), atol=1e-12)
    np.testing.assert_allclose(np.abs(np.einsum("ni,ni->n", poses[:, :3, 0], yaw[:, :3, 2])), 1.0,
                               atol=1e-12)
    a = point_load_torque(q, "parallel_upper", np.array([0.05, -0.02, 0.0]), dt)
    b = point_load_torque(q, "parallel_upper", np.array([0.40, -0.02, 0.0]), dt)
    np.testing.assert_allclose(a, b, atol=1e-6)
    # ... whereas one further from the yaw axis does change the yaw torque.
    c = point_load_torque(q, "parallel_upper", np.array([0.05, -0.06, 0.0]), dt)
    assert np.abs(c[:, 0] - a[:, 0]).max() > 0.01


def test_inertia_adds_the_point_acceleration_term():
    """With the trajectory's acceleration, tau = m (a - g) . dp/dq; a point on the yaw axis
    of a still pitch feels no yaw torque; a moving one does."""
    q, dt = _trajectory()
    point = np.array([0.0, 0.1, 0.0])
    static = point_load_torque(q, "outer_pitch", point)
    dynamic = point_load_torque(q, "outer_pitch", point, dt)
    assert np.abs(dynamic - static)[20:-20].max() > 1e-3      # inertia matters here
    still = np.repeat(q[:1], len(q), axis=0)
    np.testing.assert_allclose(point_load_torque(still, "outer_pitch", point, dt),
                               point_load_torque(still, "outer_pitch", point), atol=1e-9)


def test_links_and_points_are_validated():
    q, _ = _trajectory(10)
    assert "parallel_upper" in LINKS and "outer_yaw" in LINKS
    with pytest.raises(DataError, match="unknown link"):
        link_poses(q, "forearm")
    with pytest.raises(DataError, match="three finite"):
        point_positions(q, "outer_yaw", np.array([0.0, np.nan, 0.0]))
    # The serial links are the kinematics' own frames.
    np.testing.assert_allclose(link_poses(q, "outer_insertion"),
                               PSMKinematics().forward(q, "outer_insertion_link"))
