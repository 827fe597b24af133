"""The body wall at the trocar port: a lateral spring-damper on the shaft.

The instrument shaft always passes through the remote centre of motion (RCM, the base
origin). When the incision is not exactly at the RCM (the port was placed a little off, or
the RCM was set deeper or shallower than the abdominal wall), the shaft pushes the tissue
sideways as it pivots and the wall pushes back. With ``u`` the shaft axis, ``p`` the incision
(base axes, from the RCM) and ``s = u . p`` the depth along the shaft where the shaft meets the
wall, the shaft's lateral displacement from the tissue's rest point is ``e = s u - p`` and the
wall's force on the shaft is ``F = -k e - c s du/dt``. Insufflation stiffens the wall: the
stretched abdominal wall is tenser at higher pressure, ``k = k0 + k_p * pressure``.

The drive supplies ``tau_j = -F . d(x)/dq_j`` for the material point ``x = s u(q)``: only yaw and
pitch, since the force is perpendicular to the shaft (no work along insertion or roll).

Magnitudes are assumptions in the range reported for abdominal-wall port forces (a few N at
the port for clinical pivoting; insufflation 8 to 16 mmHg): ``k0`` 100 N/m, ``k_p``
40 N/m per mmHg, incision 3 cm above the RCM along the shaft and 3 mm to the side.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, register
from wrenchd.models.physics.kinematics import shaft_axis_and_derivatives


class BodyWallParams(EffectParams):
    incision_m: tuple[float, float, float] = Field(
        default=(0.003, -0.002, 0.03),
        description="incision point relative to the RCM, base axes [m]",
    )
    k0_n_per_m: float = Field(default=100.0, ge=0.0, description="stiffness at 0 mmHg [N/m]")
    k_per_mmhg: float = Field(default=40.0, ge=0.0, description="stiffening [N/m per mmHg]")
    pressure_mmhg: float = Field(default=12.0, ge=0.0, le=30.0,
                                 description="insufflation pressure [mmHg]")
    damping_ns_per_m: float = Field(default=5.0, ge=0.0, description="lateral damping [N s/m]")


def body_wall_force(motion: Motion, incision: np.ndarray, k: np.ndarray, c: np.ndarray):
    """Wall force on the shaft (N, 3) [N], the contact depth (N,) [m] and du/dq1, du/dq2."""
    u, du1, du2 = shaft_axis_and_derivatives(motion.q)
    depth = u @ incision                                       # (N,) [m]
    lateral = depth[:, None] * u - incision                    # (N, 3) [m]
    u_dot = du1 * motion.dq[:, :1] + du2 * motion.dq[:, 1:2]   # (N, 3) [1/s]
    force = -np.reshape(k, (-1, 1)) * lateral - np.reshape(c, (-1, 1)) * depth[:, None] * u_dot
    return force, depth, du1, du2


@register
class BodyWall(Effect):
    """Lateral elastic force of the abdominal wall on the shaft, stiffer with insufflation."""

    name = "body_wall"
    Params = BodyWallParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        k = self.param("k0_n_per_m", overrides) \
            + self.param("k_per_mmhg", overrides) * self.param("pressure_mmhg", overrides)
        force, depth, du1, du2 = body_wall_force(
            motion, self.param("incision_m", overrides), k,
            self.param("damping_ns_per_m", overrides))
        out = np.zeros_like(motion.q)
        out[:, 0] = -depth * np.einsum("ni,ni->n", force, du1)
        out[:, 1] = -depth * np.einsum("ni,ni->n", force, du2)
        return out
