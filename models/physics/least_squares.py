"""A rigid-body + friction torque model identified by linear least squares (a baseline).

The classic identification of the dVRK (Wang, Gondokaryono, Munawar, Fischer, RA-L 2019) in
its simplest unconstrained form: joint torques are linear in the parameters,

    tau = Y(q, dq, ddq) theta + Ia * ddq + Fc * c(dq) + Fv * dq + Fo [+ K * q] [+ Fh * p(q)]

with ``Y`` pinocchio's joint-torque regressor of the PSM chain (10 inertial parameters per
link, :meth:`wrenchd.models.physics.dynamics.RigidBodyModel.regressor`), ``Ia`` the armature
(reflected motor inertia), ``Fc`` Coulomb friction with ``c(dq) = sign(dq)`` or, smoothed,
``tanh(dq / v0)``, ``Fv`` viscous friction, ``Fo`` a constant offset and, optionally, ``K`` a
linear spring per joint (the insertion stage's counterbalance, the tool's roll cable) and,
optionally, ``Fh`` a presliding friction per joint with ``p`` the play operator of
:mod:`wrenchd.models.physics.hysteresis` (friction that reverses over a displacement after the
joint reverses, as in the PSM's cable drives, not at the instant its velocity changes sign).
``p`` has a memory: a segment's columns start it afresh at the first sample unless the caller
passes it (``presliding``), as a stream that continues does. Many
inertial parameters are not identifiable from joint torques alone (the regressor is rank
deficient), so the minimum-norm least-squares solution is used; the predicted torques are
unique even where the parameters are not. No physical-consistency constraints (positive
masses, ...) are imposed: this is a model for prediction accuracy.

The acceleration is not measured. Offline it is a centred Savitzky-Golay derivative of the
velocity (:func:`smoothed_acceleration`); a causal estimate for streaming is in
:mod:`wrenchd.models.physics.causal_acceleration`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator
from scipy.signal import savgol_filter
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.physics.hysteresis import play
from wrenchd.models.series import N_JOINTS

#: Inertial columns of the regressor: 10 standard parameters for each of the six links.
N_INERTIAL = 10 * N_JOINTS


def smoothed_acceleration(velocity: np.ndarray, dt_s: float, window_s: float = 0.105,
                          order: int = 3) -> np.ndarray:
    """Joint accelerations (N, 6) from velocities (N, 6) sampled every ``dt_s`` seconds.

    A centred Savitzky-Golay derivative over ``window_s`` seconds (odd number of samples, at
    least ``order + 2``) of polynomial ``order``: smoothing and differentiating in one filter.
    It reads ``window_s / 2`` into the future: an offline estimate.
    """
    v = np.asarray(velocity, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != N_JOINTS or not dt_s > 0:
        raise DataError(f"velocity must be (N, 6) with dt_s > 0, got {v.shape}, {dt_s}")
    n = max(int(round(window_s / dt_s)) | 1, order + 2 | 1)
    if v.shape[0] < n:
        raise DataError(f"need at least {n} samples for the acceleration filter")
    return savgol_filter(v, n, order, deriv=1, delta=dt_s, axis=0)


class LeastSquaresConfig(BaseModel):
    """Columns of the rigid-body + friction model."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    coulomb_velocity: float | None = Field(
        default=0.02, gt=0.0,
        description="Coulomb friction as tanh(dq / v0) with this v0 [rad/s; m/s]; None: "
                    "sign(dq). A few times the velocity noise (about 0.01 rad/s on the PSM)")
    spring: bool = Field(default=True, description="a linear spring K * q per joint")
    hysteresis_width: tuple[float, ...] | None = Field(
        default=None,
        description="play-operator widths per joint [rad; m] of a presliding friction column "
                    "Fh * p(q) per joint; None: no such column")
    rcond: float = Field(
        default=1e-5, gt=0.0,
        description="lstsq cut-off of small singular values (relative): drops the directions "
                    "the data barely excite, whose large minimum-norm coefficients would turn "
                    "small input errors (an estimated acceleration) into large torque errors")

    @field_validator("hysteresis_width")
    @classmethod
    def _six_widths(cls, v: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if v is not None and (len(v) != N_JOINTS or min(v) <= 0):
            raise ValueError(f"hysteresis_width must be {N_JOINTS} positive widths, got {v}")
        return v


#: The default columns.
DEFAULT_LEAST_SQUARES = LeastSquaresConfig()
#: The first baseline's columns: sign(dq) Coulomb friction, no spring.
PLAIN_LEAST_SQUARES = LeastSquaresConfig(coulomb_velocity=None, spring=False, rcond=1e-10)


def coulomb_shape(dq: np.ndarray, coulomb_velocity: float | None) -> np.ndarray:
    """``sign(dq)``, or ``tanh(dq / v0)`` when ``coulomb_velocity`` v0 is given."""
    return np.sign(dq) if coulomb_velocity is None else np.tanh(dq / coulomb_velocity)


@dataclass(frozen=True)
class RigidBodyFrictionModel:
    """Identified parameters: ``coefficients`` in the column order of :meth:`columns`."""

    coefficients: np.ndarray
    rank: int
    config: LeastSquaresConfig = DEFAULT_LEAST_SQUARES

    @staticmethod
    def n_columns(config: LeastSquaresConfig) -> int:
        """60 inertial, 6 armature, 6 Coulomb, 6 viscous, 6 offset [, 6 spring] [, 6 play]."""
        return (N_INERTIAL + 4 * N_JOINTS + (N_JOINTS if config.spring else 0)
                + (N_JOINTS if config.hysteresis_width is not None else 0))

    @staticmethod
    def presliding(q: np.ndarray, config: LeastSquaresConfig) -> np.ndarray | None:
        """Play-operator outputs (N, 6) of one segment of (N, 6) positions started afresh, or
        None where ``config`` has no presliding column."""
        if config.hysteresis_width is None:
            return None
        return play(np.asarray(q, dtype=np.float64).reshape(-1, N_JOINTS),
                    np.array(config.hysteresis_width))[0]

    @staticmethod
    def columns(rigid: RigidBodyModel, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                config: LeastSquaresConfig = DEFAULT_LEAST_SQUARES,
                presliding: np.ndarray | None = None) -> np.ndarray:
        """Regressor (N, 6, :meth:`n_columns`) of (N, 6) positions, velocities, accelerations.

        ``presliding``: (N, 6) play-operator outputs where the samples continue a stream
        (:func:`wrenchd.models.physics.hysteresis.play` with its state); None computes them
        as one segment from its first sample. Ignored without ``config.hysteresis_width``.
        """
        y = rigid.regressor(q, dq, ddq)
        per_joint = RigidBodyFrictionModel._per_joint(y.shape[0], q, dq, ddq, config,
                                                      presliding)
        out = np.empty((y.shape[0], N_JOINTS, RigidBodyFrictionModel.n_columns(config)))
        out[:, :, :N_INERTIAL] = y
        eye = np.eye(N_JOINTS)
        for k, values in enumerate(per_joint):
            out[:, :, N_INERTIAL + k * N_JOINTS:N_INERTIAL + (k + 1) * N_JOINTS] = (
                eye * values[:, :, None])
        return out

    @staticmethod
    def _per_joint(n: int, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                   config: LeastSquaresConfig, presliding: np.ndarray | None
                   ) -> list[np.ndarray]:
        """The diagonal columns' (n, 6) values in their order: armature (ddq), Coulomb,
        viscous (dq), offset (ones) [, spring (q)] [, presliding] (``presliding`` as in
        :meth:`columns`)."""
        q, dq, ddq = (np.asarray(a, dtype=np.float64).reshape(n, N_JOINTS) for a in (q, dq, ddq))
        per_joint = [ddq, coulomb_shape(dq, config.coulomb_velocity), dq, np.ones_like(dq)]
        if config.spring:
            per_joint.append(q)
        if config.hysteresis_width is not None:
            p = (RigidBodyFrictionModel.presliding(q, config) if presliding is None
                 else np.asarray(presliding, dtype=np.float64))
            if p.shape != q.shape:
                raise DataError(f"presliding must have shape {q.shape}, got {p.shape}")
            per_joint.append(p)
        return per_joint

    @classmethod
    def fit(cls, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, tau: np.ndarray,
            rigid: RigidBodyModel | None = None,
            config: LeastSquaresConfig = DEFAULT_LEAST_SQUARES,
            presliding: np.ndarray | None = None) -> RigidBodyFrictionModel:
        """Least squares on (N, 6) positions, velocities, accelerations and torques.

        Each joint's equations are scaled by that joint's torque standard deviation, so the
        insertion joint (N) and the revolute joints (N m) weigh alike. ``presliding``: as in
        :meth:`columns` (pass it for several segments concatenated, each started afresh).
        """
        rigid = rigid if rigid is not None else RigidBodyModel()
        tau = np.asarray(tau, dtype=np.float64)
        a = cls.columns(rigid, q, dq, ddq, config, presliding)
        if tau.shape != a.shape[:2]:
            raise DataError(f"torques must have shape {a.shape[:2]}, got {tau.shape}")
        scale = np.maximum(tau.std(axis=0), 1e-9)                # (6,)
        a = (a / scale[None, :, None]).reshape(-1, a.shape[2])
        b = (tau / scale).reshape(-1)
        coef, _, rank, _ = np.linalg.lstsq(a, b, rcond=config.rcond)
        return cls(coef, int(rank), config)

    def predict(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                rigid: RigidBodyModel | None = None,
                presliding: np.ndarray | None = None) -> np.ndarray:
        """Joint torques (N, 6) [N m; N] (``presliding`` as in :meth:`columns`): the columns
        times the coefficients, without building the columns past the rigid body's (the
        others are diagonal: each joint's own value times its coefficient)."""
        rigid = rigid if rigid is not None else RigidBodyModel()
        coef = self.coefficients
        y = rigid.regressor(q, dq, ddq)
        out = y @ coef[:N_INERTIAL]
        for k, values in enumerate(self._per_joint(y.shape[0], q, dq, ddq, self.config,
                                                   presliding)):
            out += values * coef[N_INERTIAL + k * N_JOINTS:N_INERTIAL + (k + 1) * N_JOINTS]
        return out

    def to_dict(self) -> dict:
        """JSON-ready parameters (:meth:`from_dict` reads them back)."""
        return {"coefficients": self.coefficients.tolist(), "rank": self.rank,
                "config": self.config.model_dump()}

    @classmethod
    def from_dict(cls, d: dict) -> RigidBodyFrictionModel:
        """The model from :meth:`to_dict`'s output."""
        try:
            config = LeastSquaresConfig(**d["config"])
            coef = np.asarray(d["coefficients"], dtype=np.float64)
            rank = int(d["rank"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"not a rigid-body + friction parameter set: {exc}") from exc
        if coef.shape != (cls.n_columns(config),) or not np.isfinite(coef).all():
            raise ConfigError(f"expected {cls.n_columns(config)} finite coefficients, "
                              f"got shape {coef.shape}")
        return cls(coef, rank, config)
