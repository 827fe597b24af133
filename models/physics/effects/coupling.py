"""Cable coupling of the wrist: motor-side friction seen through the coupling matrix.

The instrument's wrist pitch and wrist yaw are cable driven; the yaw cables run over the
pitch pulleys, so moving the pitch joint also turns the yaw motor. With ``m = C dq_wrist`` the
motor velocities and ``f_m`` the friction of each motor, the drive supplies
``tau_wrist = C^T f_m(C dq_wrist)`` at the wrist joints. The default ``C`` follows the shape of
the dVRK large needle driver's actuator-to-joint coupling (a lower-triangular pitch-to-yaw term
of order one, ``psm-large-needle-driver.json``); its numbers here are assumptions.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, field_validator

from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, register
from wrenchd.models.physics.effects.friction import smooth_sign

WRIST = slice(4, 6)


class CableCouplingParams(EffectParams):
    coupling: tuple[tuple[float, float], tuple[float, float]] = Field(
        default=((1.0, 0.0), (0.8, 1.0)),
        description="C: wrist joint velocities (pitch, yaw) to motor velocities",
    )
    motor_fc: tuple[float, float] = Field(default=(0.004, 0.004),
                                          description="motor Coulomb friction [N m]")
    motor_fv: tuple[float, float] = Field(default=(0.003, 0.003),
                                          description="motor viscous friction [N m s/rad]")

    @field_validator("motor_fc", "motor_fv")
    @classmethod
    def _non_negative(cls, v):
        if min(v) < 0:
            raise ValueError(f"friction must be >= 0, got {v}")
        return v


@register
class CableCoupling(Effect):
    """Wrist friction that couples pitch into yaw through the cables (joints 5, 6)."""

    name = "cable_coupling"
    Params = CableCouplingParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        c = self.param("coupling", overrides)                    # (2, 2) or (N, 2, 2)
        dq = motion.dq[:, WRIST]                                 # (N, 2)
        m_vel = np.einsum("...ij,nj->ni", c, dq)                 # motor velocities
        f_m = self.param("motor_fc", overrides) * smooth_sign(m_vel) \
            + self.param("motor_fv", overrides) * m_vel          # (N, 2) [N m]
        out = np.zeros_like(motion.dq)
        out[:, WRIST] = np.einsum("...ji,nj->ni", c, f_m)        # C^T f_m
        return out
