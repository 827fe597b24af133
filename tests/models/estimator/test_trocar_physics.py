"""The trocar's physics in step 2: the regressors hold the simulator's body wall exactly, a fit
on one motion carries to another, and the net's serving kernel and module agree with it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.correction import Corr, CorrConfig, CorrKernel
from wrenchd.models.estimator.trocar_physics import (fit_trocar, trocar_regressors,
                                                     trocar_torque, wall_matrices, wall_theta,
                                                     wall_torque_one)
from wrenchd.models.physics.effects.base import Motion
from wrenchd.models.physics.effects.body_wall import BodyWall

def sweep(t: np.ndarray, yaw=(0.5, 0.13), pitch=(0.4, 0.08), ins=(0.03, 0.2)):
    """Positions and velocities (N, 6) of a yaw, pitch and insertion sweep of (amplitude,
    frequency) each."""
    q, dq = np.zeros((len(t), 6)), np.zeros((len(t), 6))
    for j, (a, f) in enumerate((yaw, pitch, ins)):
        w = 2 * np.pi * f
        q[:, j] = a * np.sin(w * t + j) + (0.12 if j == 2 else 0.0)
        dq[:, j] = a * w * np.cos(w * t + j)
    return q, dq


def test_the_regressors_hold_the_simulators_body_wall_exactly():
    t = np.arange(0, 20, 0.01)
    q, dq = sweep(t)
    p, k, c = (0.004, -0.003, 0.041), 180.0, 7.0
    params = {"incision_m": p, "k0_n_per_m": k, "k_per_mmhg": 0.0, "damping_ns_per_m": c}
    wall = BodyWall(params).torque(Motion(t, q, dq, np.zeros_like(q), None))
    got = trocar_torque(q, dq, wall_theta(k, c, p))
    assert np.abs(wall).max() > 0.05                               # a torque worth holding
    np.testing.assert_allclose(got, wall, atol=1e-12 * np.abs(wall).max() + 1e-15)
    assert not got[:, 2:].any()                                    # the wall: yaw, pitch only


def test_the_one_sample_path_is_the_array_path():
    t = np.arange(0, 3, 0.05)
    q, dq = sweep(t)
    theta = np.random.default_rng(1).normal(size=12)
    want = trocar_torque(q, dq, theta)
    mats = [m.tolist() for m in wall_matrices(theta)]
    got = np.array([wall_torque_one(q[i], dq[i], *mats) for i in range(len(t))])
    np.testing.assert_allclose(got, want[:, :2], rtol=1e-12, atol=1e-14)


def test_a_fit_on_one_motion_carries_to_motion_it_has_not_seen():
    """The body wall fitted on 30 s of one sweep predicts another sweep (other amplitudes,
    other frequencies, another part of the workspace) to within the noise."""
    rng = np.random.default_rng(3)
    p, k, c = (-0.003, 0.002, 0.028), 120.0, 4.0
    truth = wall_theta(k, c, p)
    t = np.arange(0, 30, 0.005)
    q, dq = sweep(t)
    noise = 0.002
    fitted = fit_trocar(q, dq, trocar_torque(q, dq, truth) + rng.normal(0, noise, (len(t), 6)))
    q2, dq2 = sweep(t, yaw=(0.3, 0.21), pitch=(0.6, 0.05), ins=(0.05, 0.11))
    q2[:, 0] += 0.4
    want = trocar_torque(q2, dq2, truth)
    err = trocar_torque(q2, dq2, fitted) - want
    assert np.sqrt(np.mean(want[:, :2] ** 2)) > 10 * noise
    assert np.sqrt(np.mean(err ** 2, axis=0)).max() < noise


def test_the_linear_fit_keeps_what_the_motion_cannot_see_and_bad_shapes_are_refused():
    t = np.arange(0, 10, 0.01)
    q, dq = sweep(t)
    current = wall_theta(100.0, 5.0, (0.003, -0.002, 0.03))
    shifted = current.copy()
    shifted[:3] += 0.05            # the diagonal's common shift: no torque, nothing to fit
    np.testing.assert_allclose(trocar_torque(q, dq, shifted), trocar_torque(q, dq, current),
                               atol=1e-12)
    fitted = fit_trocar(q, dq, trocar_torque(q, dq, current), shifted, physical=False)
    np.testing.assert_allclose(fitted[:3] - current[:3], 0.05, rtol=1e-3)
    with pytest.raises(DataError, match="residuals"):
        fit_trocar(q, dq, np.zeros((len(t), 5)))
    with pytest.raises(DataError, match="positions and velocities"):
        trocar_regressors(q[:, :5], dq)


def test_the_physical_fit_is_a_wall_and_takes_up_less_of_another_pose_dependent_error():
    """A wall plus a step-1 error that depends on the pose (a gravity-like sin q2 on pitch):
    the physical fit is ``k p p^T``, ``c p p^T`` (rank one, the same direction, k and c >= 0)
    near the true wall, and on poses elsewhere it carries less of the other error than the
    free twelve parameters do."""
    t = np.arange(0, 30, 0.005)
    q, dq = sweep(t)
    p, k, c = np.array([0.004, -0.003, 0.035]), 150.0, 6.0
    truth = wall_theta(k, c, p)
    other = np.zeros((len(t), 6))
    other[:, 1] = 0.03 * np.sin(q[:, 1])
    fitted = fit_trocar(q, dq, trocar_torque(q, dq, truth) + other)
    free = fit_trocar(q, dq, trocar_torque(q, dq, truth) + other, physical=False)
    stiff, damp = wall_matrices(fitted)
    w, v = np.linalg.eigh(stiff)
    assert w[-1] > 0 and np.abs(w[:2]).max() < 1e-9 * w[-1]
    np.testing.assert_allclose(damp, damp[2, 2] / stiff[2, 2] * stiff, atol=1e-12)
    assert abs(v[:, -1] @ p) / np.linalg.norm(p) > 0.99
    q2, dq2 = sweep(t, yaw=(0.3, 0.21), pitch=(0.6, 0.05), ins=(0.05, 0.11))
    q2[:, 0] += 0.4
    want = trocar_torque(q2, dq2, truth)
    err = {name: np.sqrt(np.mean((trocar_torque(q2, dq2, th) - want)[:, :2] ** 2))
           for name, th in (("physical", fitted), ("free", free))}
    assert err["physical"] < err["free"], err


def test_the_serving_kernel_adds_the_physics_as_the_module_does():
    torch.manual_seed(0)
    corr = Corr(CorrConfig(window=4, hidden_size=8, trocar_physics=True)).eval()
    theta = wall_theta(150.0, 5.0, (0.003, -0.002, 0.03))
    corr.trocar_theta.copy_(torch.from_numpy(theta))
    t = np.arange(0, 2, 0.01)
    q, dq = sweep(t)
    windows = np.repeat(np.concatenate([q, dq], 1)[:, None], 4, axis=1)
    step1 = np.random.default_rng(0).normal(size=(len(t), 6))
    with torch.no_grad():
        module = corr(torch.as_tensor(windows, dtype=torch.float32),
                      torch.as_tensor(step1, dtype=torch.float32)).double().numpy()
    plain = Corr(CorrConfig(window=4, hidden_size=8)).eval()
    plain.load_state_dict({k: v for k, v in corr.state_dict().items() if k != "trocar_theta"})
    with torch.no_grad():
        net_only = plain(torch.as_tensor(windows, dtype=torch.float32),
                         torch.as_tensor(step1, dtype=torch.float32)).double().numpy()
    np.testing.assert_allclose(module - net_only, trocar_torque(q, dq, theta), atol=2e-5)
    for kernel in (corr.kernel(), CorrKernel.from_state(corr.state_arrays(), 4)):
        np.testing.assert_allclose(kernel.correct(windows, step1.astype(np.float32)), module,
                                   atol=2e-5)
        one = np.concatenate([kernel.correct(windows[i:i + 1], step1[i:i + 1].astype(np.float32))
                              for i in range(0, len(t), 37)])
        np.testing.assert_allclose(one, module[::37], atol=2e-5)
    again = Corr.from_state(corr.config, corr.state_arrays())
    assert torch.equal(again.trocar_theta, corr.trocar_theta)
    # the state decides: a net configured without the physics takes a state with it, and back
    assert Corr.from_state(plain.config, corr.state_arrays()).config.trocar_physics
    assert not Corr.from_state(corr.config, plain.state_arrays()).config.trocar_physics
