"""Drift of the free-motion residual: has the set-up changed under the model?

Fed with every free-motion sample's residual, it monitors one number, the residual's size in
units of the gate's noise floor (``mean_j |r_j| / min_std_j``), with a ``river`` change
detector that raises when that level rises: Page-Hinkley in ``up`` mode by default (a
cumulative-sum test for an increase of the mean; improvements from adaptation are not
drifts), or ADWIN (adaptive windowing, both directions). After a detection the detector is
rebuilt and stays quiet for ``cooldown_s``, so one change raises one event. The pipeline turns
a detection into an event and makes adaptation eager.

Two rules keep contacts out of it, like the training delay line does for the adaptation:
levels wait ``delay_s`` before they reach the detector, and a hole in the stream of free
samples longer than ``hole_s`` (the gate called a contact, or the data stopped) discards the
levels still waiting: the onset of a contact, before the gate saw it, would otherwise look
like a rise of the free-motion level (without these rules, contact onsets, not the
pressure step, raise the detections on ``insufflation-change``).

Cost: levels are averaged over ``block`` samples and the river detector sees the block means
(its threshold and minimum count are given per sample and scaled to blocks), a few
microseconds per sample.
"""

from __future__ import annotations

from collections import deque
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from river import drift


class DriftConfig(BaseModel):
    """Change detection on the free-motion residual level."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    method: Literal["page-hinkley", "adwin"] = Field(default="page-hinkley",
                                                     description="page-hinkley or adwin")
    threshold: float = Field(default=200.0, gt=0.0,
                             description="Page-Hinkley threshold [noise-floor units x samples]")
    delta: float = Field(default=0.5, ge=0.0,
                         description="Page-Hinkley tolerated increase [noise-floor units]")
    adwin_delta: float = Field(default=0.002, gt=0.0, lt=1.0, description="ADWIN confidence")
    min_samples: int = Field(default=400, ge=1, description="samples before a detection")
    cooldown_s: float = Field(default=30.0, ge=0.0, description="quiet time after a detection [s]")
    block: int = Field(default=10, ge=1, description="samples averaged per detector update")
    delay_s: float = Field(default=2.5, ge=0.0,
                           description="a level waits this long before the detector sees it [s]")
    hole_s: float = Field(default=0.1, gt=0.0,
                          description="a longer pause between free samples discards the "
                                      "waiting levels (a contact began) [s]")


class ResidualDriftDetector:
    """Page-Hinkley or ADWIN on the normalised free-motion residual level.

    A residual at its noise floor for a minute, then three times it (200 Hz samples): one
    detection, a few seconds after the step.

    >>> detector = ResidualDriftDetector(floor=np.full(6, 0.1))
    >>> rng = np.random.default_rng(0)
    >>> times = np.arange(120 * 200) / 200                   # two minutes [s]
    >>> scale = np.where(times < 60, 0.1, 0.3)               # the residual's std [N m]
    >>> [float(t) for t, s in zip(times, scale) if detector.update(t, rng.normal(0, s, 6))]
    [63.345]
    """

    def __init__(self, floor: np.ndarray, config: DriftConfig | None = None) -> None:
        self.config = config if config is not None else DriftConfig()
        self._floor = np.asarray(floor, dtype=float)
        self._inv_floor = (1.0 / self._floor).tolist()
        self.detections = 0
        self.last_detection_t: float | None = None
        self._waiting: deque[tuple[float, float]] = deque()   # (time of block end, mean level)
        self._sum = 0.0
        self._n = 0
        self._last_t: float | None = None
        self._rebuild()

    def _rebuild(self) -> None:
        c = self.config
        if c.method == "adwin":
            self._detector = drift.ADWIN(delta=c.adwin_delta)
        else:
            self._detector = drift.PageHinkley(
                min_instances=max(1, round(c.min_samples / c.block)), delta=c.delta,
                threshold=c.threshold / c.block, mode="up")

    def level(self, residual: np.ndarray) -> float:
        """The monitored number of a residual (6,): mean |r_j| / floor_j."""
        r = residual.tolist() if isinstance(residual, np.ndarray) else list(residual)
        return sum([abs(a * b) for a, b in zip(r, self._inv_floor)]) / len(r)

    def update(self, t: float, residual: np.ndarray) -> bool:
        """Feed a free-motion residual at ``t`` [s]; True when a drift is detected now."""
        c = self.config
        if self._last_t is not None and t - self._last_t > c.hole_s:
            self._waiting.clear()                      # a contact's onset may be in there
            self._sum, self._n = 0.0, 0
        self._last_t = t
        if (self.last_detection_t is not None
                and t - self.last_detection_t < c.cooldown_s):
            return False
        self._sum += self.level(residual)
        self._n += 1
        if self._n >= c.block:
            self._waiting.append((t, self._sum / self._n))
            self._sum, self._n = 0.0, 0
        detected = False
        while self._waiting and t - self._waiting[0][0] >= c.delay_s:
            self._detector.update(self._waiting.popleft()[1])
            if self._detector.drift_detected:
                detected = True
                break
        if detected:
            self.detections += 1
            self.last_detection_t = t
            self._waiting.clear()
            self._rebuild()
        return detected
