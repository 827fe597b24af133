"""Drift of the free-motion residual: has the set-up changed under the model?

Fed one number per free-motion sample, the residual's size in units of the gate's noise floor
(``mean_j |r_j| / min_std_j``), a ``river`` change detector raises when that level rises:
Page-Hinkley in ``up`` mode by default (a cumulative-sum test for an increase of the mean;
improvements from adaptation are not drifts), or ADWIN (adaptive windowing, both directions).
After a detection the detector is rebuilt and stays quiet for ``cooldown_s``, so one change
raises one event. The pipeline turns a detection into an event and makes adaptation eager.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from river import drift


class DriftConfig(BaseModel):
    """Change detection on the free-motion residual level."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    method: Literal["page-hinkley", "adwin"] = "page-hinkley"
    threshold: float = Field(default=200.0, gt=0.0, description="Page-Hinkley threshold")
    delta: float = Field(default=0.5, ge=0.0,
                         description="Page-Hinkley tolerated increase [noise-floor units]")
    adwin_delta: float = Field(default=0.002, gt=0.0, lt=1.0, description="ADWIN confidence")
    min_samples: int = Field(default=400, ge=1, description="samples before a detection")
    cooldown_s: float = Field(default=30.0, ge=0.0, description="quiet time after a detection [s]")


class ResidualDriftDetector:
    """Page-Hinkley or ADWIN on the normalised free-motion residual level."""

    def __init__(self, floor: np.ndarray, config: DriftConfig | None = None) -> None:
        self.config = config if config is not None else DriftConfig()
        self._floor = np.asarray(floor, dtype=float)
        self.detections = 0
        self.last_detection_t: float | None = None
        self._rebuild()

    def _rebuild(self) -> None:
        c = self.config
        if c.method == "adwin":
            self._detector = drift.ADWIN(delta=c.adwin_delta)
        else:
            self._detector = drift.PageHinkley(min_instances=c.min_samples, delta=c.delta,
                                               threshold=c.threshold, mode="up")

    def level(self, residual: np.ndarray) -> float:
        """The monitored number of a residual (6,): mean |r_j| / floor_j."""
        return float(np.mean(np.abs(residual) / self._floor))

    def update(self, t: float, residual: np.ndarray) -> bool:
        """Feed a free-motion residual at ``t`` [s]; True when a drift is detected now."""
        if (self.last_detection_t is not None
                and t - self.last_detection_t < self.config.cooldown_s):
            return False
        self._detector.update(self.level(residual))
        if self._detector.drift_detected:
            self.detections += 1
            self.last_detection_t = t
            self._rebuild()
            return True
        return False
