import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.errors import DataError
from wrenchd.models.estimator.wrench import (WrenchMap, WrenchMapConfig, damped_wrench,
                                     external_torque)
from wrenchd.models.physics.kinematics import PSMKinematics

#: Insertion at which the wrist-pitch axis passes through the remote centre: 0.4318 m (DH
#: insertion offset) - 0.4162 m (tool length) [m]. The tip Jacobian is singular there.
SINGULAR_INSERTION_M = 0.4318 - 0.4162


@pytest.fixture(scope="module")
def contact_session():
    return run_scenario("trocar-contact", 20.0, 3)


def test_recovers_the_true_wrench_from_true_external_torques(contact_session):
    truth = contact_session.truth
    assert truth.in_contact.sum() > 100 and np.abs(truth.external_wrench).max() > 1.0
    w = WrenchMap().wrench_batch(truth.position, truth.external_torque)
    # Away from singularities the map is the exact inverse of tau = J^T w.
    np.testing.assert_allclose(w, truth.external_wrench, rtol=0, atol=1e-9)


def test_single_sample_equals_batch(contact_session):
    truth = contact_session.truth
    wm = WrenchMap()
    idx = np.flatnonzero(truth.in_contact)[::97]
    batch = wm.wrench_batch(truth.position[idx], truth.external_torque[idx])
    single = np.array([wm.wrench(truth.position[i], truth.external_torque[i]) for i in idx])
    np.testing.assert_allclose(single, batch, rtol=0, atol=1e-12)


def test_undamped_region_is_the_plain_inverse_transpose():
    q = np.array([0.2, -0.1, 0.12, 0.5, 0.3, -0.2])
    jac = PSMKinematics().jacobian(q)
    tau = np.array([0.3, -0.2, 1.5, 0.01, 0.02, -0.01])
    np.testing.assert_allclose(WrenchMap().wrench(q, tau), np.linalg.solve(jac.T, tau),
                               rtol=1e-12, atol=1e-12)


def test_bounded_near_a_singularity():
    wm = WrenchMap(WrenchMapConfig(threshold=0.01))
    kin = PSMKinematics()
    rng = np.random.default_rng(0)
    offsets = np.concatenate([[0.0], np.geomspace(1e-9, 2e-3, 20)])
    q = np.tile([0.1, 0.2, SINGULAR_INSERTION_M, 0.3, 0.4, -0.2], (2 * len(offsets), 1))
    q[:, 2] += np.concatenate([offsets, -offsets])
    s_min = np.linalg.svd(kin.jacobian(q), compute_uv=False)[:, -1]
    assert s_min.min() < 1e-12 and s_min.max() < 0.01          # all inside the damped zone
    tau = rng.normal(size=q.shape) * [0.2, 0.2, 1.0, 0.01, 0.01, 0.01]
    w = wm.wrench_batch(q, tau)
    assert np.all(np.isfinite(w))
    gain = np.linalg.norm(w, axis=1) / np.linalg.norm(tau, axis=1)
    assert gain.max() <= wm.max_gain * (1 + 1e-9)
    assert wm.max_gain == pytest.approx(100.0)
    # Undamped, the same torques would give wrenches without bound.
    inverse_transpose = np.linalg.pinv(np.swapaxes(kin.jacobian(q[1:5]), 1, 2))
    plain = np.linalg.norm(inverse_transpose @ tau[1:5, :, None])
    assert plain > 1e3 * np.linalg.norm(w[1:5])


def test_damping_is_continuous_at_the_threshold():
    jac = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 0.0])
    tau = np.ones(6)
    for s in (0.01 * (1 + 1e-9), 0.01 * (1 - 1e-9)):
        jac[5, 5] = s
        assert damped_wrench(jac, tau, 0.01)[5] == pytest.approx(100.0, rel=1e-6)
    jac[5, 5] = 0.0
    assert damped_wrench(jac, tau, 0.01)[5] == 0.0            # unobservable: reported as zero


def test_external_torque_and_shape_checks():
    np.testing.assert_array_equal(external_torque(np.ones(6) * 3, np.ones(6)), np.full(6, 2.0))
    with pytest.raises(DataError):
        external_torque(np.ones(6), np.ones(5))
    with pytest.raises(DataError):
        WrenchMap().wrench(np.zeros(5), np.zeros(6))
    with pytest.raises(DataError):
        WrenchMap().wrench_batch(np.zeros((3, 6)), np.zeros((2, 6)))


@pytest.mark.parametrize("region", ["undamped", "near a singularity"])
def test_compiled_fast_path_equals_lapack(region):
    """The wrench of one sample, compiled (where numba is) and by LAPACK's LU, on random
    poses: the same map to rounding, in the damped zone too (where both leave it to the
    SVD)."""
    rng = np.random.default_rng(4)
    q = np.column_stack([rng.uniform(-1, 1, 200), rng.uniform(-0.7, 0.7, 200),
                         rng.uniform(0.05, 0.22, 200), rng.uniform(-2, 2, (200, 3))])
    if region == "near a singularity":
        q[:, 2] = SINGULAR_INSERTION_M + rng.uniform(-1e-3, 1e-3, 200)
    tau = rng.normal(size=(200, 6)) * [0.2, 0.2, 1.0, 0.01, 0.01, 0.01]
    compiled, lapack = WrenchMap(), WrenchMap()
    lapack._plain = False                                 # as without numba
    a = np.array([compiled.wrench(qi, ti) for qi, ti in zip(q, tau)])
    b = np.array([lapack.wrench(qi, ti) for qi, ti in zip(q, tau)])
    np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-12)


def test_a_copied_map_finds_its_own_fast_path():
    import copy
    import pickle

    wm = WrenchMap()
    q, tau = np.array([0.2, -0.1, 0.12, 0.5, 0.3, -0.2]), np.array([0.3, -0.2, 1.5, 0, 0, 0])
    w = wm.wrench(q, tau)
    for other in (pickle.loads(pickle.dumps(wm)), copy.deepcopy(wm)):
        assert other._plain is None                       # not the sender's compiled function
        np.testing.assert_array_equal(other.wrench(q, tau), w)
