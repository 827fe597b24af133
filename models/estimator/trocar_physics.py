"""The body wall at the port as physics, linear in its parameters: step 2's part that carries to
new poses.

The correction net (:class:`~wrenchd.models.estimator.correction.Corr`) learns this patient's
trocar only where the arm has been: on poses it has not seen it extrapolates, and on the real
recordings with a simulated trocar it read 4 N of false force after the motion changed. Of the
port's two forces, the body wall depends on the pose (the shaft's direction about the
incision), and it is linear in a dozen parameters whatever the incision, so a least-squares fit
carries it to any pose:

* **Body wall** (:mod:`~wrenchd.models.physics.effects.body_wall`): a lateral spring-damper on
  the shaft about the incision ``p`` (base axes, from the RCM). With the shaft axis ``u(q)``
  and ``d_j = du/dq_j`` (``u . d_j = 0``), the wall's torque on yaw and pitch (j = 0, 1) is
  ``tau_j = -k (u . p)(p . d_j) + c (u . p)^2 (du/dt . d_j)``. Written with the six products
  ``p_a p_b`` (a <= b) it is linear in ``k p_a p_b`` and ``c p_a p_b``: twelve parameters
  shared by yaw and pitch, whatever the incision, stiffness and damping (the three diagonal
  stiffness products are known only up to a common shift, since ``sum_a u_a d_ja = 0``: the
  fit's ridge holds that direction).

The cannula seal (:mod:`~wrenchd.models.physics.effects.seal`) is left to the net: its friction
depends on the insertion and roll velocities, whose whole range any minute of motion covers,
and its sliding curve alone (``f_c tanh(v / v_s) + f_v v``) missed 0.3 N of the simulated seal's
hysteresis on the real recordings with a simulated trocar; with it in the physics, the
simulated sessions' false contacts tripled (``docs/results.md``).

:func:`trocar_regressors` gives the (N, 6, 12) regressor, :func:`trocar_torque` the torques of
parameters ``theta`` (12,), and :func:`fit_trocar` the ridge fit towards a current ``theta``.
Pure NumPy, float64.
"""

from __future__ import annotations

import math

import numpy as np

from wrenchd.models.errors import DataError

#: parameters: the body wall's stiffness and damping times the six products p_a p_b
N_TROCAR = 12
_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def trocar_regressors(q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """(N, 6, 12) torque per unit of each parameter [N m or N per unit], for positions and
    velocities (N, 6): ``tau = X @ theta`` (module docstring)."""
    q = np.asarray(q, dtype=np.float64)
    dq = np.asarray(dq, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 6 or dq.shape != q.shape:
        raise DataError(f"trocar regressors: expected (N, 6) positions and velocities, got "
                        f"{q.shape}, {dq.shape}")
    n = len(q)
    s1, c1 = np.sin(q[:, 0]), np.cos(q[:, 0])
    s2, c2 = np.sin(q[:, 1]), np.cos(q[:, 1])
    zero = np.zeros(n)
    # the shaft axis and its derivatives (models/physics/kinematics.py's closed form)
    u = (s1 * c2, -s2, -c1 * c2)
    d = ((c1 * c2, zero, s1 * c2), (-s1 * s2, -c2, c1 * s2))
    w1, w2 = dq[:, 0], dq[:, 1]
    u_dot = tuple(d[0][a] * w1 + d[1][a] * w2 for a in range(3))
    x = np.zeros((n, 6, N_TROCAR))
    uu = [u[a] * u[b] * (1.0 if a == b else 2.0) for a, b in _PAIRS]
    for j in (0, 1):
        dj = d[j]
        speed = u_dot[0] * dj[0] + u_dot[1] * dj[1] + u_dot[2] * dj[2]
        for k, (a, b) in enumerate(_PAIRS):
            x[:, j, k] = -(u[a] * dj[b] + u[b] * dj[a]) if a != b else -u[a] * dj[a]
            x[:, j, 6 + k] = uu[k] * speed
    return x


def trocar_torque(q: np.ndarray, dq: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(N, 6) trocar torques [N m; N] of parameters ``theta`` (12,) at (N, 6) ``q``, ``dq``."""
    return trocar_regressors(q, dq) @ np.asarray(theta, dtype=np.float64)


def wall_torque_one(q, dq, stiffness: list[list[float]], damping: list[list[float]]
                    ) -> tuple[float, float]:
    """Yaw and pitch torque [N m] of one sample (``q``, ``dq``: 6 values each), for the
    matrices of :func:`wall_matrices` as nested lists: :func:`trocar_torque` in plain floats,
    for the streaming path (a few us, where the array version costs tens)."""
    s1, c1, s2, c2 = math.sin(q[0]), math.cos(q[0]), math.sin(q[1]), math.cos(q[1])
    u = (s1 * c2, -s2, -c1 * c2)
    d1 = (c1 * c2, 0.0, s1 * c2)
    d2 = (-s1 * s2, -c2, c1 * s2)
    w1, w2 = float(dq[0]), float(dq[1])
    u_dot = [d1[a] * w1 + d2[a] * w2 for a in range(3)]
    ku = [u[0] * stiffness[0][a] + u[1] * stiffness[1][a] + u[2] * stiffness[2][a]
          for a in range(3)]
    cu = [u[0] * damping[0][a] + u[1] * damping[1][a] + u[2] * damping[2][a] for a in range(3)]
    depth2 = cu[0] * u[0] + cu[1] * u[1] + cu[2] * u[2]           # u^T C u
    out = []
    for d in (d1, d2):
        out.append(-(ku[0] * d[0] + ku[1] * d[1] + ku[2] * d[2])
                   + depth2 * (u_dot[0] * d[0] + u_dot[1] * d[1] + u_dot[2] * d[2]))
    return out[0], out[1]


def wall_matrices(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stiffness and damping parts of ``theta`` (12,) as symmetric 3x3 matrices
    (``k p p^T`` and ``c p p^T`` for a physical wall)."""
    out = []
    for part in (theta[:6], theta[6:12]):
        m = np.zeros((3, 3))
        for value, (a, b) in zip(part, _PAIRS):
            m[a, b] = m[b, a] = value
        out.append(m)
    return out[0], out[1]


def wall_theta(k: float, c: float, incision) -> np.ndarray:
    """``theta`` (12,) of a wall of stiffness ``k`` [N/m] and damping ``c`` [N s/m] about the
    incision point (3,) [m]."""
    p = np.asarray(incision, dtype=np.float64)
    pp = np.array([p[a] * p[b] for a, b in _PAIRS])
    return np.concatenate([k * pp, c * pp])


def fit_trocar(q: np.ndarray, dq: np.ndarray, residual: np.ndarray,
               theta: np.ndarray | None = None, shrink: float = 1e-3,
               physical: bool = True) -> np.ndarray:
    """``theta`` (12,) fitted to residual torques (N, 6) [N m; N] at (N, 6) ``q``, ``dq``.

    First the linear fit ``argmin |X theta - r|^2 + lam |D (theta - theta_0)|^2`` over the
    six joints' torques, with ``D`` each column's RMS, ``lam = shrink * trace(D^-1 X^T X
    D^-1) / 12`` and ``theta_0`` the current parameters (zeros when None): a parameter the
    motion does not excite stays where it was. With ``physical`` (the default), the result is
    then made a wall's: the twelve free parameters can also take up pose-dependent errors of
    step 1, which the physics would carry everywhere, while a wall's are ``k p p^T`` and
    ``c p p^T`` for one incision ``p``, stiffness ``k >= 0`` and damping ``c >= 0``. The
    incision's direction is the stiffness matrix's leading eigenvector (after the common
    diagonal shift the torque cannot see), and ``k |p|^2`` and ``c |p|^2`` are fitted again
    on that direction (clipped at 0). Rows with a non-finite value are left out.
    """
    x = trocar_regressors(q, dq)
    r = np.asarray(residual, dtype=np.float64)
    if r.shape != (len(x), 6):
        raise DataError(f"trocar fit: expected ({len(x)}, 6) residuals, got {r.shape}")
    current = np.zeros(N_TROCAR) if theta is None else np.asarray(theta, np.float64)
    ok = np.isfinite(r).all(axis=1) & np.isfinite(x).all(axis=(1, 2))
    if not ok.any():
        return current.copy()
    x = x[ok]
    a = x.reshape(-1, N_TROCAR)
    b = r[ok].reshape(-1)
    scale = np.sqrt(np.mean(a * a, axis=0))
    scale[scale == 0.0] = 1.0
    a = a / scale
    gram = a.T @ a
    lam = max(shrink * np.trace(gram) / N_TROCAR, 1e-12)
    solved = np.linalg.solve(gram + lam * np.eye(N_TROCAR), a.T @ b + lam * current * scale)
    solved /= scale
    if not physical:
        return solved
    stiffness, _ = wall_matrices(solved)
    _, vectors = np.linalg.eigh(stiffness)          # ascending: the leading one is last
    direction = vectors[:, -1]
    pp = np.array([direction[i] * direction[j] for i, j in _PAIRS])
    # the torque of k|p|^2 = 1 and of c|p|^2 = 1 along that direction: two columns
    cols = np.stack([x[:, :, :6] @ pp, x[:, :, 6:] @ pp], axis=-1).reshape(-1, 2)
    g2 = cols.T @ cols
    size = np.linalg.solve(g2 + 1e-12 * np.trace(g2) * np.eye(2), cols.T @ b)
    return np.concatenate([pp * max(size[0], 0.0), pp * max(size[1], 0.0)])
