"""Free-motion gate: is this sample's residual torque small enough to call it free motion?

The residual (measured minus predicted joint torque) of free motion is noise plus whatever
the model has not learned yet; a contact adds ``J^T w`` on top. The gate keeps a slow running
scale of the residual of the samples it judged free (``river`` exponentially weighted mean of
the squared residual per joint, i.e. an RMS about zero), scores each sample by its largest
per-joint residual in those units, and switches with hysteresis:

* free -> contact when the score exceeds ``enter_sigma`` on ``enter_samples`` consecutive
  samples (one noisy sample does not start a contact);
* contact -> free when the score stays below ``exit_sigma`` for ``exit_s`` (a contact whose
  force passes through zero is not chopped into pieces).

The statistics only learn from free samples scoring under ``learn_sigma``, and the scale may
never grow beyond ``max_growth`` times its warm-up value, so a contact, even one that starts
too gently to be seen, cannot widen the bounds that detect it (measured on the
``insufflation-change`` scenario: without these two rules, contacts that slipped through
widened the scale until 2-8 N contacts were called free). ``trainable`` is stricter than
``free``: a free sample scoring over ``train_sigma`` is published as free but kept out of
training. They are centred on zero, not on a running mean, and slow (``alpha``: a time constant of
tens of seconds): a contact's force builds up over a second or more, and a fast running mean
would follow it up and never see it (measured: with a 2.5 s mean, 4-9 N contacts scored
2 sigma). A bias of the residual is the correction net's job, not the gate's. A floor ``min_std`` (per joint, N m or N) keeps the bounds from collapsing onto the noise
of a perfectly adapted model. A gate stuck in contact for longer than ``max_contact_s`` is
re-calibrated (its mean moves to the present residual): a lasting change of the set-up (a new
insufflation pressure) must not look like an endless contact; the pipeline reports it.

Besides the flag, the gate gives the pipeline what it needs to keep contact out of training:
the sample index at which the current contact began, so samples buffered before that moment
(the onset, when the force was still under the bound) can be dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from river import stats

from models.errors import DataError
from models.series import N_JOINTS


class GateConfig(BaseModel):
    """Bounds and hysteresis of the free-motion gate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enter_sigma: float = Field(default=4.0, gt=0.0,
                               description="score that starts a contact [std of free residual]")
    exit_sigma: float = Field(default=3.0, gt=0.0,
                              description="score under which a contact may end [std]")
    enter_samples: int = Field(default=3, ge=1, description="consecutive samples above enter")
    exit_s: float = Field(default=0.5, ge=0.0, description="time below exit to end a contact [s]")
    alpha: float = Field(default=2e-4, gt=0.0, lt=1.0,
                         description="weight of a new free sample in the running RMS")
    warmup_samples: int = Field(default=1000, ge=1,
                                description="samples before the gate may call anything free")
    min_std: tuple[float, ...] = Field(
        default=(0.02, 0.02, 0.1, 0.002, 0.002, 0.002),
        description="floor of each joint's residual std [N m; N on insertion]")
    max_contact_s: float = Field(default=15.0, gt=0.0,
                                 description="a longer contact re-calibrates the gate [s]")
    learn_sigma: float = Field(default=4.0, gt=0.0,
                               description="only samples scoring below this teach the scale")
    train_sigma: float = Field(default=2.0, gt=0.0,
                               description="only free samples scoring below this may train")
    max_growth: float = Field(default=2.0, ge=1.0,
                              description="the scale never exceeds this x its warm-up value")


@dataclass(frozen=True)
class GateDecision:
    """One sample's verdict.

    Attributes:
        free: free motion (published with the estimate).
        score: largest per-joint |residual - mean| / std [std].
        contact_started: sample index where the current contact began (-1 when free).
        recalibrated: the gate re-calibrated at this sample (stuck in contact too long).
    """

    free: bool
    score: float
    contact_started: int
    recalibrated: bool = False
    trainable: bool = False


class FreeMotionGate:
    """Running-statistics residual gate with hysteresis (see the module docstring)."""

    def __init__(self, config: GateConfig | None = None) -> None:
        self.config = config if config is not None else GateConfig()
        if len(self.config.min_std) != N_JOINTS:
            raise DataError(f"min_std needs {N_JOINTS} values")
        if self.config.exit_sigma > self.config.enter_sigma:
            raise DataError("exit_sigma must not exceed enter_sigma")
        self._floor = np.asarray(self.config.min_std, dtype=float)
        self.reset()

    def reset(self) -> None:
        """Forget the statistics (a new set-up)."""
        a = self.config.alpha
        self._msq = [stats.EWMean(fading_factor=a) for _ in range(N_JOINTS)]
        self._warm = [stats.Mean() for _ in range(N_JOINTS)]     # plain mean while warming up
        self._seen = 0
        self._cap = np.full(N_JOINTS, np.inf)
        self._in_contact = False
        self._above = 0
        self._below_since: float | None = None
        self._contact_start = -1
        self._contact_t0 = 0.0
        self.contacts = 0

    @property
    def in_contact(self) -> bool:
        return self._in_contact

    @property
    def calibrated(self) -> bool:
        return self._seen >= self.config.warmup_samples

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre (zeros) and scale (floored RMS) of the free residual, (6,) each."""
        if self._seen < self.config.warmup_samples:
            rms = np.sqrt(np.array([m.get() for m in self._warm]))
        else:
            rms = np.minimum(np.sqrt(np.array([m.get() for m in self._msq])), self._cap)
        return np.zeros(N_JOINTS), np.maximum(rms, self._floor)

    def _learn(self, residual: np.ndarray) -> None:
        warming = self._seen < self.config.warmup_samples
        for j in range(N_JOINTS):
            sq = float(residual[j]) ** 2
            if warming:
                self._warm[j].update(sq)
                if self._seen == self.config.warmup_samples - 1:    # seed the slow average
                    self._msq[j] = stats.EWMean(fading_factor=self.config.alpha)
                    self._msq[j].update(self._warm[j].get())
                    self._cap[j] = self.config.max_growth * max(
                        np.sqrt(self._warm[j].get()), self._floor[j])
            else:
                self._msq[j].update(sq)
        self._seen += 1

    def update(self, index: int, t: float, residual: np.ndarray) -> GateDecision:
        """Judge sample ``index`` at time ``t`` [s] with residual torques (6,)."""
        cfg = self.config
        mean, std = self.bounds()
        score = float(np.max(np.abs(residual) / std)) if self._seen else 0.0
        if not self.calibrated:                          # learn the level first, call nothing
            self._learn(residual)
            return GateDecision(False, score, -1)
        if not self._in_contact:
            self._above = self._above + 1 if score > cfg.enter_sigma else 0
            if self._above >= cfg.enter_samples:
                self._in_contact = True
                self._contact_start = index - cfg.enter_samples + 1
                self._contact_t0 = t
                self._below_since = None
                self.contacts += 1
            else:
                if score < cfg.learn_sigma:
                    self._learn(residual)
                return GateDecision(True, score, -1, trainable=score < cfg.train_sigma)
        # in contact
        if score < cfg.exit_sigma:
            if self._below_since is None:
                self._below_since = t
            if t - self._below_since >= cfg.exit_s:
                self._in_contact, self._above, self._contact_start = False, 0, -1
                return GateDecision(False, score, -1)     # the first free sample is not trusted
        else:
            self._below_since = None
        if t - self._contact_t0 > cfg.max_contact_s:
            for j in range(N_JOINTS):                  # re-scale on the present level
                self._msq[j] = stats.EWMean(fading_factor=cfg.alpha)
                self._msq[j].update(float(residual[j]) ** 2)
                self._cap[j] = cfg.max_growth * max(abs(float(residual[j])), self._floor[j])
            self._in_contact, self._above = False, 0
            start, self._contact_start = self._contact_start, -1
            return GateDecision(False, score, start, recalibrated=True)
        return GateDecision(False, score, self._contact_start)
