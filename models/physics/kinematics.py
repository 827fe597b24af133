"""PSM kinematics from the dVRK's modified Denavit-Hartenberg table, on pinocchio.

The chain is built as a pinocchio model (one revolute or prismatic joint per DH row), so
forward kinematics, Jacobians and rigid-body dynamics all come from one maintained library.

Modified DH (Craig): the transform from frame i-1 to frame i is
``RotX(alpha) . TransX(a) . RotZ(theta) . TransZ(d)``, where the joint variable plus the row's
offset replaces theta (revolute) or d (prismatic).

Source of the table and limits: dVRK configuration ``psm-large-needle-driver.json``
(jhu-dvrk/sawIntuitiveResearchKit, "DH" section, convention "modified"). The base frame has
its origin at the remote centre of motion (RCM): yaw and pitch axes pass through it and the
instrument shaft always does.

Frames and Jacobians (pinocchio's conventions; twists are ``[v; w]``, linear first):

* ``spatial``: the tip's twist in base axes, with ``v`` the velocity of the body point
  that coincides with the base origin (the RCM). Pinocchio ``WORLD``.
* ``body``: the tip's twist in tip axes, at the tip origin. Pinocchio ``LOCAL``.
* ``hybrid``: the velocity of the tip point and the angular velocity, both in base axes.
  Pinocchio ``LOCAL_WORLD_ALIGNED``. wrenchd's tip wrenches use this frame: force [N] in base
  axes, torque [N m] about the tip point in base axes, so ``tau = J_hybrid^T w``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from wrenchd.models.errors import DataError
from wrenchd.models.series import JOINT_NAMES, N_JOINTS

HALF_PI = np.pi / 2


@dataclass(frozen=True)
class DHRow:
    """One modified-DH row. Lengths in m, angles in rad."""

    alpha: float
    a: float
    theta: float
    d: float
    offset: float
    prismatic: bool = False


#: dVRK PSM, large needle driver (see module docstring for the source).
PSM_DH: tuple[DHRow, ...] = (
    DHRow(HALF_PI, 0.0, 0.0, 0.0, HALF_PI),                  # 1 outer yaw
    DHRow(-HALF_PI, 0.0, 0.0, 0.0, -HALF_PI),                # 2 outer pitch
    DHRow(HALF_PI, 0.0, 0.0, 0.0, -0.4318, prismatic=True),  # 3 insertion
    DHRow(0.0, 0.0, 0.0, 0.4162, 0.0),                       # 4 tool roll
    DHRow(-HALF_PI, 0.0, 0.0, 0.0, -HALF_PI),                # 5 wrist pitch
    DHRow(-HALF_PI, 0.0091, 0.0, 0.0, -HALF_PI),             # 6 wrist yaw
)

#: Joint limits [rad, rad, m, rad, rad, rad] (same source).
PSM_LOWER = np.array([-1.588, -0.925, 0.0, -4.538, -1.396, -1.396])
PSM_UPPER = np.array([1.588, 0.925, 0.24, 4.538, 1.396, 1.396])

#: Distance from the wrist-yaw frame to the tool tip along its x axis [m]: the large
#: needle driver's jaw length (dVRK ``tooltip-offset`` and Intuitive's 9.1 mm + 10.2 mm
#: wrist geometry). An assumption documented here; the tip frame keeps wrist-yaw axes.
TIP_OFFSET_M = 0.0102

#: The frame whose z axis is the instrument shaft, pointing from the RCM towards the tip.
SHAFT_FRAME = "outer_insertion"


def _dh_placement(row: DHRow) -> pin.SE3:
    """Constant part of the row's transform, up to and including the joint offset."""
    rot_x = pin.SE3(pin.utils.rotate("x", row.alpha), np.zeros(3))
    trans_x = pin.SE3(np.eye(3), np.array([row.a, 0.0, 0.0]))
    theta = row.theta if row.prismatic else row.theta + row.offset
    d = row.d + row.offset if row.prismatic else row.d
    rot_z = pin.SE3(pin.utils.rotate("z", theta), np.zeros(3))
    trans_z = pin.SE3(np.eye(3), np.array([0.0, 0.0, d]))
    return rot_x * trans_x * rot_z * trans_z


def build_chain(dh: tuple[DHRow, ...] = PSM_DH) -> pin.Model:
    """A pinocchio model of the serial chain with massless bodies and a ``tip`` frame.

    Inertias are attached by :mod:`wrenchd.models.physics.dynamics`.
    """
    model = pin.Model()
    model.name = "dvrk_psm"
    parent = 0
    for name, row, lo, hi in zip(JOINT_NAMES, dh, PSM_LOWER, PSM_UPPER):
        joint = pin.JointModelPZ() if row.prismatic else pin.JointModelRZ()
        parent = model.addJoint(parent, joint, _dh_placement(row), name)
        model.lowerPositionLimit[parent - 1] = lo
        model.upperPositionLimit[parent - 1] = hi
        model.addJointFrame(parent, -1)
        model.addBodyFrame(f"{name}_link", parent, pin.SE3.Identity(), -1)
    tip = pin.SE3(np.eye(3), np.array([TIP_OFFSET_M, 0.0, 0.0]))
    model.addFrame(pin.Frame("tip", parent, tip, pin.FrameType.OP_FRAME))
    return model


_REFERENCE = {"spatial": pin.WORLD, "body": pin.LOCAL, "hybrid": pin.LOCAL_WORLD_ALIGNED}


def check_positions(q: np.ndarray) -> np.ndarray:
    """Validate joint positions: shape (6,) or (N, 6), finite. Returns a float64 array."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape[-1] != N_JOINTS or q.ndim not in (1, 2):
        raise DataError(f"joint positions must have shape (6,) or (N, 6), got {q.shape}")
    if not np.all(np.isfinite(q)):
        raise DataError("joint positions contain NaN or Inf")
    return q


class PSMKinematics:
    """Forward kinematics and Jacobians of the PSM.

    Methods accept one configuration ``(6,)`` or a batch ``(N, 6)`` and return the matching
    leading shape.
    """

    def __init__(self, model: pin.Model | None = None) -> None:
        self.model = model if model is not None else build_chain()
        self.data = self.model.createData()
        self.tip_id = self.model.getFrameId("tip")
        self.shaft_id = self.model.getFrameId(SHAFT_FRAME)

    def _frame_pose(self, q: np.ndarray, frame_id: int) -> np.ndarray:
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[frame_id].homogeneous

    def forward(self, q: np.ndarray, frame: str = "tip") -> np.ndarray:
        """Pose of ``frame`` in the base frame: (4, 4) or (N, 4, 4) homogeneous, metres."""
        q = check_positions(q)
        fid = self.model.getFrameId(frame)
        if q.ndim == 1:
            return self._frame_pose(q, fid).copy()
        return np.stack([self._frame_pose(qi, fid) for qi in q])

    def jacobian(self, q: np.ndarray, frame: str = "hybrid", point: str = "tip") -> np.ndarray:
        """Geometric Jacobian (6, 6) or (N, 6, 6); rows ``[v; w]``, see module docstring.

        Args:
            q: joint positions.
            frame: ``"spatial"``, ``"body"`` or ``"hybrid"``.
            point: the frame whose motion is described (default the tool tip).
        """
        q = check_positions(q)
        try:
            ref = _REFERENCE[frame]
        except KeyError:
            raise DataError(f"frame must be one of {sorted(_REFERENCE)}, got {frame!r}") from None
        fid = self.model.getFrameId(point)

        def one(qi: np.ndarray) -> np.ndarray:
            return pin.computeFrameJacobian(self.model, self.data, qi, fid, ref)

        if q.ndim == 1:
            return one(q).copy()
        return np.stack([one(qi) for qi in q])

    def shaft_axis(self, q: np.ndarray) -> np.ndarray:
        """Unit vector of the instrument shaft (RCM towards tip) in base axes, (3,) or (N, 3).

        Only the yaw and pitch joints move the shaft (see :func:`shaft_axis_and_derivatives`).
        """
        q = check_positions(q)
        return shaft_axis_and_derivatives(np.atleast_2d(q))[0].reshape(q.shape[:-1] + (3,))


def shaft_axis_and_derivatives(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shaft axis ``u`` and its partial derivatives in yaw and pitch, each (N, 3), for q (N, 6).

    Closed form of the DH chain's insertion z axis,
    ``Rx(pi/2) Rz(q1+pi/2) Rx(-pi/2) Rz(q2-pi/2) Rx(pi/2)``; checked against pinocchio in the tests.
    """
    s1, c1 = np.sin(q[:, 0]), np.cos(q[:, 0])
    s2, c2 = np.sin(q[:, 1]), np.cos(q[:, 1])
    u = np.stack([s1 * c2, -s2, -c1 * c2], axis=1)
    du1 = np.stack([c1 * c2, np.zeros_like(c1), s1 * c2], axis=1)
    du2 = np.stack([-s1 * s2, -c2, c1 * s2], axis=1)
    return u, du1, du2
