"""A point mass attached to a link (a load on the parallelogram, a heavier instrument).

Its torque is exactly the rigid-body torque of the added inertia: with pinocchio's regressor
``Y_link`` (N, 6, 10) of the carrying link and the point mass's standard parameters
``[m, m c, m (|c|^2 I - c c^T)]``, ``tau = Y_link @ theta_payload``. Linear in the mass for a
fixed position, which the discrepancy workflow uses.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from pydantic import Field

from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, register


class PayloadParams(EffectParams):
    mass_kg: float = Field(default=0.1, ge=0.0, le=5.0, description="added mass [kg]")
    link: int = Field(default=2, ge=1, le=6, description="carrying link, 1 = yaw ... 6 = wrist yaw")
    position_m: tuple[float, float, float] = Field(
        default=(0.0, 0.065, 0.165),
        description="mass position in the link's DH frame [m]",
    )


def point_mass_parameters(mass_kg: float, position_m) -> np.ndarray:
    """Standard inertial parameters (10,) of a point mass, pinocchio's order."""
    return pin.Inertia(mass_kg, np.asarray(position_m, dtype=np.float64),
                       np.zeros((3, 3))).toDynamicParameters()


@register
class PayloadMass(Effect):
    """Gravity and inertia of a point mass on a link."""

    name = "payload_mass"
    Params = PayloadParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        y = motion.robot.regressor(motion.q, motion.dq, motion.ddq)        # (N, 6, 60)
        cols = slice(10 * (self.params.link - 1), 10 * self.params.link)
        mass = self.param("mass_kg", overrides)
        theta = point_mass_parameters(1.0, self.params.position_m)         # per kg
        per_kg = y[:, :, cols] @ theta                                     # (N, 6)
        return per_kg * (mass[:, None] if mass.ndim == 1 else mass)
