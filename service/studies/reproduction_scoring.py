"""Scoring of the reproduction: predicted torques to tip wrenches, errors per trial.

A :class:`Scorer` holds one set of test trials; :func:`score_models` scores configurations
(a step-1 model and an optional step 2) on the test tables and returns their per-trial
errors (:class:`ModelScores`) for every reference (the simulator's true tip wrench, the
force sensor's channel) and metric (RMSE over every sample, over contact samples, peak).
The oracle floor is the estimate made with the simulator's noise-free internal torque.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.models.estimator.correction import Corr, Xfer
from wrenchd.models.estimator.correction_training import predict_segments
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.models.series import Session
from wrenchd.service.studies.reproduction_sets import ReproductionSets

#: {reference: {metric: (trials, 6) errors [N, N m]}} of one set of estimates
TrialScores = dict[str, dict[str, np.ndarray]]
#: a configuration: its step-1 model and its step 2 (None: step 1 alone)
Configuration = tuple[FreeSpaceModel, Corr | Xfer | None]


# -- predicted torques of each configuration ----------------------------------------------
def _features(sessions: list[Session]) -> list[np.ndarray]:
    return [np.concatenate([s.joint_states.position, s.joint_states.velocity], 1)
            for s in sessions]


def predicted_torques(step1: FreeSpaceModel, step2: Corr | Xfer | None,
                      sessions: list[Session]) -> list[np.ndarray]:
    """(T, 6) predicted internal torques of each session (every session starts fresh)."""
    xs = _features(sessions)
    if isinstance(step2, Xfer):
        return predict_segments(step2, xs)
    tau1 = predict_segments(step1, xs)
    if isinstance(step2, Corr):
        return [step2.correct_sequence(x, t) for x, t in zip(xs, tau1)]
    return tau1


def wrench_rmse(predicted: list[np.ndarray], sessions: list[Session], wrench_map: WrenchMap
                ) -> np.ndarray:
    """(trials, 6) RMSE of the estimated tip wrench against the true one [N, N m]."""
    out = []
    for tau, s in zip(predicted, sessions):
        js = s.joint_states
        w = wrench_map.wrench_batch(js.position, js.effort - tau)
        out.append(np.sqrt(np.mean((w - s.truth.external_wrench) ** 2, axis=0)))
    return np.array(out)


def oracle_torques(sessions: list[Session]) -> list[np.ndarray]:
    """The simulator's noise-free internal torque: the best any predictor can do."""
    return [s.truth.internal_torque for s in sessions]


# -- scoring: every trial, every reference, every metric -----------------------------------
METRICS = ("rmse", "contact_rmse", "peak")


def lowpass(wrench: np.ndarray, rate_hz: float, cutoff_hz: float | None) -> np.ndarray:
    """Causal second-order Butterworth low-pass of (T, 6) samples at ``rate_hz`` [Hz], started
    settled at the first sample; ``cutoff_hz`` None returns the input."""
    if cutoff_hz is None:
        return wrench
    from scipy.signal import butter, lfilter, lfilter_zi

    b, a = butter(2, cutoff_hz / (rate_hz / 2.0))
    zi = lfilter_zi(b, a)[:, None] * wrench[:1]
    return lfilter(b, a, wrench, axis=0, zi=zi)[0]


def trial_errors(estimate: np.ndarray, reference: np.ndarray, in_contact: np.ndarray
                 ) -> dict[str, np.ndarray]:
    """Per-axis errors of one trial (each (6,), [N, N m]).

    ``rmse`` over every sample; ``contact_rmse`` over the samples in contact (NaN without
    contact); ``peak``: the largest absolute error over every sample.
    """
    err = estimate - reference
    contact = (np.sqrt(np.mean(err[in_contact] ** 2, axis=0)) if in_contact.any()
               else np.full(err.shape[1], np.nan))
    return {"rmse": np.sqrt(np.mean(err ** 2, axis=0)), "contact_rmse": contact,
            "peak": np.abs(err).max(axis=0)}


def mean_interval(values: np.ndarray, level: float = 0.95, n_boot: int = 2000,
                  seed: int = 0) -> tuple[float, float, float]:
    """Mean of a (seeds, trials) table and its percentile-bootstrap interval.

    Each resample draws seeds with replacement and, independently, trials with replacement
    (the same trials for every seed: every seed is tested on the same sessions), and takes
    the mean of the selected block; with one seed only the trials are resampled.
    """
    v = np.atleast_2d(np.asarray(values, dtype=np.float64))
    s_n, t_n = v.shape
    rng = np.random.default_rng(seed)
    si = rng.integers(0, s_n, (n_boot, s_n)) if s_n > 1 else np.zeros((n_boot, 1), int)
    ti = rng.integers(0, t_n, (n_boot, t_n))
    per_seed = v[si[:, :, None], ti[:, None, :]]              # (n_boot, S, T)
    means = per_seed.mean(axis=(1, 2))
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(v.mean()), float(lo), float(hi)


class Scorer:
    """Scores wrench estimates of one trial set against the truth and the sensor channel.

    The map from external torque to wrench of every trial is computed once
    (``WrenchMap.gains``); the output filter (``cutoff_hz``) is applied to every estimate.
    """

    def __init__(self, sessions: list[Session], wrench_map: WrenchMap,
                 cutoff_hz: float | None) -> None:
        self.sessions, self.cutoff_hz = sessions, cutoff_hz
        self.gains = [wrench_map.gains(s.joint_states.position) for s in sessions]
        self.references = {"truth": [s.truth.external_wrench for s in sessions]}
        if all(s.truth.sensor_wrench is not None for s in sessions):
            self.references["sensor"] = [s.truth.sensor_wrench for s in sessions]
        self._floors: dict[str, TrialScores] | None = None

    def wrenches(self, torques: list[np.ndarray], filtered: bool = True) -> list[np.ndarray]:
        """Estimated tip wrenches from predicted internal torques (filtered if asked)."""
        out = []
        for g, tau, s in zip(self.gains, torques, self.sessions):
            w = np.einsum("nij,nj->ni", g, s.joint_states.effort - tau)
            out.append(lowpass(w, s.joint_states.rate_hz, self.cutoff_hz) if filtered else w)
        return out

    def score(self, torques: list[np.ndarray], filtered: bool = True) -> TrialScores:
        """{reference: {metric: (trials, 6)}}.

        With an output filter, ``truth_unfiltered`` scores the same estimates before the
        filter against the truth (the like-for-like comparison with the raw floor).
        """
        raw = self.wrenches(torques, filtered=False)
        est = ([lowpass(w, s.joint_states.rate_hz, self.cutoff_hz)
                for w, s in zip(raw, self.sessions)] if filtered else raw)
        refs = [(ref, values, est) for ref, values in self.references.items()]
        if filtered and self.cutoff_hz is not None:
            refs.append(("truth_unfiltered", self.references["truth"], raw))
        out = {}
        for ref, values, estimates in refs:
            rows = [trial_errors(e, r, s.truth.in_contact)
                    for e, r, s in zip(estimates, values, self.sessions)]
            out[ref] = {m: np.array([r[m] for r in rows]) for m in METRICS}
        return out

    def floors(self) -> dict[str, TrialScores]:
        """The oracle (noise-free internal torque) raw and through the output filter,
        computed once (the run logs the in-domain floors early and reports them at its end)."""
        if self._floors is None:
            oracle = oracle_torques(self.sessions)
            self._floors = {"raw": self.score(oracle, filtered=False),
                            "filtered": self.score(oracle, filtered=True)}
        return self._floors


class Scorers(BaseModel):
    """The test tables of a run: no-contact and contact trials, and the in-domain step-1
    trials of Base and Seal (none unless the run has them)."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    no_contact: Scorer
    contact: Scorer
    step1_in_domain: dict[str, Scorer] = Field(default_factory=dict)

    @classmethod
    def build(cls, sets: ReproductionSets, wrench_map: WrenchMap,
              cutoff_hz: float | None) -> Scorers:
        return cls(no_contact=Scorer(sets.no_contact, wrench_map, cutoff_hz),
                   contact=Scorer(sets.contact, wrench_map, cutoff_hz),
                   step1_in_domain={k: Scorer(v, wrench_map, cutoff_hz)
                                    for k, v in sets.step1_tests.items()})

    def floors(self) -> dict[str, dict[str, TrialScores]]:
        """{table: the oracle raw and filtered} of the no-contact and contact tables."""
        return {"no_contact": self.no_contact.floors(), "contact": self.contact.floors()}


class ModelScores(BaseModel):
    """Per-trial errors of configurations on each test table: {table: {name: scores}}."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    no_contact: dict[str, TrialScores] = Field(default_factory=dict)
    contact: dict[str, TrialScores] = Field(default_factory=dict)
    step1_in_domain: dict[str, TrialScores] = Field(default_factory=dict)


def score_models(scorers: Scorers, models: dict[str, Configuration],
                 tables: tuple[str, ...]) -> ModelScores:
    """Each configuration of ``models`` scored on ``tables`` (``no_contact``, ``contact``,
    ``step1_in_domain``: there only the step-1 models that have in-domain trials)."""
    out: dict[str, dict[str, TrialScores]] = {t: {} for t in tables}
    for name, (step1, step2) in models.items():
        for table in tables:
            if table == "step1_in_domain":
                scorer = scorers.step1_in_domain.get(name)
                if scorer is None:
                    continue
            else:
                scorer = getattr(scorers, table)
            out[table][name] = scorer.score(predicted_torques(step1, step2, scorer.sessions))
    return ModelScores(**out)
