"""Position-dependent effects: a constant torque offset and a joint spring.

Magnitudes: the WPI identification (``identified_params.json``, entries ``Fo`` and ``K``)
finds offsets of 0.005 to 0.3 N m and a wrist spring of ~0.002 N m/rad; the instrument's
cable preload acts on the wrist like a weak spring.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field, field_validator

from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, per_joint, register


class OffsetParams(EffectParams):
    offset: tuple[float, ...] = Field(default=(0.0,) * 6,
                                      description="constant torque per joint [N m; N]")
    _six = field_validator("offset", mode="before")(lambda cls, v: per_joint(v))


@register
class JointOffset(Effect):
    """A constant torque per joint (amplifier offset, unmodelled preload): ``tau = offset``."""

    name = "joint_offset"
    Params = OffsetParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        return np.broadcast_to(self.param("offset", overrides), motion.q.shape).copy()


class SpringParams(EffectParams):
    stiffness: tuple[float, ...] = Field(default=(0.0,) * 6,
                                         description="per joint [N m/rad; N/m]")
    rest: tuple[float, ...] = Field(default=(0.0,) * 6,
                                    description="rest position per joint [rad; m]")
    _six = field_validator("stiffness", "rest", mode="before")(lambda cls, v: per_joint(v))


@register
class JointSpring(Effect):
    """A linear spring on each joint: ``tau = stiffness * (q - rest)``."""

    name = "spring"
    Params = SpringParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        k, rest = self.param("stiffness", overrides), self.param("rest", overrides)
        return k * (motion.q - rest)
