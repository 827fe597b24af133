"""What a joint state must satisfy to be estimated, for one sample or a whole session.

The same bounds (:class:`~wrenchd.service.pipeline.config.ValidationConfig`) serve the
daemon's per-sample check and replay's vectorised pre-pass, so both refuse the same samples.
"""

from __future__ import annotations

import numpy as np

from wrenchd.models.series import N_JOINTS, JointSample
from wrenchd.service.pipeline.config import ValidationConfig

_FIELDS = ("position", "velocity", "effort")


def _floats(values) -> list:
    """The values of a (6,) array or sequence as a list (a list as it is)."""
    return values.tolist() if isinstance(values, np.ndarray) else list(values)


class SampleValidator:
    """Six finite values each of position, velocity and effort, within their bounds.

    Args:
        config: the bounds per joint [rad; m], [rad/s; m/s], [N m; N].
    """

    def __init__(self, config: ValidationConfig) -> None:
        self.config = config
        self.limits = tuple(np.asarray(v, dtype=float) for v in (
            config.max_abs_position, config.max_abs_velocity, config.max_abs_effort))
        self._bounds = np.stack(self.limits).ravel().tolist()    # 18 floats

    def reason(self, sample: JointSample) -> str | None:
        """Why ``sample`` is refused, or None when it is valid."""
        lengths = (len(sample.position), len(sample.velocity), len(sample.effort))
        if lengths != (N_JOINTS,) * 3:
            return (f"position, velocity, effort have {lengths[0]}, {lengths[1]}, {lengths[2]} "
                    f"values; the PSM pipeline needs {N_JOINTS} each")
        values = (sample.position, sample.velocity, sample.effort)
        # The common case in Python floats, faster than NumPy on 18 values (NaN compares
        # False, so it fails too); the reason is worked out only for a bad sample.
        flat = [*_floats(values[0]), *_floats(values[1]), *_floats(values[2])]
        for v, bound in zip(flat, self._bounds):
            if not abs(v) <= bound:
                break
        else:
            return None
        for name, v, lim in zip(_FIELDS, values, self.limits):
            if not np.isfinite(v).all():
                return f"{name} contains NaN or Inf"
            bad = np.abs(v) > lim
            if bad.any():
                j = int(np.argmax(bad))
                return f"{name}[{j + 1}] = {v[j]:.6g} is beyond the bound {lim[j]:g}"
        return "joint state out of bounds"                     # not reached

    def within(self, position: np.ndarray, velocity: np.ndarray,
               effort: np.ndarray) -> np.ndarray:
        """(N,) bool: the rows :meth:`reason` would accept, for (N, 6) arrays at once (all
        False when the arrays are not (N, 6): the per-sample check then says why)."""
        n = len(position)
        ok = np.ones(n, dtype=bool)
        for values, lim in zip((position, velocity, effort), self.limits):
            values = np.asarray(values)
            if values.ndim != 2 or values.shape[1] != N_JOINTS:
                return np.zeros(n, dtype=bool)
            ok &= np.all(np.isfinite(values) & (np.abs(values) <= lim), axis=1)
        return ok


def accepted_indices(valid: np.ndarray, stamps_ns: np.ndarray) -> np.ndarray:
    """Indices of the samples a pipeline estimates from a session whose stamps [ns] increase
    (a session's never go back): the ``valid`` ones, less any whose stamp does not exceed the
    previous kept one's (refused as a duplicate)."""
    keep = np.flatnonzero(valid)
    stamps = np.asarray(stamps_ns, dtype=np.int64)[keep]
    dup = np.r_[False, np.diff(stamps) <= 0]
    return keep[~dup]
