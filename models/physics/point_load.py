"""The joint torques of a point mass fixed to a PSM link, the parallelogram's links included.

A load (a payload, an instrument's mass, a weight hung on the arm to check an estimate) of
mass ``m`` [kg] at a point ``p`` fixed in a link's frame moves with the joints; the motors
hold it with

    tau_j = m (a_p - g) . dp/dq_j            [N m; N on insertion]

where ``p(q)`` is the point in base axes [m], ``a_p`` its acceleration and ``g`` gravity
[m/s^2] (the base frame of :mod:`wrenchd.models.physics.kinematics`, origin at the RCM, and
the gravity of :class:`~wrenchd.models.physics.dynamics.RigidBodyConfig`, ``-z``). Gravity
alone (``a_p = 0``) is the static part; with the trajectory's acceleration (a centred,
offline derivative of ``p(t)``) the point's inertia is included.

Links (:data:`LINKS`): the serial chain's, by joint name (``outer_yaw`` ...
``outer_wrist_yaw``, the modified-DH frames of :mod:`~wrenchd.models.physics.kinematics`),
and the pitch parallelogram's (``parallel_back``, ``parallel_upper``, ``parallel_top``,
``parallel_bottom``), which the serial chain replaces by a virtual pitch joint at the RCM.
These follow the PSM model of WPI-AIM/dvrk_dynamics_identification (notebook
``main_psm.ipynb``, model ``psm``, the modified-DH rows of its links ``L_21`` ... ``L_25``);
their frames, and which point of a link moves how, are in docs/physics-and-discrepancy.md
("A point load on a link").
"""

from __future__ import annotations

import numpy as np

from wrenchd.models.errors import DataError
from wrenchd.models.series import JOINT_NAMES, N_JOINTS

#: WPI model lengths [m]: ``l_2L1``, ``l_2L2``, ``l_2L3``, ``l_2H1`` of the PSM model in
#: WPI-AIM/dvrk_dynamics_identification (``main_psm.ipynb``, model ``psm``).
L2L1, L2L2, L2L3, L2H1 = 0.096, 0.516, 0.04009, 0.14454
PARALLEL_LINKS = ("parallel_back", "parallel_upper", "parallel_top", "parallel_bottom")
LINKS = JOINT_NAMES + PARALLEL_LINKS
#: Step of the central differences that give dp/dq [rad; m].
_STEP = 1e-6


def _mdh(alpha: float, a: float, theta: np.ndarray, d: float = 0.0) -> np.ndarray:
    """Modified-DH transforms ``RotX(alpha) TransX(a) RotZ(theta) TransZ(d)``, (N, 4, 4)."""
    theta = np.asarray(theta, np.float64)
    ca, sa = np.cos(alpha), np.sin(alpha)
    ct, st = np.cos(theta), np.sin(theta)
    t = np.zeros(theta.shape + (4, 4))
    t[..., 0, 0], t[..., 0, 1], t[..., 0, 3] = ct, -st, a
    t[..., 1, 0], t[..., 1, 1], t[..., 1, 2], t[..., 1, 3] = st * ca, ct * ca, -sa, -sa * d
    t[..., 2, 0], t[..., 2, 1], t[..., 2, 2], t[..., 2, 3] = st * sa, ct * sa, ca, ca * d
    t[..., 3, 3] = 1.0
    return t


def _parallel_pose(q: np.ndarray, link: str) -> np.ndarray:
    """Poses (N, 4, 4) of a parallelogram link for joint positions (N, 6)."""
    q1, q2 = q[:, 0], q[:, 1]
    half = np.full_like(q1, np.pi / 2)
    pose = _mdh(np.pi / 2, 0.0, q1 + np.pi / 2) @ _mdh(-np.pi / 2, 0.0, q2 - np.pi / 2)
    pose = pose @ _mdh(0.0, L2L3, half)                                      # L_21
    if link == "parallel_back":
        return pose
    pose = pose @ _mdh(0.0, L2H1, np.pi / 2 - q2)                            # L_22
    if link == "parallel_upper":
        return pose
    if link == "parallel_top":
        return pose @ _mdh(0.0, L2L1, q2 + np.pi)                            # L_25
    return pose @ _mdh(0.0, L2L2, q2)                                        # L_24


def link_poses(q: np.ndarray, link: str) -> np.ndarray:
    """Poses (N, 4, 4) of ``link`` (one of :data:`LINKS`) in the base frame."""
    q = np.atleast_2d(np.asarray(q, np.float64))
    if q.shape[-1] != N_JOINTS:
        raise DataError(f"joint positions must have shape (N, 6), got {q.shape}")
    if link in PARALLEL_LINKS:
        return _parallel_pose(q, link)
    if link not in JOINT_NAMES:
        raise DataError(f"unknown link {link!r}; choose from {', '.join(LINKS)}")
    from wrenchd.models.physics.kinematics import PSMKinematics

    return PSMKinematics().forward(q, f"{link}_link").reshape(-1, 4, 4)


def point_positions(q: np.ndarray, link: str, point: np.ndarray) -> np.ndarray:
    """Base-frame positions (N, 3) of ``point`` (3,) [m], fixed in ``link``'s frame."""
    point = np.asarray(point, np.float64)
    if point.shape != (3,) or not np.isfinite(point).all():
        raise DataError(f"a point is three finite coordinates [m], got {point!r}")
    return (link_poses(q, link) @ np.append(point, 1.0))[:, :3]


def point_jacobian(q: np.ndarray, link: str, point: np.ndarray) -> np.ndarray:
    """dp/dq (N, 3, 6) of the point, by central differences."""
    q = np.atleast_2d(np.asarray(q, np.float64))
    jac = np.empty((len(q), 3, N_JOINTS))
    for j in range(N_JOINTS):
        step = np.zeros(N_JOINTS)
        step[j] = _STEP
        jac[:, :, j] = (point_positions(q + step, link, point)
                        - point_positions(q - step, link, point)) / (2 * _STEP)
    return jac


def point_load_torque(q: np.ndarray, link: str, point: np.ndarray, dt: float | None = None,
                      gravity: np.ndarray | None = None) -> np.ndarray:
    """Joint torques (N, 6) [N m; N] per kilogram at ``point`` on ``link``.

    Args:
        q: joint positions (N, 6) of a gap-free series.
        dt: its sample period [s]; with it the point's inertia is included (acceleration by
            a centred Savitzky-Golay derivative: offline), without it gravity alone.
        gravity: base-frame gravity [m/s^2]; default that of the rigid-body model.
    """
    from wrenchd.models.physics.dynamics import RigidBodyConfig

    g = np.asarray(RigidBodyConfig().gravity_mps2 if gravity is None else gravity, np.float64)
    q = np.atleast_2d(np.asarray(q, np.float64))
    force = np.broadcast_to(-g, (len(q), 3)).copy()
    if dt is not None:
        from scipy.signal import savgol_filter

        p = point_positions(q, link, point)
        window = min(31, len(q) - (1 - len(q) % 2))
        if window < 5:
            raise DataError("a point's acceleration needs at least 5 samples")
        force += savgol_filter(p, window, 3, deriv=2, delta=dt, axis=0)
    return np.einsum("nk,nkj->nj", force, point_jacobian(q, link, point))


def parse_link_point(spec: str) -> tuple[str, np.ndarray]:
    """``LINK:X,Y,Z`` -> (link, point [m]).

    Raises:
        DataError: an unknown link or not three finite numbers.
    """
    link, _, xyz = spec.rpartition(":")
    if link not in LINKS:
        raise DataError(f"{spec!r}: expected LINK:X,Y,Z with LINK one of {', '.join(LINKS)}")
    try:
        point = np.array([float(v) for v in xyz.split(",")])
    except ValueError:
        raise DataError(f"{spec!r}: X,Y,Z must be numbers [m]") from None
    if point.shape != (3,) or not np.isfinite(point).all():
        raise DataError(f"{spec!r}: expected three finite coordinates X,Y,Z [m]")
    return link, point


def fit_mass(per_kg: np.ndarray, external: np.ndarray) -> dict:
    """The point mass [kg] that best explains ``external`` (N, 6) torques by ``per_kg`` (N, 6)
    (:func:`point_load_torque`), least squares over the joints it acts on, its point held.

    Returns:
        ``mass_kg``, ``joints`` (1-based), ``rmse_before`` and ``rmse_after`` on them.
    """
    joints = np.flatnonzero(np.sqrt(np.mean(per_kg ** 2, axis=0)) > 1e-9)
    if joints.size == 0:
        raise DataError("a load at that point moves no joint's torque")
    a, b = per_kg[:, joints].ravel(), external[:, joints].ravel()
    mass = float(a @ b / (a @ a))
    after = external[:, joints] - mass * per_kg[:, joints]
    return {"mass_kg": mass, "joints": (joints + 1).tolist(),
            "rmse_before": np.sqrt(np.mean(external[:, joints] ** 2, axis=0)).tolist(),
            "rmse_after": np.sqrt(np.mean(after ** 2, axis=0)).tolist()}
