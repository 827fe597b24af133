"""From external joint torques to the tip wrench.

The external joint torque is what the measurement holds beyond the predicted torque of the
robot's own motion: ``tau_ext = tau_measured - tau_predicted``. A tip wrench ``w`` acts on the
joints as ``tau_ext = J^T w`` with ``J`` the hybrid Jacobian of the tip
(:mod:`wrenchd.models.physics.kinematics`): ``w = [Fx, Fy, Fz, Tx, Ty, Tz]``, force [N] in base-frame
axes, torque [N m] about the tip point in base-frame axes. The base frame has its origin at
the remote centre of motion.

Inverting ``J^T`` blows up near singular configurations (for the PSM: the wrist withdrawn to
the remote centre, insertion ~0.0156 m). Damped least squares (Nakamura and Hanafusa 1986;
Chiaverini 1997) bounds it::

    w = (J J^T + lambda^2 I)^-1 J tau_ext = U diag(s / (s^2 + lambda^2)) V^T tau_ext

with ``J = U diag(s) V^T``. ``lambda`` is chosen from the smallest singular value s_min
(Maciejewski and Klein 1988): zero while ``s_min >= threshold``, so the map is the exact
inverse, and ``lambda^2 = (1 - (s_min / threshold)^2) max_damping^2`` below it. With the
default ``max_damping = threshold`` every direction's gain is at most ``1 / threshold``:
``s / (s^2 + lambda^2) = s / threshold^2`` for the singular direction once damped, which falls
to zero with ``s`` (an unobservable wrench component is reported as zero).

The singular values mix units (columns: rad or m joints; rows: linear or angular), so the
threshold is a number for this robot, not a physical constant: 0.01 keeps the map exact over
the dVRK workspaces used here (s_min > 0.02 once the insertion is past 0.05 m).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from pydantic import BaseModel, ConfigDict, Field

from scipy.linalg.lapack import dgesv as _gesv
from scipy.linalg.lapack import dgesvd as _gesvd

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.compiled import wrench_kernel
from wrenchd.models.physics.kinematics import PSMKinematics
from wrenchd.models.series import N_JOINTS, all_finite


_EYE = np.eye(N_JOINTS)


class WrenchMapConfig(BaseModel):
    """Damping of the torque-to-wrench map."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    threshold: float = Field(default=0.01, gt=0.0,
                             description="smallest singular value of J left undamped")
    max_damping: float | None = Field(default=None, gt=0.0,
                                      description="damping at s_min = 0; None: the threshold")


def external_torque(measured: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """``measured - predicted`` joint torques, (6,) or (N, 6) [N m; N]."""
    measured, predicted = np.asarray(measured, np.float64), np.asarray(predicted, np.float64)
    if measured.shape != predicted.shape or measured.shape[-1] != N_JOINTS:
        raise DataError(f"torques must have matching shapes (..., 6), got {measured.shape} "
                        f"and {predicted.shape}")
    return measured - predicted


def damped_wrench(jacobian: np.ndarray, tau_ext: np.ndarray, threshold: float,
                  max_damping: float | None = None) -> np.ndarray:
    """Damped least-squares solution of ``J^T w = tau_ext``, vectorised.

    Args:
        jacobian: (..., 6, 6) hybrid Jacobians.
        tau_ext: (..., 6) external joint torques [N m; N].
        threshold, max_damping: see the module docstring.
    Returns:
        (..., 6) wrenches [N, N m].
    """
    lam_max = threshold if max_damping is None else max_damping
    u, s, vt = np.linalg.svd(jacobian)                               # J = U diag(s) Vt
    s_min = s[..., -1:]
    ratio = np.minimum(s_min / threshold, 1.0)
    lam2 = (1.0 - ratio ** 2) * lam_max ** 2                         # (..., 1)
    gain = s / (s ** 2 + lam2)
    coeff = gain * np.einsum("...ij,...j->...i", vt, tau_ext)        # diag(gain) Vt tau
    return np.einsum("...ij,...j->...i", u, coeff)


class WrenchMap:
    """External joint torques to tip wrench (hybrid frame, see module docstring)."""

    def __init__(self, config: WrenchMapConfig | None = None,
                 kinematics: PSMKinematics | None = None) -> None:
        self.config = config if config is not None else WrenchMapConfig()
        self.kinematics = kinematics if kinematics is not None else PSMKinematics()
        self._plain_bound2 = 1.0 / self.config.threshold ** 2
        self._plain = None        # the fast path compiled: found on the first wrench (False: none)

    def __getstate__(self) -> dict:
        # the compiled fast path stays in its process: the receiver finds its own
        return {**self.__dict__, "_plain": None}

    def wrench(self, q: np.ndarray, tau_ext: np.ndarray) -> np.ndarray:
        """One sample: (6,) positions, (6,) external torques -> (6,) wrench [N, N m]."""
        q, tau_ext = np.asarray(q, np.float64), np.asarray(tau_ext, np.float64)
        if q.shape != (N_JOINTS,) or tau_ext.shape != (N_JOINTS,):
            raise DataError(f"expected (6,) positions and torques, got {q.shape}, {tau_ext.shape}")
        if not all_finite(q):
            raise DataError("joint positions contain NaN or Inf")
        # PSMKinematics.jacobian(q, "hybrid") without its per-call checks and look-ups: this is
        # the streaming hot path (one pinocchio call, ~1 us instead of ~6 us).
        kin = self.kinematics
        jac = pin.computeFrameJacobian(kin.model, kin.data, q, kin.tip_id, pin.LOCAL_WORLD_ALIGNED)
        # Fast path, exact: J^-1 by elimination. ||J^-1||_F >= ||J^-1||_2 = 1 / s_min, so
        # ||J^-1||_F <= 1 / threshold proves s_min >= threshold, where the damped map is the
        # plain inverse w = J^-T tau, ~3x cheaper than the SVD. Compiled where numba is
        # (one call instead of four NumPy and LAPACK ones), else LAPACK's LU.
        plain = self._plain
        if plain is None:
            plain = self._plain = wrench_kernel() or False
        if plain:
            out = np.empty(N_JOINTS)
            if plain(jac, tau_ext, self._plain_bound2, out):
                return out
        else:
            _, _, inv, info = _gesv(jac, _EYE)
            if info == 0:
                flat = inv.ravel()
                if flat @ flat <= self._plain_bound2:
                    return inv.T @ tau_ext
        # Near a singularity: damped least squares by SVD (LAPACK called directly: the
        # numpy.linalg.svd wrapper costs ~4x the 6x6 decomposition itself).
        u, s, vt, info = _gesvd(jac)
        if info != 0:
            raise DataError(f"SVD of the Jacobian did not converge (LAPACK info {info})")
        gain = s / (s * s + self._damping2(s[-1]))
        return u @ (gain * (vt @ tau_ext))

    def wrench_batch(self, q: np.ndarray, tau_ext: np.ndarray) -> np.ndarray:
        """(N, 6) positions, (N, 6) external torques -> (N, 6) wrenches [N, N m]."""
        q, tau_ext = np.asarray(q, np.float64), np.asarray(tau_ext, np.float64)
        if q.ndim != 2 or q.shape != tau_ext.shape or q.shape[1] != N_JOINTS:
            raise DataError(
                f"expected (N, 6) positions and torques, got {q.shape}, {tau_ext.shape}")
        if q.shape[0] == 0:
            return np.zeros((0, N_JOINTS))
        return self._solve(self.kinematics.jacobian(q, frame="hybrid"), tau_ext)

    def gains(self, q: np.ndarray) -> np.ndarray:
        """(N, 6) positions -> (N, 6, 6) per-sample linear maps from external torque to
        wrench, ``w = G @ tau_ext``: what :meth:`wrench` applies, each sample on its own."""
        q = np.asarray(q, np.float64)
        if q.ndim != 2 or q.shape[1] != N_JOINTS:
            raise DataError(f"expected (N, 6) positions, got {q.shape}")
        if len(q) == 0:
            return np.zeros((0, N_JOINTS, N_JOINTS))
        jac = self.kinematics.jacobian(q, frame="hybrid")                    # (N, 6, 6)
        # As wrench(): where ||J^-1||_F <= 1 / threshold (so s_min >= threshold) the map is
        # J^-T exactly; elsewhere the damped one, whose columns are the wrenches of unit
        # torques (the map is linear in the torque).
        gains = np.empty_like(jac)
        plain = np.zeros(len(q), dtype=bool)
        ok = np.abs(np.linalg.det(jac)) > 0.0
        if ok.any():
            inv = np.linalg.inv(jac[ok])
            gains[ok] = inv.transpose(0, 2, 1)
            plain[ok] = np.einsum("nij,nij->n", inv, inv) <= self._plain_bound2
        damped = ~plain
        if damped.any():
            unit = damped_wrench(jac[damped][:, None], np.eye(N_JOINTS), self.config.threshold,
                                 self.config.max_damping)
            gains[damped] = unit.transpose(0, 2, 1)
        return np.ascontiguousarray(gains)

    def _solve(self, jacobian: np.ndarray, tau_ext: np.ndarray) -> np.ndarray:
        return damped_wrench(jacobian, tau_ext, self.config.threshold, self.config.max_damping)

    def _damping2(self, s_min: float) -> float:
        """``lambda^2`` for a smallest singular value ``s_min`` (as :func:`damped_wrench`)."""
        eps = self.config.threshold
        lam = eps if self.config.max_damping is None else self.config.max_damping
        return (1.0 - min(s_min / eps, 1.0) ** 2) * lam ** 2

    @property
    def max_gain(self) -> float:
        """Upper bound of ``|w| / |tau_ext|`` over all configurations [1 / (m or rad)]."""
        eps = self.config.threshold
        lam = eps if self.config.max_damping is None else self.config.max_damping
        r2 = min((lam / eps) ** 2, 1.0)
        # max of s / (s^2 (1 - r^2) + lam^2) over s in [0, eps], and 1/s above eps.
        if r2 >= 0.5:
            return 1.0 / eps
        return max(1.0 / eps, 1.0 / (2.0 * lam * np.sqrt(1.0 - r2)))
