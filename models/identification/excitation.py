"""Optimised excitation trajectories for identifying the PSM's rigid body and friction.

Each excited joint follows a finite Fourier series (Swevers, Ganseman, Tukel, De Schutter,
Van Brussel, "Optimal robot excitation and identification", IEEE Trans. Robotics and
Automation 13(5), 1997), periodic in ``T = 1 / f`` with base frequency ``f`` [Hz] and
``N`` harmonics, ``w = 2 pi f``, positions in rad (m on insertion)::

    q_j(t)   = q0_j + sum_k  a_jk / (w k) sin(w k t) - b_jk / (w k) cos(w k t)
    dq_j(t)  =        sum_k  a_jk cos(w k t) + b_jk sin(w k t)
    ddq_j(t) =        sum_k -a_jk w k sin(w k t) + b_jk w k cos(w k t)

Periodicity lets repeated periods be averaged and makes velocities and accelerations
analytic. The first harmonic is fixed by ``sum_k a_jk = 0`` and ``sum_k k b_jk = 0``, so the
trajectory starts and ends at rest (``dq = ddq = 0`` at ``t = 0, T``): the arm is moved to
``q(0)`` and the set-points streamed from there.

The optimiser (:func:`optimise_excitation`) minimises the condition number of the
base-parameter regressor over one period, the criterion of Gautier and Khalil ("Exciting
trajectories for the identification of base inertial parameters of robots", IJRR 11(4), 1992)
that the WPI dVRK package (Wang et al., RA-L 2019) minimises, within the joint limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.identification.base_parameters import (
    STRUCTURAL_TOL, independent_columns, offset_columns,
)
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.physics.effects.base import Motion
from wrenchd.models.physics.effects.friction import SIGN_SMOOTHING, smooth_sign
from wrenchd.models.physics.effects.inertial import inertial_columns
from wrenchd.models.physics.kinematics import PSM_LOWER, PSM_UPPER
from wrenchd.models.series import N_JOINTS

# Default box [rad, rad, m, rad, rad, rad], inside the dVRK joint limits (PSM_LOWER/UPPER,
# psm-large-needle-driver.json) and close to where the WPI excitation trajectories drove a
# real PSM (their recordings span yaw -0.56..0.07, pitch -0.76..0.80, insertion 0.07..0.235 m,
# roll -1.3..1.4, wrist -1.2..0.7). The insertion stays >= 60 mm: the dVRK's own inverse
# kinematics keeps the tool at least 40 mm past the RCM (mtsIntuitiveResearchKitPSM.cpp).
DEFAULT_LOWER = (-0.8, -0.8, 0.06, -1.4, -1.2, -1.2)
DEFAULT_UPPER = (0.8, 0.8, 0.22, 1.4, 1.2, 1.2)
# Speed caps [rad/s; m/s]: under the dVRK's joint trajectory-generator caps (180 deg/s for
# yaw/pitch, 0.2 m/s insertion, 3 x 360 deg/s wrist: jhu-dvrk/sawIntuitiveResearchKit,
# mtsIntuitiveResearchKitPSM.cpp, Init) and at the speeds the WPI trajectories reached on the
# real arm (1.5 rad/s yaw/pitch, 0.32 m/s insertion, 2.4-2.7 rad/s wrist).
DEFAULT_MAX_VELOCITY = (1.5, 1.5, 0.2, 2.5, 2.5, 2.5)
# Acceleration caps [rad/s^2; m/s^2]: about half the 99th percentile of |ddq| on the WPI
# recordings (yaw 9-11, pitch 7-9, insertion 2.2, wrist 40-60).
DEFAULT_MAX_ACCELERATION = (5.0, 4.0, 1.0, 20.0, 20.0, 20.0)
DEFAULT_HOLD = (0.0, 0.0, 0.12, 0.0, 0.0, 0.0)


def _six(name: str, v) -> tuple[float, ...]:
    v = tuple(float(x) for x in v)
    if len(v) != N_JOINTS or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be {N_JOINTS} finite numbers, got {v}")
    return v


class ExcitationConfig(BaseModel):
    """What to excite, within which limits, and how hard to optimise."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    joints: tuple[int, ...] = Field(default=(1, 2, 3), description="excited joints, 1-based")
    base_frequency_hz: float = Field(default=0.1, gt=0, le=2.0, description="f = 1 / period [Hz]")
    harmonics: int = Field(default=5, ge=2, le=20, description="N, harmonics per joint")
    rate_hz: float = Field(default=200.0, gt=0, description="set-point rate [Hz]")
    lower: tuple[float, ...] = Field(default=DEFAULT_LOWER, description="position box [rad; m]")
    upper: tuple[float, ...] = Field(default=DEFAULT_UPPER, description="position box [rad; m]")
    max_velocity: tuple[float, ...] = Field(default=DEFAULT_MAX_VELOCITY,
                                            description="|dq| cap [rad/s; m/s]")
    max_acceleration: tuple[float, ...] = Field(default=DEFAULT_MAX_ACCELERATION,
                                                description="|ddq| cap [rad/s^2; m/s^2]")
    hold: tuple[float, ...] = Field(default=DEFAULT_HOLD,
                                    description="position of the joints not excited [rad; m]")
    margin: float = Field(default=0.98, gt=0, le=1.0,
                          description="fraction of each limit the trajectory may use")
    samples: int = Field(default=100, ge=20, description="regressor samples per period")
    iterations: int = Field(default=100, ge=0, description="optimiser budget: at most this many "
                            "iterations and iterations x (decision variables + 1) objective "
                            "evaluations (0: keep the seeded start)")
    seed: int = 0

    @model_validator(mode="after")
    def _check(self):
        for name in ("lower", "upper", "max_velocity", "max_acceleration", "hold"):
            _six(name, getattr(self, name))
        if not self.joints or len(set(self.joints)) != len(self.joints) or not all(
                1 <= j <= N_JOINTS for j in self.joints):
            raise ValueError(f"joints must be distinct numbers in 1..6, got {self.joints}")
        lo, hi = np.array(self.lower), np.array(self.upper)
        if np.any(lo >= hi):
            raise ValueError(f"lower {self.lower} must lie below upper {self.upper}")
        if np.any(lo < PSM_LOWER) or np.any(hi > PSM_UPPER):
            raise ValueError(f"the box [{self.lower}, {self.upper}] leaves the PSM joint "
                             f"limits [{tuple(PSM_LOWER)}, {tuple(PSM_UPPER)}]")
        if min(self.max_velocity) <= 0 or min(self.max_acceleration) <= 0:
            raise ValueError("max_velocity and max_acceleration must be > 0")
        hold = np.array(self.hold)
        if np.any(hold < lo) or np.any(hold > hi):
            raise ValueError(f"hold {self.hold} must lie inside the box")
        return self

    @property
    def index(self) -> np.ndarray:
        """Excited joints, 0-based."""
        return np.array(sorted(j - 1 for j in self.joints))

    @property
    def period_s(self) -> float:
        return 1.0 / self.base_frequency_hz


@dataclass(frozen=True)
class FourierTrajectory:
    """A periodic joint trajectory (module docstring): ``a``, ``b`` (6, N) [rad/s; m/s],
    ``q0`` (6,) [rad; m], base frequency [Hz]. Joints with zero coefficients stay at q0."""

    base_frequency_hz: float
    a: np.ndarray
    b: np.ndarray
    q0: np.ndarray

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, accelerations (n, 6) at times ``t`` (n,) [s]."""
        t = np.asarray(t, dtype=np.float64)
        k = np.arange(1, self.a.shape[1] + 1)
        wk = 2 * np.pi * self.base_frequency_hz * k                     # (N,)
        s, c = np.sin(t[:, None] * wk), np.cos(t[:, None] * wk)         # (n, N)
        q = self.q0 + s @ (self.a / wk).T - c @ (self.b / wk).T
        dq = c @ self.a.T + s @ self.b.T
        ddq = -s @ (self.a * wk).T + c @ (self.b * wk).T
        return q, dq, ddq


class RegressorCondition:
    """Condition number of the identification regressor over a trajectory (excited rows)."""

    def __init__(self, config: ExcitationConfig, robot: RigidBodyModel | None = None,
                 n_states: int = 400) -> None:
        self.robot = robot if robot is not None else RigidBodyModel()
        self.joints = config.index
        self.hold = np.array(config.hold)
        self.base = self._structural_base(n_states, config.seed)

    def _structural_base(self, n: int, seed: int) -> np.ndarray:
        """Independent inertial and offset columns when only ``joints`` move."""
        rng = np.random.default_rng(seed)
        lo, hi = self.robot.model.lowerPositionLimit, self.robot.model.upperPositionLimit
        j = self.joints
        q, dq, ddq = np.tile(self.hold, (n, 1)), np.zeros((n, N_JOINTS)), np.zeros((n, N_JOINTS))
        q[:, j] = rng.uniform(lo[j], hi[j], (n, j.size))
        dq[:, j], ddq[:, j] = rng.normal(0, 1, (2, n, j.size))
        cols = self._inertial(q, dq, ddq)
        return independent_columns(cols.reshape(-1, cols.shape[2]), STRUCTURAL_TOL)

    def _inertial(self, q, dq, ddq) -> np.ndarray:
        motion = Motion(np.arange(q.shape[0], dtype=float), q, dq, ddq, self.robot)
        cols = np.concatenate([inertial_columns(motion), offset_columns(q.shape[0])], axis=2)
        return cols[:, self.joints]

    @property
    def n_parameters(self) -> int:
        return int(self.base.size + 2 * self.joints.size)

    def matrix(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Stacked regressor (n * joints, parameters): base columns, Coulomb, viscous."""
        n, m = q.shape[0], self.joints.size
        inertial = self._inertial(q, dq, ddq)[:, :, self.base]
        fric = np.zeros((n, m, 2 * m))
        rows = np.arange(m)
        fric[:, rows, rows] = smooth_sign(dq[:, self.joints], SIGN_SMOOTHING)
        fric[:, rows, rows + m] = dq[:, self.joints]
        return np.concatenate([inertial, fric], axis=2).reshape(n * m, -1)

    def __call__(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> float:
        s = np.linalg.svd(self.matrix(q, dq, ddq), compute_uv=False)
        return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


@dataclass
class Excitation:
    """Result of :func:`optimise_excitation`.

    Attributes:
        trajectory: the optimised :class:`FourierTrajectory`.
        initial: the seeded starting trajectory (same limits).
        cond_initial, cond_final: regressor condition numbers over one period.
        parameters: columns of the regressor (base inertial + offsets + 2 per excited joint).
        info: optimiser iterations, evaluations and message.
    """

    config: ExcitationConfig
    trajectory: FourierTrajectory
    initial: FourierTrajectory
    cond_initial: float
    cond_final: float
    parameters: int
    info: dict = field(default_factory=dict)

    def set_points(self, periods: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``t`` (n,) [s] and q, dq, ddq (n, 6) at ``config.rate_hz`` over ``periods`` periods,
        both ends included (the arm is at rest at each)."""
        return sample_periods(self.config, self.trajectory, periods)


def sample_periods(config: ExcitationConfig, trajectory: FourierTrajectory, periods: int = 1):
    """``(t, q, dq, ddq)`` on the set-point grid ``k / rate_hz``, ``periods`` periods."""
    if periods < 1:
        raise DataError(f"periods must be >= 1, got {periods}")
    n = int(round(periods * config.period_s * config.rate_hz))
    t = np.arange(n + 1) / config.rate_hz
    return (t, *trajectory.sample(t))


class _Parametrisation:
    """Decision vector <-> trajectory; every trajectory it builds meets the limits."""

    def __init__(self, config: ExcitationConfig) -> None:
        self.config = config
        self.joints = config.index
        self.n = config.harmonics
        self.free = 2 * (self.n - 1)                         # a_2..a_N, b_2..b_N per joint
        self.k = np.arange(1, self.n + 1)
        self.w = 2 * np.pi * config.base_frequency_hz
        self.lo, self.hi = np.array(config.lower), np.array(config.upper)
        self.vmax, self.amax = np.array(config.max_velocity), np.array(config.max_acceleration)
        # the set-point grid of one period: limits hold exactly where the arm is commanded
        steps = int(round(config.period_s * config.rate_hz))
        t = np.arange(steps) / config.rate_hz
        self.s, self.c = np.sin(np.outer(t, self.w * self.k)), np.cos(np.outer(t, self.w * self.k))

    @property
    def size(self) -> int:
        return self.joints.size * (self.free + 1)

    def bounds(self) -> list[tuple[float, float]]:
        per_joint = [(-1.0, 1.0)] * self.free + [(0.1, 0.9)]     # shape, centre fraction
        return per_joint * self.joints.size

    def initial(self, rng: np.random.Generator) -> np.ndarray:
        x = rng.uniform(-1.0, 1.0, (self.joints.size, self.free + 1))
        x[:, -1] = 0.5
        return x.reshape(-1)

    def trajectory(self, x: np.ndarray) -> FourierTrajectory:
        a, b = np.zeros((N_JOINTS, self.n)), np.zeros((N_JOINTS, self.n))
        q0 = np.array(self.config.hold, dtype=np.float64)
        k, w = self.k, self.w
        for row, j in zip(x.reshape(self.joints.size, -1), self.joints):
            aj = np.r_[0.0, row[:self.n - 1]]
            bj = np.r_[0.0, row[self.n - 1:self.free]]
            aj[0] = -aj[1:].sum()                           # dq(0) = 0
            bj[0] = -(k[1:] * bj[1:]).sum()                 # ddq(0) = 0
            pos = self.s @ (aj / (w * k)) - self.c @ (bj / (w * k))
            vel = self.c @ aj + self.s @ bj
            acc = -self.s @ (aj * w * k) + self.c @ (bj * w * k)
            centre = self.lo[j] + row[-1] * (self.hi[j] - self.lo[j])
            half = max((pos.max() - pos.min()) / 2, 1e-12)
            scale = self.config.margin * min(
                min(self.hi[j] - centre, centre - self.lo[j]) / half,
                self.vmax[j] / max(np.abs(vel).max(), 1e-12),
                self.amax[j] / max(np.abs(acc).max(), 1e-12))
            a[j], b[j] = scale * aj, scale * bj
            q0[j] = centre - scale * (pos.max() + pos.min()) / 2
        return FourierTrajectory(self.config.base_frequency_hz, a, b, q0)


def optimise_excitation(config: ExcitationConfig | None = None,
                        robot: RigidBodyModel | None = None) -> Excitation:
    """An excitation trajectory within the limits with a minimal regressor condition number.

    Limits are met by construction: each joint's free coefficients are scaled by the largest
    factor that keeps its position inside the box, its speed under ``max_velocity`` and its
    acceleration under ``max_acceleration`` on the output grid (times a margin), with the
    centre of its swing a bounded decision variable. ``scipy.optimize.minimize`` (L-BFGS-B,
    finite differences, a bounded number of iterations, seeded start) then minimises ``log10``
    of the condition number of the base-parameter regressor of
    :mod:`~wrenchd.models.identification.free_motion`'s model (base inertial and offset
    columns plus Coulomb ``tanh(dq / eps)`` and viscous ``dq``) stacked over one period: the
    criterion of Gautier and Khalil that Swevers et al. compare with. Only the torques of the
    excited joints enter: a joint held still by its controller measures mostly its own
    stiction.

    Args:
        config: joints, frequencies, limits, optimiser budget (defaults: joints 1-3, 0.1 Hz,
            5 harmonics, 100 iterations).
        robot: the rigid-body model whose regressor is conditioned (default nominal PSM).

    Raises:
        ConfigError: the configuration is inconsistent.
    """
    from scipy.optimize import minimize

    config = config if config is not None else ExcitationConfig()
    measure = RegressorCondition(config, robot)
    par = _Parametrisation(config)
    t_obj = np.arange(config.samples) * (config.period_s / config.samples)
    evaluations = 0

    def objective(x: np.ndarray) -> float:
        nonlocal evaluations
        evaluations += 1
        cond = measure(*par.trajectory(x).sample(t_obj))
        return float(np.log10(cond)) if np.isfinite(cond) else 1e6

    x0 = par.initial(np.random.default_rng(config.seed))
    f0 = objective(x0)
    x, f = x0, f0
    info: dict = {"iterations": 0, "message": "not optimised (iterations = 0)"}
    if config.iterations > 0:
        # a finite-difference gradient costs size + 1 evaluations: the budget is that per
        # iteration, so line searches cannot stretch the run past ``iterations`` gradients
        res = minimize(objective, x0, method="L-BFGS-B", bounds=par.bounds(),
                       options={"maxiter": config.iterations,
                                "maxfun": config.iterations * (par.size + 1)})
        if res.fun < f0:
            x, f = res.x, float(res.fun)
        info = {"iterations": int(res.nit), "message": str(res.message)}
    info["evaluations"] = evaluations
    return Excitation(config, par.trajectory(x), par.trajectory(x0), 10.0 ** f0, 10.0 ** f,
                      measure.n_parameters, info)


def excitation_config(**values) -> ExcitationConfig:
    """:class:`ExcitationConfig` from keyword values; a bad value raises ConfigError."""
    try:
        return ExcitationConfig(**values)
    except Exception as exc:          # pydantic.ValidationError
        raise ConfigError(f"excitation: {exc}") from None
