"""A rigid-body + friction torque model identified by linear least squares (a baseline).

The classic identification of the dVRK (Wang, Gondokaryono, Munawar, Fischer, RA-L 2019) in
its simplest unconstrained form: joint torques are linear in the parameters,

    tau = Y(q, dq, ddq) theta + Ia * ddq + Fc * sign(dq) + Fv * dq + Fo

with ``Y`` pinocchio's joint-torque regressor of the PSM chain (10 inertial parameters per
link, :meth:`wrenchd.models.physics.dynamics.RigidBodyModel.regressor`), ``Ia`` the armature
(reflected motor inertia), ``Fc`` Coulomb, ``Fv`` viscous friction and ``Fo`` a constant
offset per joint. Many inertial parameters are not identifiable from joint torques alone
(the regressor is rank deficient), so the minimum-norm least-squares solution is used; the
predicted torques are unique even where the parameters are not. No physical-consistency
constraints (positive masses, ...) are imposed: this is a baseline for prediction accuracy.

The acceleration is not measured: it is a Savitzky-Golay derivative of the velocity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter

from wrenchd.models.errors import DataError
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.series import N_JOINTS


def smoothed_acceleration(velocity: np.ndarray, dt_s: float, window_s: float = 0.105,
                          order: int = 3) -> np.ndarray:
    """Joint accelerations (N, 6) from velocities (N, 6) sampled every ``dt_s`` seconds.

    A Savitzky-Golay derivative over ``window_s`` seconds (odd number of samples, at least
    ``order + 2``) of polynomial ``order``: smoothing and differentiating in one filter.
    """
    v = np.asarray(velocity, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != N_JOINTS or not dt_s > 0:
        raise DataError(f"velocity must be (N, 6) with dt_s > 0, got {v.shape}, {dt_s}")
    n = max(int(round(window_s / dt_s)) | 1, order + 2 | 1)
    if v.shape[0] < n:
        raise DataError(f"need at least {n} samples for the acceleration filter")
    return savgol_filter(v, n, order, deriv=1, delta=dt_s, axis=0)


@dataclass(frozen=True)
class RigidBodyFrictionModel:
    """Identified parameters: ``coefficients`` (84,) in the column order of :meth:`columns`."""

    coefficients: np.ndarray
    rank: int

    @staticmethod
    def columns(rigid: RigidBodyModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray
                ) -> np.ndarray:
        """Regressor (N, 6, 84): 60 inertial, 6 armature, 6 Coulomb, 6 viscous, 6 offset."""
        y = rigid.regressor(q, dq, ddq)
        n = y.shape[0]
        eye = np.eye(N_JOINTS)
        per_joint = [eye * ddq[:, :, None], eye * np.sign(dq)[:, :, None],
                     eye * dq[:, :, None], np.broadcast_to(eye, (n, N_JOINTS, N_JOINTS))]
        return np.concatenate([y, *per_joint], axis=2)

    @classmethod
    def fit(cls, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, tau: np.ndarray,
            rigid: RigidBodyModel | None = None) -> "RigidBodyFrictionModel":
        """Least squares on (N, 6) positions, velocities, accelerations and torques.

        Each joint's equations are scaled by that joint's torque standard deviation, so the
        insertion joint (N) and the revolute joints (N m) weigh alike.
        """
        rigid = rigid if rigid is not None else RigidBodyModel()
        tau = np.asarray(tau, dtype=np.float64)
        a = cls.columns(rigid, q, dq, ddq)                       # (N, 6, 84)
        scale = np.maximum(tau.std(axis=0), 1e-9)                # (6,)
        a = (a / scale[None, :, None]).reshape(-1, a.shape[2])
        b = (tau / scale).reshape(-1)
        coef, _, rank, _ = np.linalg.lstsq(a, b, rcond=1e-10)
        return cls(coef, int(rank))

    def predict(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                rigid: RigidBodyModel | None = None) -> np.ndarray:
        """Joint torques (N, 6) [N m; N]."""
        rigid = rigid if rigid is not None else RigidBodyModel()
        return self.columns(rigid, q, dq, ddq) @ self.coefficients
