"""Least-squares identification of a physics model from free-motion joint data.

Model (linear in its parameters), per joint ``j``::

    tau_j = tau_nominal_j + sum_b Y_b,j delta_b + fc_j tanh(dq_j / eps) + fv_j dq_j + offset_j

``tau_nominal`` is the nominal rigid body (the model file's ``rigid_body`` section, default
:mod:`wrenchd.models.physics.dynamics`), ``Y_b`` the identifiable base columns of the inertial
regressor (:mod:`~wrenchd.models.identification.base_parameters`), so ``delta`` is the change of the
base parameters from nominal, which keeps the file's ``rigid_body`` physically consistent and
puts the identified correction in an ``inertial_delta`` effect. Friction and offsets are the
existing ``coulomb_friction``, ``viscous_friction`` and ``joint_offset`` effects.

Fit: statsmodels weighted least squares, rows of joint ``j`` weighted by ``1 / sigma_j^2``
with ``sigma_j`` the residual level of a first unweighted pass, so the insertion force [N]
and the wrist torques [mN m] count by their own noise, not their units. Base columns this
recording does not excite (relative pivot of the scaled, weighted columns below
``EXCITATION_TOL``) keep their nominal value. The held-out error is measured on contiguous
blocks (time series: a random split would interleave neighbouring, correlated samples).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import statsmodels.api as sm

from wrenchd.models.errors import DataError
from wrenchd.models.identification.base_parameters import independent_columns, offset_columns, structural_base
from wrenchd.models.identification.differentiation import smoothed_acceleration, zero_phase_velocity
from wrenchd.models.physics.effects.base import Motion
from wrenchd.models.physics.effects.friction import SIGN_SMOOTHING, smooth_sign
from wrenchd.models.physics.effects.inertial import column_name, inertial_columns
from wrenchd.models.physics.model import PhysicsModel

#: Relative pivot below which a base column counts as not excited by the recording.
EXCITATION_TOL = 1e-3
N_FOLDS = 5


@dataclass
class Identification:
    """Result of :func:`identify_free_motion`.

    Attributes:
        model: the identified :class:`PhysicsModel` (rigid body + inertial_delta + friction).
        heldout_rms: (6,) RMS residual per joint on held-out contiguous blocks [N m; N].
        fit_rms: (6,) RMS residual per joint of the fit on all data.
        columns: names of the fitted inertial base columns.
        unexcited: names of structural base columns kept at nominal (not excited).
    """

    model: PhysicsModel
    heldout_rms: np.ndarray
    fit_rms: np.ndarray
    columns: list[str]
    unexcited: list[str]
    info: dict[str, Any] = field(default_factory=dict)


def _design(motion: Motion, base: np.ndarray, with_offset: bool) -> tuple[np.ndarray, list[str]]:
    """Columns (N, 6, k) and their names: base inertial, offsets, Coulomb, viscous."""
    n = len(motion)
    inertial = np.concatenate([inertial_columns(motion), offset_columns(n)], axis=2)[:, :, base]
    names = [column_name(i) if i < 66 else f"offset{i - 65}" for i in base]
    if not with_offset:
        keep = [k for k, name in enumerate(names) if not name.startswith("offset")]
        inertial, names = inertial[:, :, keep], [names[k] for k in keep]
    fric = np.zeros((n, 6, 12))
    idx = np.arange(6)
    fric[:, idx, idx] = smooth_sign(motion.dq, SIGN_SMOOTHING)
    fric[:, idx, idx + 6] = motion.dq
    names += [f"fc{j}" for j in range(1, 7)] + [f"fv{j}" for j in range(1, 7)]
    return np.concatenate([inertial, fric], axis=2), names


def _wls(x: np.ndarray, y: np.ndarray, w_joint: np.ndarray):
    """statsmodels WLS on stacked rows; x (N, 6, k), y (N, 6), weights per joint (6,)."""
    n, _, k = x.shape
    weights = np.broadcast_to(w_joint, (n, 6)).reshape(-1)
    return sm.WLS(y.reshape(-1), x.reshape(-1, k), weights=weights, hasconst=False).fit()


def identify_free_motion(t: np.ndarray, q: np.ndarray, dq: np.ndarray, tau: np.ndarray,
                         nominal: PhysicsModel | None = None, with_offset: bool = True,
                         description: str = "") -> Identification:
    """Fit base inertial parameters, Coulomb/viscous friction and offsets to free motion.

    Args:
        t: (N,) times [s]; q, dq, tau: (N, 6) positions, velocities, efforts (SI, N on insertion).
        nominal: model whose ``rigid_body`` is the starting point (its effects are ignored).
        with_offset: also fit a constant offset per joint.

    Returns:
        :class:`Identification`.

    Raises:
        DataError: too few samples, or the data are not finite.
    """
    t, q, dq, tau = (np.asarray(a, float) for a in (t, q, dq, tau))
    if q.shape[0] < 200:
        raise DataError(f"identification needs at least 200 samples, got {q.shape[0]}")
    nominal = nominal if nominal is not None else PhysicsModel()
    rigid_cfg = nominal.config.rigid_body
    base_model = PhysicsModel.from_dict({"rigid_body": rigid_cfg.model_dump(mode="json")})
    dq, from_position = zero_phase_velocity(t, q, dq)
    ddq = smoothed_acceleration(t, dq)
    motion = base_model.motion(t, q, dq, ddq)
    y = tau - base_model.rigid_body_torque(motion)                  # (N, 6)
    x, names = _design(motion, structural_base(base_model.robot), with_offset)

    # pass 1: unweighted, for the per-joint noise level
    sigma = np.std(y - (x @ _wls(x, y, np.ones(6)).params), axis=0) + 1e-9
    w = 1.0 / sigma**2
    # drop base columns the recording does not excite (scaled, weighted pivots)
    xw = (x * np.sqrt(w)[None, :, None]).reshape(-1, x.shape[2])
    keep = independent_columns(xw, EXCITATION_TOL)
    unexcited = [names[k] for k in range(len(names)) if k not in set(keep)]
    x, names = x[:, :, keep], [names[k] for k in keep]
    fit = _wls(x, y, w)
    params = dict(zip(names, fit.params))
    fit_rms = np.sqrt(np.mean((y - x @ fit.params) ** 2, axis=0))

    heldout = np.empty_like(y)
    for test in np.array_split(np.arange(len(t)), N_FOLDS):
        train = np.setdiff1d(np.arange(len(t)), test)
        heldout[test] = y[test] - x[test] @ _wls(x[train], y[train], w).params
    heldout_rms = np.sqrt(np.mean(heldout**2, axis=0))

    inertial = [nm for nm in names if "." in nm]
    effects = [
        {"name": "inertial_delta", "params": {
            "columns": inertial, "delta": [float(params[nm]) for nm in inertial],
            "identified_rms": [float(v) for v in heldout_rms]}},
        {"name": "coulomb_friction",
         "params": {"fc": [float(params.get(f"fc{j}", 0.0)) for j in range(1, 7)]}},
        {"name": "viscous_friction",
         "params": {"fv": [float(params.get(f"fv{j}", 0.0)) for j in range(1, 7)]}},
    ]
    if with_offset:
        effects.append({"name": "joint_offset", "params": {
            "offset": [float(params.get(f"offset{j}", 0.0)) for j in range(1, 7)]}})
    model = PhysicsModel.from_dict({
        "description": description or "identified from free motion by wrenchd identify",
        "rigid_body": rigid_cfg.model_dump(mode="json"), "effects": effects})
    return Identification(model, heldout_rms, fit_rms, inertial, unexcited,
                          {"samples": int(len(t)), "noise_sigma": sigma.tolist(),
                           "velocity_from_position": [int(j) + 1 for j in np.flatnonzero(from_position)],
                           "condition_number": float(fit.condition_number)})
