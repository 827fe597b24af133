"""Which inertial parameters the joint torques can identify: the base columns.

The regressor ``[Y | diag(ddq)]`` (66 columns: 10 standard parameters per link, then six
armatures) plus six joint-offset columns has many columns that are zero for every motion
(a link's inertia about axes it never turns about) or linear combinations of others (the
mass of a link sitting on an axis, armature and link inertia about the same axis). The base
set is found structurally, independent of a recording: QR with column pivoting on the
stacked columns of random states in the joint limits picks a maximal independent subset;
the remaining columns' effect on torque is carried by the base columns they depend on.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import qr

from wrenchd.models.physics.effects.base import Motion
from wrenchd.models.physics.effects.inertial import inertial_columns

#: |R_kk| / |R_00| below this counts as dependent (columns are scaled to unit norm first).
STRUCTURAL_TOL = 1e-8
N_INERTIAL = 66


def offset_columns(n: int) -> np.ndarray:
    """Joint-offset columns (n, 6, 6): column j is 1 on joint j."""
    out = np.zeros((n, 6, 6))
    out[:, np.arange(6), np.arange(6)] = 1.0
    return out


def independent_columns(x: np.ndarray, tol: float) -> np.ndarray:
    """Indices of a maximal independent subset of the columns of ``x`` (rows, k), sorted."""
    norms = np.linalg.norm(x, axis=0)
    live = np.flatnonzero(norms > 0)
    if live.size == 0:
        return live
    _, r, piv = qr(x[:, live] / norms[live], mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    rank = int(np.sum(diag > tol * diag[0]))
    return np.sort(live[piv[:rank]])


def structural_base(robot, n_states: int = 400, seed: int = 0) -> np.ndarray:
    """Base columns of ``[Y | armature | offset]`` (72 columns) for the chain ``robot``.

    Args:
        robot: a :class:`~wrenchd.models.physics.dynamics.RigidBodyModel`.

    Returns:
        Sorted column indices (0..71); 66..71 are the offsets.
    """
    rng = np.random.default_rng(seed)
    lo, hi = robot.model.lowerPositionLimit, robot.model.upperPositionLimit
    q = rng.uniform(lo, hi, (n_states, 6))
    dq, ddq = rng.normal(0, 1, (2, n_states, 6))
    motion = Motion(np.arange(n_states, dtype=float), q, dq, ddq, robot)
    cols = np.concatenate([inertial_columns(motion), offset_columns(n_states)], axis=2)
    return independent_columns(cols.reshape(-1, cols.shape[2]), STRUCTURAL_TOL)
