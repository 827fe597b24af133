"""Free-space joint friction: Coulomb, viscous and Stribeck.

Published free-space magnitudes (Wang et al., RA-L 2019, the WPI identification in
``../shared/data/wpi-psm/identified_params.json``):
yaw Fc 0.05 N m, Fv 0.09 N m s; pitch Fc 0.067 N m, Fv 0.22 N m s; insertion Fc 0.45 N,
Fv 1.2 N s/m. Roll and wrist values are the same file's small wrist entries (order 0.002 to
0.007 N m and N m s), rounded.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, field_validator

from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, per_joint, register

DEFAULT_FC = (0.05, 0.067, 0.45, 0.003, 0.005, 0.005)
DEFAULT_FV = (0.09, 0.22, 1.2, 0.002, 0.006, 0.006)

#: Velocity scale [rad/s or m/s] of the smooth sign used for Coulomb friction: a hard
#: sign makes torque discontinuous at reversals, which no real drive shows.
SIGN_SMOOTHING = 1e-3


def smooth_sign(v: np.ndarray, scale: float = SIGN_SMOOTHING) -> np.ndarray:
    """``tanh(v / scale)``: sign of ``v`` with a smooth zero crossing."""
    return np.tanh(np.asarray(v) / scale)


class CoulombParams(EffectParams):
    fc: tuple[float, ...] = Field(default=DEFAULT_FC,
                                  description="Coulomb level per joint [N m; N on insertion]")
    _six = field_validator("fc", mode="before")(lambda cls, v: per_joint(v))


@register
class CoulombFriction(Effect):
    """Coulomb friction: the drive supplies ``tau = fc * sign(dq)`` to overcome it.

    Every effect returns the torque the *drive* supplies because of it (what the measured
    effort contains), so dissipative effects have the sign of the velocity.
    """

    name = "coulomb_friction"
    Params = CoulombParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        return self.param("fc", overrides) * smooth_sign(motion.dq)


class ViscousParams(EffectParams):
    fv: tuple[float, ...] = Field(default=DEFAULT_FV,
                                  description="viscous coefficient [N m s/rad; N s/m]")
    _six = field_validator("fv", mode="before")(lambda cls, v: per_joint(v))


@register
class ViscousFriction(Effect):
    """``tau = fv * dq``."""

    name = "viscous_friction"
    Params = ViscousParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        return self.param("fv", overrides) * motion.dq


class StribeckParams(EffectParams):
    fs: tuple[float, ...] = Field(default=(0.02, 0.03, 0.2, 0.0, 0.0, 0.0),
                                  description="static excess over Coulomb [N m; N]")
    vs: tuple[float, ...] = Field(default=(0.05, 0.05, 0.01, 0.1, 0.1, 0.1),
                                  description="Stribeck velocity [rad/s; m/s]")
    _six = field_validator("fs", "vs", mode="before")(lambda cls, v: per_joint(v))

    @field_validator("vs")
    @classmethod
    def _positive(cls, v):
        if min(v) <= 0:
            raise ValueError(f"vs must be > 0, got {v}")
        return v


@register
class StribeckFriction(Effect):
    """Stribeck excess ``tau = fs * exp(-(dq/vs)^2) * sign(dq)``: friction higher near rest.

    Add it to ``coulomb_friction`` for the classic Stribeck curve.
    """

    name = "stribeck_friction"
    Params = StribeckParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        fs, vs = self.param("fs", overrides), self.param("vs", overrides)
        return fs * np.exp(-np.square(motion.dq / vs)) * smooth_sign(motion.dq)
