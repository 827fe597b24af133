"""Rigid-body dynamics of the PSM's serial-chain approximation, on pinocchio.

The real PSM's pitch axis is driven through a parallelogram with a counterweight; wrenchd
models it as the serial chain of :mod:`wrenchd.models.physics.kinematics` with lumped inertias. The
default inertias below are **assumptions**, chosen so that simulated torques on the WPI
excitation trajectories have the magnitudes measured on a real PSM
(``../shared/data/wpi-psm/one_no_weight.csv``: yaw and pitch about 1 N m RMS, insertion about
1 N RMS, small mean pitch torque because the counterweight balances the arm). The WPI
identification (``identified_params.json``) models the closed chain with nine links, several on
their optimisation bounds, so it does not map one-to-one onto this chain; it informed the
masses (instrument and carriage 0.3 to 0.5 kg) and the friction defaults, not the layout.

Gravity defaults to ``-z`` of the base frame (shaft pointing down at the zero
configuration); the real mounting tilts it, so it is a model parameter.

All torques are ``(N, 6)`` [N m, N m, N, N m, N m, N m].
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from pydantic import BaseModel, ConfigDict, Field, field_validator

from wrenchd.models.errors import DataError
from wrenchd.models.physics.kinematics import PSMKinematics, build_chain, check_positions
from wrenchd.models.series import N_JOINTS


class LinkInertia(BaseModel):
    """Inertial parameters of one link, in its own DH frame."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    mass_kg: float = Field(ge=0.0, description="link mass [kg]")
    com_m: tuple[float, float, float] = Field(description="centre of mass in the link frame [m]")
    inertia_kgm2: tuple[float, float, float, float, float, float] = Field(
        description="rotational inertia about the COM: Ixx, Ixy, Iyy, Ixz, Iyz, Izz [kg m^2]"
    )


def _default_links() -> list[LinkInertia]:
    # Assumed lumped inertias (see module docstring). Link frames are the DH frames.
    return [
        # 1 yaw assembly: the yaw motor stage and the part of the arm that only yaws.
        LinkInertia(mass_kg=1.2, com_m=(0.0, 0.0, 0.05),
                    inertia_kgm2=(0.02, 0.0, 0.02, 0.0, 0.0, 0.06)),
        # 2 parallelogram with counterweight: its COM sits opposite the instrument.
        LinkInertia(mass_kg=2.0, com_m=(0.0, 0.0, 0.03),
                    inertia_kgm2=(0.04, 0.0, 0.04, 0.0, 0.0, 0.08)),
        # 3 insertion carriage + instrument body, net of the counterbalance: a least-squares
        # fit on one_no_weight.csv finds only ~0.25 N of gravity along the shaft; most of the
        # insertion inertia (~0.7 kg fitted) is reflected motor inertia (armature below).
        LinkInertia(mass_kg=0.05, com_m=(0.0, 0.0, 0.12),
                    inertia_kgm2=(0.004, 0.0, 0.004, 0.0, 0.0, 2e-4)),
        # 4 instrument shaft (rolls), COM at mid shaft.
        LinkInertia(mass_kg=0.03, com_m=(0.0, 0.0, -0.2),
                    inertia_kgm2=(1e-3, 0.0, 1e-3, 0.0, 0.0, 2e-6)),
        # 5, 6 wrist links: grams.
        LinkInertia(mass_kg=0.01, com_m=(0.0, 0.0, 0.0),
                    inertia_kgm2=(1e-7, 0.0, 1e-7, 0.0, 0.0, 1e-7)),
        LinkInertia(mass_kg=0.01, com_m=(0.005, 0.0, 0.0),
                    inertia_kgm2=(1e-7, 0.0, 1e-7, 0.0, 0.0, 1e-7)),
    ]


class RigidBodyConfig(BaseModel):
    """Rigid-body part of a physics model file."""

    model_config = ConfigDict(extra="forbid")

    links: list[LinkInertia] = Field(default_factory=_default_links,
                                     description="six links, yaw to wrist yaw")
    armature: tuple[float, ...] = Field(
        default=(0.08, 0.08, 0.6, 1e-5, 1e-5, 1e-5),
        description="reflected motor inertia per joint [kg m^2, or kg for insertion]",
    )
    gravity_mps2: tuple[float, float, float] = Field(
        default=(0.0, 0.0, -9.81), description="gravity in base axes [m/s^2]"
    )

    @field_validator("links")
    @classmethod
    def _six_links(cls, v: list[LinkInertia]) -> list[LinkInertia]:
        if len(v) != N_JOINTS:
            raise ValueError(f"links must list {N_JOINTS} links, got {len(v)}")
        return v

    @field_validator("armature")
    @classmethod
    def _six_armatures(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if len(v) != N_JOINTS or min(v) < 0:
            raise ValueError(f"armature must be {N_JOINTS} non-negative values, got {v}")
        return v


def _pin_inertia(link: LinkInertia) -> pin.Inertia:
    ixx, ixy, iyy, ixz, iyz, izz = link.inertia_kgm2
    rot = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    return pin.Inertia(link.mass_kg, np.array(link.com_m), rot)


def _batch(a: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != N_JOINTS:
        raise DataError(f"{name} must have shape (N, 6), got {a.shape}")
    return a


class RigidBodyModel:
    """Inverse dynamics and the joint-torque regressor of the PSM chain.

    ``tau = M(q) ddq + C(q, dq) dq + g(q)`` (plus armature on the diagonal of ``M``), and the
    same torques as ``Y(q, dq, ddq) @ theta`` with ``theta`` the 10 standard inertial
    parameters per link (pinocchio order: m, m c_x, m c_y, m c_z, Ixx, Ixy, Iyy, Ixz, Iyz, Izz
    about the link origin). Armature is not in ``theta``; :meth:`armature_torque` gives it.
    """

    def __init__(self, config: RigidBodyConfig | None = None) -> None:
        self.config = config if config is not None else RigidBodyConfig()
        self.model = build_chain()
        for jid, link in enumerate(self.config.links, start=1):
            self.model.appendBodyToJoint(jid, _pin_inertia(link), pin.SE3.Identity())
        self.model.armature = np.array(self.config.armature, dtype=np.float64)
        self.model.gravity.linear = np.array(self.config.gravity_mps2, dtype=np.float64)
        self.data = self.model.createData()
        self.kinematics = PSMKinematics(self.model)

    @property
    def parameters(self) -> np.ndarray:
        """Standard inertial parameters ``theta``, shape (60,)."""
        return np.concatenate([
            self.model.inertias[j].toDynamicParameters() for j in range(1, N_JOINTS + 1)
        ])

    def inverse_dynamics(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Joint torques (N, 6) for the motion, by pinocchio's RNEA (armature included)."""
        q, dq, ddq = check_positions(_batch(q, "q")), _batch(dq, "dq"), _batch(ddq, "ddq")
        out = np.empty_like(q)
        model, data = self.model, self.data
        for i in range(q.shape[0]):
            out[i] = pin.rnea(model, data, q[i], dq[i], ddq[i])
        return out

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """Gravity torques (N, 6) at rest."""
        q = check_positions(_batch(q, "q"))
        out = np.empty_like(q)
        for i in range(q.shape[0]):
            out[i] = pin.computeGeneralizedGravity(self.model, self.data, q[i])
        return out

    def regressor(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Joint-torque regressor (N, 6, 60): ``tau_rigid = Y @ parameters`` (no armature)."""
        q, dq, ddq = check_positions(_batch(q, "q")), _batch(dq, "dq"), _batch(ddq, "ddq")
        out = np.empty((q.shape[0], N_JOINTS, 10 * N_JOINTS))
        for i in range(q.shape[0]):
            out[i] = pin.computeJointTorqueRegressor(self.model, self.data, q[i], dq[i], ddq[i])
        return out

    def rigid_torque(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                     parameters: np.ndarray) -> np.ndarray:
        """``regressor(q, dq, ddq) @ parameters`` (B, 6) of rows already checked (float64,
        (B, 6), finite), without checking them again: a streamed sample's rigid body with
        identified parameters (which need not be a physical body's, so not by RNEA)."""
        model, data = self.model, self.data
        out = np.empty((q.shape[0], N_JOINTS))
        for i in range(q.shape[0]):
            out[i] = pin.computeJointTorqueRegressor(model, data, q[i], dq[i], ddq[i]) @ parameters
        return out

    def armature_torque(self, ddq: np.ndarray) -> np.ndarray:
        """Torque (N, 6) of the reflected motor inertia: ``armature * ddq``."""
        return _batch(ddq, "ddq") * self.model.armature
