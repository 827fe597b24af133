"""Where a learned model has seen data: nearest-neighbour distance in joint-state space.

A network trained on a few excitation trajectories is only trustworthy near the joint states
it was trained on; elsewhere its output is an extrapolation. :class:`Coverage` keeps the
training samples' feature rows ``[q, dq]`` or ``[q, dq, ddq]`` (every ``stride``-th, each
feature scaled by its training standard deviation; accelerations count
``acceleration_weight`` as much, being noisier) and measures, for a new row, the Euclidean distance to the
nearest of them in those normalised units. :meth:`Coverage.weight` turns the distance into a
trust weight: 1 up to ``inner_distance``, 0 from ``outer_distance`` on, a smoothstep between,
so a model that blends by this weight hands over without jumps.

The accelerations matter where a network reads them: the same path at half the speed passes
the same positions at velocities a network has seen elsewhere on the path, but at a quarter of
the accelerations, which it has not.

Scale of the distance: consecutive periods of one WPI excitation trajectory lie within about
0.05 (median) to 0.4 (99th percentile) of each other; another trajectory lies 2 to 4 away.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from scipy.spatial import cKDTree
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.features import N_FEATURES

#: Smallest feature scale (a joint that never moved in training).
MIN_SCALE = 1e-6
#: Up to this many rows a distance is computed against every point, not searched in the tree.
BRUTE_ROWS = 4
#: Row widths: ``[q, dq]`` and ``[q, dq, ddq]``.
WIDTHS = (N_FEATURES, N_FEATURES + 6)


class CoverageConfig(BaseModel):
    """The trust region of a learned model."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    inner_distance: float = Field(default=0.5, ge=0.0,
                                  description="full trust up to this normalised distance")
    outer_distance: float = Field(default=1.0, gt=0.0,
                                  description="no trust from this normalised distance on")
    stride: int = Field(default=4, ge=1, description="keep every n-th training sample")
    acceleration_weight: float = Field(
        default=0.0, ge=0.0, description="weight of the accelerations in the distance; 0: the "
                                         "distance in [q, dq] only")

    @model_validator(mode="after")
    def _ordered(self) -> CoverageConfig:
        if not self.outer_distance > self.inner_distance:
            raise ValueError("outer_distance must exceed inner_distance")
        return self


DEFAULT_COVERAGE = CoverageConfig()


def smoothstep(x: np.ndarray) -> np.ndarray:
    """``3 x^2 - 2 x^3`` of ``x`` clipped to [0, 1]: 0 -> 0, 1 -> 1, flat at both ends."""
    x = np.minimum(np.maximum(x, 0.0), 1.0)       # np.clip's dispatch costs more on a row
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class Coverage:
    """Reference rows ``points`` (M, 12) already normalised: ``(x - mean) / scale``."""

    points: np.ndarray
    mean: np.ndarray
    scale: np.ndarray
    config: CoverageConfig = DEFAULT_COVERAGE
    _tree: cKDTree = field(init=False, repr=False, compare=False)
    _norms: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=np.float64)
        mean = np.asarray(self.mean, dtype=np.float64)
        scale = np.asarray(self.scale, dtype=np.float64)
        width = pts.shape[1] if pts.ndim == 2 else -1
        if (width not in WIDTHS or len(pts) == 0
                or mean.shape != (width,) or scale.shape != (width,)):
            raise ConfigError(f"coverage needs (M >= 1, 12 or 18) points and a mean and scale "
                              f"as wide, got {pts.shape}, {mean.shape}, {scale.shape}")
        if not (np.isfinite(pts).all() and np.isfinite(mean).all() and np.all(scale > 0)):
            raise ConfigError("coverage points, mean and scale must be finite, scale > 0")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "scale", scale)
        object.__setattr__(self, "_tree", cKDTree(pts))
        object.__setattr__(self, "_norms", np.einsum("ij,ij->i", pts, pts))

    @classmethod
    def fit(cls, features: Sequence[np.ndarray], config: CoverageConfig | None = None
            ) -> Coverage:
        """Coverage of training segments' (T, 12) rows ``[q, dq]``, or (T, 18) rows
        ``[q, dq, ddq]`` whose accelerations count ``config.acceleration_weight`` as much
        (their scale is divided by it)."""
        config = config if config is not None else CoverageConfig()
        rows = [np.asarray(f, dtype=np.float64) for f in features]
        if not rows or any(r.ndim != 2 or r.shape[1] != rows[0].shape[1] for r in rows) or \
                rows[0].shape[1] not in WIDTHS:
            raise DataError("coverage needs (T, 12) or (T, 18) feature rows")
        every = np.concatenate(rows)
        if len(every) == 0:
            raise DataError("coverage needs at least one training sample")
        mean, scale = every.mean(0), np.maximum(every.std(0), MIN_SCALE)
        if every.shape[1] > N_FEATURES:
            if not config.acceleration_weight > 0:
                raise DataError("accelerations in the coverage need acceleration_weight > 0")
            scale[N_FEATURES:] /= config.acceleration_weight
        kept = np.concatenate([r[::config.stride] for r in rows])
        return cls((kept - mean) / scale, mean, scale, config)

    @property
    def norms(self) -> np.ndarray:
        """(M,) each point's squared norm (for distances computed against every point)."""
        return self._norms

    @property
    def width(self) -> int:
        """Columns of a row: 12 (``[q, dq]``) or 18 (``[q, dq, ddq]``)."""
        return int(self.points.shape[1])

    def distance(self, features: np.ndarray) -> np.ndarray:
        """Normalised distance (N,) of (N, :attr:`width`) rows to the nearest training row."""
        x = np.asarray(features, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self.width:
            raise DataError(f"features must be (N, {self.width}), got {x.shape}")
        z = (x - self.mean) / self.scale
        if len(z) > BRUTE_ROWS:
            d, _ = self._tree.query(z)
            return np.asarray(d, dtype=np.float64)
        # a streamed row: all M distances at once, |p|^2 - 2 p.z + |z|^2, beat the tree's
        # search and its call (in 12-18 dimensions it visits most leaves anyway)
        d2 = self._norms[None, :] - 2.0 * (z @ self.points.T)
        d2 = d2.min(axis=1) + np.einsum("ij,ij->i", z, z)
        return np.sqrt(np.maximum(d2, 0.0))

    def weight(self, features: np.ndarray) -> np.ndarray:
        """Trust (N,) in [0, 1] of (N, :attr:`width`) rows (see the module docstring)."""
        cfg = self.config
        d = self.distance(features)
        return smoothstep((cfg.outer_distance - d) / (cfg.outer_distance - cfg.inner_distance))
