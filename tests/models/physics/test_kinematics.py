"""Kinematics: pinocchio chain against an independent DH product, Jacobians, wrench maps."""

import numpy as np
import pytest

from wrenchd.models.errors import DataError
from wrenchd.models.physics.kinematics import (
    PSM_DH, PSM_LOWER, PSM_UPPER, TIP_OFFSET_M, PSMKinematics,
)


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def trans(x=0.0, z=0.0):
    t = np.eye(4)
    t[0, 3], t[2, 3] = x, z
    return t


def dh_forward(q):
    """Modified DH written out by hand: RotX(alpha) TransX(a) RotZ(theta) TransZ(d)."""
    pose = np.eye(4)
    for row, qi in zip(PSM_DH, q):
        theta = row.theta + (0.0 if row.prismatic else qi + row.offset)
        d = row.d + (qi + row.offset if row.prismatic else 0.0)
        pose = pose @ rot_x(row.alpha) @ trans(x=row.a) @ rot_z(theta) @ trans(z=d)
    return pose @ trans(x=TIP_OFFSET_M)


@pytest.fixture(scope="module")
def kin():
    return PSMKinematics()


@pytest.fixture(scope="module")
def configs():
    rng = np.random.default_rng(7)
    return rng.uniform(PSM_LOWER * 0.9, PSM_UPPER * 0.9, (25, 6))


def test_forward_matches_dh_chain(kin, configs):
    for q in configs:
        np.testing.assert_allclose(kin.forward(q), dh_forward(q), atol=1e-12)


def test_batch_equals_single(kin, configs):
    batch = kin.forward(configs)
    assert batch.shape == (len(configs), 4, 4)
    np.testing.assert_allclose(batch[3], kin.forward(configs[3]))


def test_shaft_passes_through_rcm(kin, configs):
    """The remote centre of motion: the tip always lies on the line through the base origin
    along the shaft axis (before the wrist), whatever yaw, pitch and insertion are."""
    for q in configs:
        roll_frame = kin.forward(q, frame="outer_roll")
        axis = kin.shaft_axis(q)
        p = roll_frame[:3, 3]
        np.testing.assert_allclose(np.cross(p, axis), 0.0, atol=1e-12)
        np.testing.assert_allclose(roll_frame[:3, 2], axis, atol=1e-12)
        # depth along the shaft = insertion - 0.4318 + 0.4162
        assert p @ axis == pytest.approx(q[2] - 0.4318 + 0.4162, abs=1e-12)


@pytest.mark.parametrize("frame", ["hybrid", "spatial", "body"])
def test_jacobian_matches_finite_differences(kin, configs, frame):
    eps = 1e-6
    for q in configs[:8]:
        jac = kin.jacobian(q, frame=frame)
        pose = kin.forward(q)
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = eps
            plus, minus = kin.forward(q + dq), kin.forward(q - dq)
            dpose = (plus - minus) / (2 * eps)            # d(pose)/dq_j
            rot, p = pose[:3, :3], pose[:3, 3]
            omega_hat = dpose[:3, :3] @ rot.T              # base axes
            omega = np.array([omega_hat[2, 1], omega_hat[0, 2], omega_hat[1, 0]])
            v_tip = dpose[:3, 3]
            if frame == "hybrid":
                twist = np.concatenate([v_tip, omega])
            elif frame == "spatial":
                twist = np.concatenate([v_tip - np.cross(omega, p), omega])
            else:
                twist = np.concatenate([rot.T @ v_tip, rot.T @ omega])
            np.testing.assert_allclose(jac[:, j], twist, atol=1e-7)


def test_wrench_maps_to_torques_and_back(kin, configs):
    """tau = J^T w for a known tip wrench; solving J^T w = tau recovers the wrench."""
    rng = np.random.default_rng(3)
    for q in configs:
        jac = kin.jacobian(q, frame="hybrid")
        wrench = np.concatenate([rng.normal(0, 2.0, 3), rng.normal(0, 0.05, 3)])  # N, N m
        tau = jac.T @ wrench
        # insertion feels the force along the shaft, whatever the wrist does
        assert tau[2] == pytest.approx(wrench[:3] @ kin.shaft_axis(q), abs=1e-12)
        back = np.linalg.solve(jac.T, tau)
        np.testing.assert_allclose(back, wrench, atol=1e-9)


def test_virtual_work(kin, configs):
    """Power balance: w . twist == tau . dq for any joint velocity."""
    rng = np.random.default_rng(4)
    q = configs[0]
    jac = kin.jacobian(q)
    w, dq = rng.normal(size=6), rng.normal(size=6)
    assert w @ (jac @ dq) == pytest.approx((jac.T @ w) @ dq, rel=1e-12)


def test_bad_positions_raise(kin):
    with pytest.raises(DataError, match="shape"):
        kin.forward(np.zeros(5))
    with pytest.raises(DataError, match="NaN"):
        kin.forward(np.array([0, 0, np.nan, 0, 0, 0.0]))
    with pytest.raises(DataError, match="frame"):
        kin.jacobian(np.zeros(6), frame="world")
