"""The check that the contact-free calibration at a session's start is contact-free.

The step-1 residual (measured minus step-1 torque) does not change while the correction net
calibrates, and the step-1 model's held-out (validation) RMSE says how large it is in free
motion; a contact adds ``J^T w`` on top. A :class:`FreeMotionGate` on that residual, seeded from
the RMSE instead of a warm-up that could itself be spent in contact, judges from the first
sample (:class:`~wrenchd.service.pipeline.config.CalibrationGuardConfig`).

Robust statistics over the window (at most one sample per 5 ms of it) follow: each second
from 2 s into the window on, the
residual's robust level per joint (1.4826 x the median absolute residual: a normal RMS
that the contacts, as long as they fill less than half of the window, hardly move) sets the
guard's scale to ``robust_factor`` x that level, never below the seeded scale and never above
``max_growth`` x it. The model's **fit ratio** of a joint is the residual's lower-quartile
level (the |residual| that three samples in four exceed, as a normal RMS) over its held-out
RMSE (floored by the gate's ``min_std``), judged from 5 s into the window on: a misfit is
in nearly every sample, a contact in some (the median would take a contact that fills more
than half of the window's first seconds for a misfit; the lower quartile needs three
quarters). Above ``mismatch_ratio`` on a joint, the step-1 model does not explain this arm
there (a wrong checkpoint, a set-up it never saw): the guard says so
(:attr:`CalibrationGuard.mismatch`). Over ``follow_ratio`` (lower) a joint's scale follows the
window's level without the bound, instead of the guard calling nearly every sample contact
and keeping from step 2 the residual it is there to learn; the other joints, bounded, still
see the contacts.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.gate import FreeMotionGate, GateDecision
from wrenchd.models.series import N_JOINTS
from wrenchd.service.pipeline.config import CalibrationGuardConfig, PipelineConfig
from wrenchd.service.pipeline.records import Event, EventKind

#: the window's robust level is first used this long after the calibration's start, then
#: recomputed this often [s]
ROBUST_AFTER_S, ROBUST_EVERY_S = 2.0, 1.0
#: the fit ratio is first judged this long after the calibration's start [s]
MISMATCH_AFTER_S = 5.0
#: the window keeps at most one sample per this much time [s] (with a tolerance for jitter):
#: every sample at the 200 Hz of a dVRK recording, one in five at 1 kHz. The robust level's
#: quantiles over a minute of 1 kHz samples cost several milliseconds once a second, a stall
#: every arm's estimates wait through; neighbouring samples add next to nothing to them.
WINDOW_EVERY_S = 0.005
_WINDOW_TOLERANCE_S = 0.0005
#: median |x| of a zero-mean normal is 0.6745 sigma, its lower quartile 0.3186 sigma
MAD_TO_RMS, Q25_TO_RMS = 1.4826, 1.0 / 0.31864


class SortedWindow:
    """The guard's window kept sorted per joint as it grows, for its quantiles.

    A quantile by selection over the whole window costs about 0.13 ms per joint at a
    minute's 12 000 rows (the comparisons of a selection on random data are mispredicted
    branches), a stall each second that every arm's estimates wait through. Here the rows
    added since the last call are sorted and merged into the rows sorted before (a stable
    sort finds the two runs and merges them), then read by index: the same numbers as
    ``np.quantile(rows, q, axis=0)`` (its default ``linear`` method), exactly.

    >>> w = SortedWindow()
    >>> rows = np.arange(24.0).reshape(4, 6)[::-1]
    >>> w.quantiles(rows, (0.25, 0.5))[:, 0].tolist()
    [4.5, 9.0]
    """

    def __init__(self) -> None:
        self._sorted = np.empty((N_JOINTS, 0))

    def quantiles(self, rows: np.ndarray, qs: tuple[float, ...]) -> np.ndarray:
        """(len(qs), 6) quantiles of ``rows`` (n, 6), whose first rows are the ones seen
        at the last call (a window that only grows)."""
        n, m = len(rows), self._sorted.shape[1]
        if n < m:
            raise ValueError("the window shrank; start a new SortedWindow")
        if n > m:
            merged = np.concatenate([self._sorted, np.sort(rows[m:n].T, axis=1)], axis=1)
            merged.sort(axis=1, kind="stable")
            self._sorted = merged
        out = np.empty((len(qs), N_JOINTS))
        for k, q in enumerate(qs):
            # numpy's linear method: index q (n - 1), and its lerp (from b when gamma >= 0.5)
            virtual = n * q + (1.0 + q * -1.0) - 1.0
            lo = int(math.floor(virtual))
            gamma = virtual - lo
            a = self._sorted[:, lo]
            b = self._sorted[:, min(lo + 1, n - 1)]
            diff = b - a
            out[k] = b - diff * (1.0 - gamma) if gamma >= 0.5 else a + diff * gamma
        return out


class CalibrationGuard:
    """A gate on the step-1 residual during the calibration.

    Args:
        gate: the gate (seeded by :meth:`start`).
        config: the guard's settings (``action``: warn or refuse).
        heldout: (6,) free-motion RMS of the step-1 residual [N m; N on insertion]: the
            step-1 checkpoint's validation RMSE, or ``config.residual_scale``.
    """

    def __init__(self, gate: FreeMotionGate, config: CalibrationGuardConfig,
                 heldout: np.ndarray) -> None:
        self.gate, self.config = gate, config
        self.refuses = config.action == "refuse"
        # the fit ratio's unit: the held-out RMSE, floored as the gate floors its scale
        self.heldout = np.maximum(np.asarray(heldout, dtype=float),
                                  np.asarray(gate.config.min_std, dtype=float))
        self.seed_scale = config.scale_factor * np.asarray(heldout, dtype=float)
        self.start()

    @classmethod
    def build(cls, config: PipelineConfig, free_space: FreeSpaceModel) -> CalibrationGuard | None:
        """The pipeline's guard, or None (off, no calibration, no known residual scale).

        Raises:
            ConfigError: a residual scale without one value per joint.
        """
        g = config.calibration_guard
        scale = g.residual_scale
        if scale is None:
            scale = getattr(free_space, "validation_rmse", None)
        if not g.enabled or scale is None or config.calibration_s <= 0:
            return None
        if len(scale) != N_JOINTS:
            raise ConfigError(f"calibration_guard.residual_scale needs {N_JOINTS} values, "
                              f"got {len(scale)}")
        return cls(FreeMotionGate(config.gate), g, np.asarray(scale, dtype=float))

    def start(self) -> None:
        """A new calibration: the seeded scale, an empty window, no verdict on the fit."""
        self.gate.seed(self.seed_scale)
        self.last_free = True            # the verdict on the last sample judged
        self.ratios: np.ndarray | None = None     # (6,) fit ratio per joint, once judged
        self.mismatch = False
        self._window = np.empty((1024, N_JOINTS))
        self._n = 0
        self._sorted = SortedWindow()
        self._kept_t = -np.inf
        self._t0: float | None = None
        self._next_t = 0.0

    @property
    def ratio(self) -> float | None:
        """The largest per-joint fit ratio (None before it is judged)."""
        return None if self.ratios is None else float(self.ratios.max())

    def _remember(self, t: float, residual: np.ndarray) -> None:
        if t - self._kept_t >= WINDOW_EVERY_S - _WINDOW_TOLERANCE_S:
            self._kept_t = t
            if self._n == len(self._window):
                self._window = np.concatenate([self._window, np.empty_like(self._window)])
            self._window[self._n] = np.abs(residual)
            self._n += 1
        if self._t0 is None:
            self._t0 = t
            self._next_t = t + ROBUST_AFTER_S
        elif t >= self._next_t:
            self._next_t = t + ROBUST_EVERY_S
            self._follow_level(t - self._t0)

    def _follow_level(self, elapsed_s: float) -> None:
        """Set the gate's scale from the window's robust level; judge the fit."""
        q25, median = self._sorted.quantiles(self._window[:self._n], (0.25, 0.5))
        level = MAD_TO_RMS * median
        if elapsed_s >= MISMATCH_AFTER_S:
            self.ratios = Q25_TO_RMS * q25 / self.heldout
            self.mismatch = bool(self.ratios.max() > self.config.mismatch_ratio)
        scale = np.maximum(self.config.robust_factor * level, self.seed_scale)
        bounded = np.minimum(scale, self.gate.config.max_growth * self.seed_scale)
        if self.ratios is not None:         # a joint the model does not fit: its own level
            follow = min(self.config.follow_ratio, self.config.mismatch_ratio)
            bounded = np.where(self.ratios > follow, scale, bounded)
        self.gate.rescale(bounded)

    def judge(self, index: int, t: float, residual: np.ndarray) -> GateDecision:
        """The verdict on one sample from its step-1 residual (6,) [N m; N], with the guard's
        peak score. With ``action: warn`` every sample stays free and trainable (the guard
        only counts, in :attr:`last_free`)."""
        self._remember(t, residual)
        g = self.gate.update(index, t, residual)
        # a contact the gate has released (published free, the contact's until it ends) is
        # contact to the guard: its verdicts are about training
        free = g.free and g.contact_started < 0
        self.last_free = free
        if not self.refuses:
            return GateDecision(True, g.score, -1, trainable=True)
        trainable = free if self.config.borderline_trains else g.trainable
        return GateDecision(free, g.score, g.contact_started, trainable=trainable)


class CalibrationPhase:
    """The first ``calibration_s`` of a session (and of a new instrument), whose verdicts are
    the guard's, and the hand-over to the free-motion gate after it.

    While calibrating, every sample is the guard's to judge (with no guard, free); with a
    guard that refuses, also the gate's warm-up after it (the warm-up calls nothing free and
    would drop the delay line). The gate's warm-up scale after it is bounded by the RMS
    of the residual over the guard's free samples of the last ``gate_prior_s``. At the hand-
    over the delay line's samples, judged by the guard alone, are dropped; a contact the guard
    is in then goes on as the gate's.

    Args:
        arm: name used in events.
        config: the pipeline's settings.
        free_space: the step-1 model (its held-out RMSE seeds the guard).
        gate: the pipeline's free-motion gate (reset at the calibration's end).
        counters: the pipeline's counters (calibration samples and contact, onsets).
    """

    def __init__(self, arm: str, config: PipelineConfig, free_space: FreeSpaceModel,
                 gate: FreeMotionGate, counters) -> None:
        self.arm, self.config, self.gate, self.counters = arm, config, gate, counters
        self.guard = CalibrationGuard.build(config, free_space)
        self.refuses = self.guard is not None and self.guard.refuses
        self.end: float | None = None         # None: the next sample starts a calibration
        self._was_guarded = False             # the last sample was the guard's to judge
        self._mismatch_said = False           # the model_mismatch event of this calibration
        self._prior_sq = np.zeros(N_JOINTS)   # summed squared residual of the guard's free
        self._prior_n = 0                     # samples late in the calibration (gate's prior)
        # judges the gate's warm-up after the calibration beside the guard, on the corrected
        # residual (calibration_guard.judge_warmup); None: the guard alone
        self._warmup_gate: FreeMotionGate | None = None
        self._warmup_held = False        # the second gate holds a contact
        self._warmup_ended = -1          # the guard's contact (its start) the second gate ended

    @property
    def calibrating(self) -> bool:
        return self.end is None or bool(np.isfinite(self.end))

    def restart(self) -> None:
        """Calibrate again from the next sample (a new instrument), unless calibrating."""
        if self.config.calibration_s > 0 and not self.calibrating:
            self.end = None

    @property
    def contaminated(self) -> bool:
        """The guard called more than ``warn_fraction`` of the calibration's samples contact
        (so far, while calibrating): re-calibrate when it is over."""
        c = self.counters
        return (c.calibration_samples > 0 and c.calibration_contact
                > self.config.calibration_guard.warn_fraction * c.calibration_samples)

    def fit(self) -> dict[str, Any]:
        """The guard's verdict on the step-1 model's fit (status and events)."""
        guard = self.guard
        return {"model_mismatch": guard is not None and guard.mismatch,
                "fit_ratio": None if guard is None else guard.ratio}

    def overrule(self, index: int, t: float, out, effort: np.ndarray, decision: GateDecision,
                 warming: bool, events: list, backend, model_version: int, line
                 ) -> tuple[GateDecision, bool, bool]:
        """The verdict on sample ``index`` at ``t`` [s] given the gate's ``decision``
        (``warming``: the gate was warming up before it): ``(decision, calibrating,
        guarded)``, the guard's verdict where the sample is the guard's to judge."""
        calibrating = self._step(t, events, backend, model_version)  # may reset the gate
        gate = self.gate
        guarded = calibrating or (self.refuses and (warming or not gate.calibrated))
        if guarded:
            decision = self._judge(index, t, out, effort, events, calibrating, decision.score)
            if warming and gate.calibrated and not calibrating:
                # the hand-over to the gate: a contact too weak for the guard may be in
                # progress (the gate's settle keeps the next exit_s out of training); the
                # samples waiting in the delay line, judged by the guard alone, go as well
                self.counters.discarded_onsets += line.drop_onset(-1)
                decision = decision._replace(trainable=False)
        elif self._was_guarded and self.refuses:
            # the gate takes over from the guard in the middle of a contact: it goes on
            # with it (fresh, it would need a run of samples to find it, and train on them)
            warm = self._warmup_gate
            unconfirmed = (warm is not None and not warm.in_contact
                           and self.config.calibration_guard.warmup_confirm)
            starts = [g.contact_start for g in (self.guard.gate, warm)
                      if g is not None and g.in_contact
                      and not (g is self.guard.gate and warm is not None
                               and (g.contact_start == self._warmup_ended or unconfirmed))]
            if starts:
                gate.take_over_contact(min(starts), t)
            self._warmup_gate = None
        self._was_guarded = guarded
        return decision, calibrating, guarded

    def _judge(self, index: int, t: float, out, effort: np.ndarray, events: list,
               calibrating: bool, score: float) -> GateDecision:
        """The guard's verdict (free with no guard) on a sample of the calibration (counted)
        or of the gate's warm-up after it, with the gate's ``score``; the first time in a
        calibration that the guard finds the step-1 model does not fit, a ``model_mismatch``
        event."""
        if calibrating:
            self.counters.calibration_samples += 1
        guard = self.guard
        if guard is None:
            return GateDecision(True, score, -1, trainable=True)
        decision = guard.judge(index, t, effort - out.step1_torque)._replace(score=score)
        if self._warmup_gate is not None and not calibrating:
            decision = self._judge_corrected(index, t, out.external_torque, decision)
        if calibrating and not guard.last_free:
            self.counters.calibration_contact += 1
        elif calibrating and t >= self.end - self.config.calibration_guard.gate_prior_s:
            self._prior_sq += out.external_torque * out.external_torque
            self._prior_n += 1
        if guard.mismatch and not self._mismatch_said:
            self._mismatch_said = True
            ratios = guard.ratios
            events.append(Event(t, EventKind.MODEL_MISMATCH, {
                "arm": self.arm, "fit_ratio": float(ratios.max()),
                "joint": int(np.argmax(ratios)), "fit_ratios": ratios.tolist(),
                "threshold": self.config.calibration_guard.mismatch_ratio}))
        return decision

    def _judge_corrected(self, index: int, t: float, residual: np.ndarray,
                         guard: GateDecision) -> GateDecision:
        """The guard's verdict on a sample of the gate's warm-up combined with the warm-up
        gate's on the residual Corr leaves (6,) [N m; N]: contact where the warm-up gate
        calls it (from the guard's onset where the guard called it first), and, without
        ``warmup_confirm``, where the guard alone does; trainable where both let it train. A
        contact of the guard's that the warm-up gate held too and has ended is published free
        from there (the corrected residual says the force is gone; the raw one still carries
        what Corr takes out), never trainable until the guard ends it as well."""
        g = self._warmup_gate.update(index, t, residual)
        if g.contact_started >= 0:
            self._warmup_held = True
        elif self._warmup_held:                     # it has just ended one
            self._warmup_held = False
            self._warmup_ended = guard.contact_started
        if g.free and g.contact_started < 0:
            if 0 <= guard.contact_started and (guard.contact_started == self._warmup_ended
                                               or self.config.calibration_guard.warmup_confirm):
                return guard._replace(free=True, trainable=False)
            return guard
        starts = [s for s in (guard.contact_started, g.contact_started) if s >= 0]
        return GateDecision(False, guard.score, min(starts) if starts else -1, trainable=False)

    def _step(self, t: float, events: list, backend, model_version: int) -> bool:
        """Whether the sample at ``t`` [s] is in the calibration: starts one on the first
        sample (``calibrating`` event, eager adaptation), ends it (``calibrated`` event, the
        gate reset) on the first sample past it."""
        if self.end is None:
            self.end = t + self.config.calibration_s
            self._mismatch_said = False
            self._prior_sq[:] = 0.0
            self._prior_n = 0
            self._warmup_gate = None
            if self.guard is not None:
                self.guard.start()                      # a fresh window, the seeded scale
            if self.config.calibration_s > 0:
                if backend is not None:
                    backend.drift(t)                    # eager from the start
                events.append(Event(t, EventKind.CALIBRATING, {"arm": self.arm, "until": self.end}))
        if not math.isfinite(self.end):                 # a float: math is cheaper
            return False
        if t < self.end:
            return True
        self.end = math.inf
        if self.config.calibration_s > 0:
            prior = self._reset_gate(t)
            c = self.counters
            events.append(Event(t, EventKind.CALIBRATED, {"arm": self.arm, "model_version": model_version,
                                                  "samples": c.calibration_samples,
                                                  "contact": c.calibration_contact,
                                                  "gate_prior_samples": prior, **self.fit()}))
            if self.contaminated:
                events.append(Event(t, EventKind.CALIBRATION_CONTAMINATED, {
                    "arm": self.arm, "samples": c.calibration_samples,
                    "contact": c.calibration_contact,
                    "fraction": c.calibration_contact / max(c.calibration_samples, 1)}))
        return False

    def _reset_gate(self, t: float) -> int:
        """Reset the gate to warm up on the calibrated residual, its warm-up scale bounded by
        the prior (not with no guard, a guard that only warns, or fewer samples than the
        gate's warm-up); with ``judge_warmup`` a second gate, started at ``t`` [s] from
        ``scale_factor`` times the prior, judges the warm-up beside the guard on the
        corrected residual. How many samples gave the prior (0: none)."""
        n = self._prior_n
        if not self.refuses or n == 0 or n < self.gate.config.warmup_samples:
            self.gate.reset()
            return 0
        prior = np.sqrt(self._prior_sq / n)
        self.gate.reset(prior=prior)
        if self.config.calibration_guard.judge_warmup:
            # the prior is an in-sample level (Corr trained on those samples): widened as the
            # guard widens the step-1 model's held-out error to seed itself
            self._warmup_gate = FreeMotionGate(self.gate.config)
            self._warmup_held, self._warmup_ended = False, -1
            self._warmup_gate.seed(self.config.calibration_guard.scale_factor * prior)
            self._warmup_gate.settle(t)
        return n
