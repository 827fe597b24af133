"""External contact: a tip wrench mapped to joint torques through ``J^T``.

Modelled on the two-step paper's contact experiments, where the instrument grasps a handle
mounted on a 6-axis force/torque sensor: during each contact episode the tip is tied to a
compliant handle anchored where the grasp began, so the wrench grows as the arm moves away
from the grasp point, saturating smoothly at ``max_force_n`` (a soft phantom). The wrench is the one the tip applies to the handle (what the sensor
reads), in wrenchd's hybrid frame (force in base axes, torque about the tip in base axes), and
the drive supplies ``tau = J_hybrid^T w``. At the end of an episode the grasp releases over
``release_s`` so the force does not jump.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from pydantic import Field, field_validator

from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, register


class ContactParams(EffectParams):
    episodes: tuple[tuple[float, float], ...] = Field(
        default=(), description="contact intervals [t_start, t_end] in session time [s]"
    )
    stiffness_n_per_m: float = Field(default=150.0, gt=0.0, description="handle stiffness [N/m]")
    torsional_nm_per_rad: float = Field(default=0.05, ge=0.0,
                                        description="handle torsional stiffness [N m/rad]")
    release_s: float = Field(default=0.2, gt=0.0, description="release ramp [s]")
    max_force_n: float = Field(default=8.0, gt=0.0,
                               description="the handle's force saturates smoothly here [N]")

    @field_validator("episodes")
    @classmethod
    def _ordered(cls, v):
        for start, end in v:
            if not end > start:
                raise ValueError(f"episode end must follow its start, got [{start}, {end}]")
        return v


def contact_windows(t: np.ndarray, episodes, release_s: float) -> np.ndarray:
    """Per-sample grasp weight in [0, 1] (N,) and the episode index (-1 outside)."""
    weight = np.zeros(t.shape)
    index = np.full(t.shape, -1)
    for k, (start, end) in enumerate(episodes):
        inside = (t >= start) & (t < end + release_s)
        weight[inside] = np.clip((end + release_s - t[inside]) / release_s, 0.0, 1.0)
        index[inside] = k
    return weight, index


@register
class ExternalContact(Effect):
    """Tip wrench of a grasped compliant handle, mapped through ``J^T``."""

    name = "external_contact"
    Params = ContactParams

    def wrench(self, motion: Motion) -> tuple[np.ndarray, np.ndarray]:
        """Tip wrench (N, 6) [N, N m] and the in-contact flag (N,)."""
        p = self.params
        weight, index = contact_windows(motion.t, p.episodes, p.release_s)
        wrench = np.zeros((len(motion), 6))
        kin = motion.robot.kinematics
        for k in np.unique(index[index >= 0]):
            rows = np.flatnonzero(index == k)
            poses = kin.forward(motion.q[rows])                      # (n, 4, 4)
            anchor = poses[0]
            spring = p.stiffness_n_per_m * (poses[:, :3, 3] - anchor[:3, 3])   # (n, 3) [N]
            size = np.linalg.norm(spring, axis=1, keepdims=True)
            # a soft phantom / hand on the handle: the force saturates at max_force_n
            gain = np.where(size > 0, p.max_force_n * np.tanh(size / p.max_force_n)
                            / np.maximum(size, 1e-12), 1.0)
            wrench[rows, :3] = spring * gain
            for j, pose in zip(rows, poses):
                # rotation of the tip since the grasp, as a base-axes rotation vector
                rotvec = pin.log3(pose[:3, :3] @ anchor[:3, :3].T)
                wrench[j, 3:] = p.torsional_nm_per_rad * rotvec
        wrench *= weight[:, None]
        return wrench, weight > 0

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        return self.torque_from_wrench(motion, *self.wrench(motion))

    @staticmethod
    def torque_from_wrench(motion: Motion, wrench: np.ndarray, contact: np.ndarray) -> np.ndarray:
        """``J_hybrid^T w`` (N, 6) on the contact rows, zero elsewhere."""
        out = np.zeros_like(motion.q)
        rows = np.flatnonzero(contact)
        if rows.size:
            jac = motion.robot.kinematics.jacobian(motion.q[rows], frame="hybrid")  # (n, 6, 6)
            out[rows] = np.einsum("nji,nj->ni", jac, wrench[rows])
        return out
