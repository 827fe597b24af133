"""A change of the rigid body's inertial parameters, exact through the joint-torque regressor.

Least squares on free-motion data identifies only the *base* parameters of the chain: linear
combinations of the 60 standard inertial parameters (10 per link) and the six armatures that
the torques can see. They need not correspond to any physically consistent set of link
masses, centres and inertias (a link may get a negative "mass" when its mass is only seen
together with its neighbour's), so they cannot in general be written into the model file's
``rigid_body`` section (which requires masses >= 0 and centres ``m c / m``). This effect holds
them instead, as a change from the nominal rigid body:

``tau = Y(q, dq, ddq)[:, :, cols] @ delta_standard + delta_armature * ddq``

with ``columns`` naming standard parameters (``"link2.mz"``: link 2, pinocchio order
``m, mx, my, mz, ixx, ixy, iyy, ixz, iyz, izz`` with ``mx = m c_x`` and inertias about the
link origin) or armatures (``"joint3.armature"``). A column that is a base parameter
stands for its whole linear combination, so setting only the base columns reproduces the
identified torques exactly. ``identified_rms`` records how far the identification itself
was from its data (held-out RMS per joint); the discrepancy workflow reads it as the model's
own error floor.
"""

from __future__ import annotations

import re

import numpy as np
from pydantic import Field, field_validator, model_validator

from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, per_joint, register

#: pinocchio's order of a link's 10 standard inertial parameters.
STANDARD_NAMES = ("m", "mx", "my", "mz", "ixx", "ixy", "iyy", "ixz", "iyz", "izz")
_COLUMN = re.compile(r"^(link([1-6])\.(" + "|".join(STANDARD_NAMES) + r")|joint([1-6])\.armature)$")


def column_name(index: int) -> str:
    """Name of column ``index`` of ``[Y (60) | armature (6)]``."""
    if index < 60:
        return f"link{index // 10 + 1}.{STANDARD_NAMES[index % 10]}"
    return f"joint{index - 59}.armature"


def column_index(name: str) -> int:
    """Inverse of :func:`column_name`; raises ValueError for an unknown name."""
    m = _COLUMN.match(name)
    if m is None:
        raise ValueError(f"unknown inertial column {name!r}; expected 'linkL.<{'|'.join(STANDARD_NAMES)}>' "
                         f"or 'jointJ.armature', L and J in 1..6")
    if m.group(2):
        return 10 * (int(m.group(2)) - 1) + STANDARD_NAMES.index(m.group(3))
    return 59 + int(m.group(4))


def inertial_columns(motion: Motion, regressor: np.ndarray | None = None) -> np.ndarray:
    """``[Y | diag(ddq)]`` of the motion, shape (N, 6, 66) [N m or N per parameter unit]."""
    y = regressor if regressor is not None else motion.robot.regressor(motion.q, motion.dq, motion.ddq)
    arm = np.zeros((len(motion), 6, 6))
    idx = np.arange(6)
    arm[:, idx, idx] = motion.ddq
    return np.concatenate([y, arm], axis=2)


class InertialParams(EffectParams):
    columns: tuple[str, ...] = Field(default=(), description="parameter names, e.g. 'link2.mz'")
    delta: tuple[float, ...] = Field(default=(), description="change of each named parameter "
                                     "[kg, kg m, kg m^2; armature kg m^2 or kg]")
    identified_rms: tuple[float, ...] = Field(
        default=(0.0,) * 6, description="held-out RMS residual of the identification per joint "
        "[N m; N] (0: unknown)")
    _six = field_validator("identified_rms", mode="before")(lambda cls, v: per_joint(v))

    @field_validator("columns")
    @classmethod
    def _known(cls, v):
        for name in v:
            column_index(name)
        if len(set(v)) != len(v):
            raise ValueError(f"columns must be unique, got {v}")
        return v

    @model_validator(mode="after")
    def _same_length(self):
        if len(self.columns) != len(self.delta):
            raise ValueError(f"columns ({len(self.columns)}) and delta ({len(self.delta)}) "
                             "must have the same length")
        return self


@register
class InertialDelta(Effect):
    """Identified change of inertial (base) parameters and armatures, through the regressor."""

    name = "inertial_delta"
    Params = InertialParams

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        if not self.params.columns:
            return np.zeros_like(motion.q)
        idx = np.array([column_index(c) for c in self.params.columns])
        cols = inertial_columns(motion)[:, :, idx]                     # (N, 6, k)
        delta = self.param("delta", overrides)                         # (k,) or (N, k)
        return cols @ delta if delta.ndim == 1 else np.einsum("njk,nk->nj", cols, delta)
