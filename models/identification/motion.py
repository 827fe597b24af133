"""How much of a joint's range and speed a free-motion recording covered.

A model identified from a recording knows the arm only where the recording took it: a joint
that barely moved leaves its friction and gravity terms unidentified, and the learned residual
has no data there. :func:`motion_coverage` measures it per joint against the PSM's limits
(:data:`~wrenchd.models.physics.kinematics.PSM_LOWER` / ``PSM_UPPER`` and the excitation's
velocity caps), and :func:`check_motion` refuses a recording too still to identify from.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from wrenchd.models.errors import DataError
from wrenchd.models.identification.excitation import DEFAULT_MAX_VELOCITY
from wrenchd.models.physics.kinematics import PSM_LOWER, PSM_UPPER
from wrenchd.models.series import JOINT_NAMES, N_JOINTS, JointStates

#: Below these shares of the joint's position span or speed cap a joint counts as barely
#: excited (a warning in the fit report).
LOW_RANGE_SHARE = 0.2
LOW_SPEED_SHARE = 0.2
#: Joints 1-3 (yaw, pitch, insertion) carry the gravity and most of the friction: a fit
#: refuses recordings where any of them moved less than these [rad, rad, m] or whose free
#: motion is shorter than MIN_DURATION_S.
MIN_RANGE = (0.1, 0.1, 0.02)
MIN_DURATION_S = 10.0


@dataclass(frozen=True)
class JointCoverage:
    """One joint's motion in a recording: position range and peak speed, absolute and as a
    share of the joint's span (``PSM_UPPER - PSM_LOWER``) and speed cap."""

    joint: str
    range: float
    range_share: float
    max_speed: float
    speed_share: float

    @property
    def barely_excited(self) -> bool:
        return bool(self.range_share < LOW_RANGE_SHARE or self.speed_share < LOW_SPEED_SHARE)

    def to_json(self) -> dict:
        return {"joint": self.joint, "range": self.range, "range_share": self.range_share,
                "max_speed": self.max_speed, "speed_share": self.speed_share,
                "barely_excited": self.barely_excited}


def motion_coverage(series: Sequence[JointStates]) -> list[JointCoverage]:
    """Per joint, over all ``series`` together: the range of positions visited [rad; m] and
    the largest speed [rad/s; m/s], also as shares of the joint's span and speed cap."""
    if not series:
        raise DataError("no joint states to measure")
    q = np.concatenate([s.position for s in series])
    dq = np.concatenate([s.velocity for s in series])
    span = PSM_UPPER - PSM_LOWER
    cap = np.asarray(DEFAULT_MAX_VELOCITY, dtype=float)
    out = []
    for j in range(N_JOINTS):
        rng = float(q[:, j].max() - q[:, j].min())
        speed = float(np.abs(dq[:, j]).max())
        out.append(JointCoverage(JOINT_NAMES[j], rng, float(rng / span[j]), speed,
                                 float(speed / cap[j])))
    return out


def check_motion(series: Sequence[JointStates]) -> list[JointCoverage]:
    """:func:`motion_coverage`, refusing a recording that cannot identify the arm.

    Raises:
        DataError: less than :data:`MIN_DURATION_S` of samples, or one of joints 1-3 moved
            less than :data:`MIN_RANGE`; the message says which and by how much.
    """
    duration = float(sum(s.t[-1] - s.t[0] for s in series if len(s) > 1))
    if duration < MIN_DURATION_S:
        raise DataError(f"the recording holds {duration:.1f} s of motion; identification needs "
                        f"at least {MIN_DURATION_S:g} s (record longer, e.g. `wrenchd excite`)")
    coverage = motion_coverage(series)
    still = [f"{c.joint} moved {c.range:.3g} (needs {need:g})"
             for c, need in zip(coverage, MIN_RANGE) if c.range < need]
    if still:
        raise DataError("too little motion to identify the arm: " + "; ".join(still)
                        + " (play an excitation trajectory: `wrenchd excite`)")
    return coverage
