"""One arm's per-sample pipeline: validate, estimate, gate, offer to training, swap models.

The daemon and replay drive the very same :class:`ArmPipeline`; publishing and logging are
the caller's (with what :meth:`ArmPipeline.process` returns), adaptation is behind
:class:`AdaptationBackend` (inline in simulated time for replay, a worker for the daemon).
Per sample, in :meth:`ArmPipeline._after`'s order:

1. **admit**: a decoded message with six finite joints within ``ValidationConfig``, time
   increasing; a bad sample is an ``error`` event and a counter, never estimated or trained
   on. A gap over ``max_gap_s`` restarts the estimator's state (``gap`` event).
2. **estimate**: :class:`TwoStepEstimator` (step 1, ``Corr``, damped ``J^-T``).
3. **gate**: :class:`FreeMotionGate` on the residual; during the calibration (the paper's
   contact-free first ``calibration_s``) the verdicts are the calibration guard's
   (:class:`~wrenchd.service.pipeline.calibration.CalibrationPhase`); a lasting contact whose
   tip force swings with the pose is a set-up change (``gate_setup_change``).
4. **drift**: free samples feed :class:`ResidualDriftDetector`; a detection makes the
   adaptation eager (``drift``).
5. **offer**: the policy's :class:`~wrenchd.service.pipeline.mechanisms.Mechanism`: gated, a
   free sample waits ``release_delay_s`` in the delay line and is dropped if a contact began
   meanwhile, or if its residual has a weak contact's form
   (:class:`~wrenchd.models.weak_contact.WeakContactWatch`); ungated, every sample at once;
   frozen, none.
6. **swap**: accepted rounds replace the ``Corr`` between two samples.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from wrenchd.models.adaptation import normalisation_of
from wrenchd.models.adaptation.adapter import SETUP_KINDS
from wrenchd.models.drift_detector import ResidualDriftDetector
from wrenchd.models.errors import DataError
from wrenchd.models.estimator.estimator import TwoStepEstimator
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.gate import FreeMotionGate, GateDecision
from wrenchd.models.series import N_JOINTS, JointSample, all_finite
from wrenchd.service.pipeline.calibration import CalibrationPhase
from wrenchd.service.pipeline.adaptation import AdaptationBackend, InlineAdaptation, initial_corr
from wrenchd.service.pipeline.config import PipelineConfig
from wrenchd.service.pipeline.delay_line import DelayLine, Released, offer_rows
from wrenchd.service.pipeline.mechanisms import mechanism
from wrenchd.service.pipeline.records import Counters, Estimate, Event, EventKind
from wrenchd.service.pipeline.validation import SampleValidator
from wrenchd.models.adaptation import RoundResult
from wrenchd.models.weak_contact import WeakContactWatch


class ArmPipeline:
    """Validate, estimate, gate, offer to adaptation, swap models: one arm.

    Args:
        arm: name used in events.
        free_space: the step-1 model (shipped weights or a checkpoint).
        config: the pipeline's settings.
        backend: adaptation backend; default inline (replay); None with policy ``frozen``.

    A sample is estimated (the gate warms up first: nothing is free yet); a repeated stamp and
    a sample with NaN positions are error events, never estimated:

    >>> from wrenchd.models.estimator.pretrained import load_pretrained
    >>> from wrenchd.models.series import JointSample
    >>> arm = ArmPipeline("PSM1", load_pretrained("base"), PipelineConfig(calibration_s=0.0))
    >>> q, zero, names = np.array([0.1, -0.2, 0.12, 0, 0, 0]), np.zeros(6), tuple("abcdef")
    >>> est, events = arm.process(JointSample(1_000_000, "", names, q, zero, zero))
    >>> est.index, est.free, est.wrench.shape, events
    (0, False, (6,), [])
    >>> for stamp_ns, position in ((1_000_000, q), (2_000_000, q * np.nan)):
    ...     est, events = arm.process(JointSample(stamp_ns, "", names, position, zero, zero))
    ...     print(est, [(e.kind.value, e.detail["error"]) for e in events])
    None [('error', 'duplicate')]
    None [('error', 'invalid')]
    >>> arm.close()
    """

    def __init__(self, arm: str, free_space: FreeSpaceModel, config: PipelineConfig | None = None,
                 backend: AdaptationBackend | None = None) -> None:
        self.arm = arm
        self.config = c = config if config is not None else PipelineConfig()
        self.policy = c.policy.name
        self.mechanism = mechanism(c.policy.name)
        self.estimator = TwoStepEstimator(free_space, initial_corr(c.adaptation), c.estimator)
        kinematics = self.estimator.wrench_map.kinematics
        self.gate = FreeMotionGate(c.gate, kinematics)
        self.weak = (WeakContactWatch(c.gate, kinematics)
                     if c.gate.weak_contact_s > 0 and kinematics is not None else None)
        self.counters = Counters()
        self.calibration = CalibrationPhase(arm, c, free_space, self.gate, self.counters)
        self.drift = ResidualDriftDetector(np.asarray(c.gate.min_std), c.drift)
        adapt = c.adaptation.enabled and self.mechanism.adapts
        self.backend = (backend if backend is not None else InlineAdaptation(
            c.adaptation, normalisation_of(free_space))) if adapt else None
        self.on_offer = None      # optional hook: called with the times [s] of offered samples
        self.model_version = 0
        self.model_validation: float | None = None
        self._last_ns: int | None = None
        self._behind = 0                      # consecutive samples stamped before the last
        self.line = DelayLine(c.policy)
        self.validator = SampleValidator(c.validation)
        self._adapt_until = -np.inf           # eager (and drift-triggered offers) until then
        self._was_contact = False
        self._last_setup: dict[str, Any] | None = None
        self.body_wall: list[float | None] = []    # stiffness per segment, the last round's

    # -- validation ---------------------------------------------------------------------
    def _error(self, t: float, kind: str, reason: str) -> Event:
        self.counters.errors += 1
        self.counters.error_kinds[kind] = self.counters.error_kinds.get(kind, 0) + 1
        return Event(t, EventKind.ERROR, {"arm": self.arm, "error": kind, "reason": reason})

    def reject(self, t: float, kind: str, reason: str) -> Event:
        """Count and describe an input refused before it reached the pipeline (decoding)."""
        self.counters.received += 1
        return self._error(t, kind, reason)

    # -- per sample ---------------------------------------------------------------------
    def process(self, msg: JointSample, checked: bool = False
                ) -> tuple[Estimate | None, list[Event]]:
        """Run one decoded joint state through the pipeline.

        ``checked``: the caller has already found ``msg`` within ``config.validation`` (six
        finite values each, within the bounds; replay checks a whole session at once), so
        the per-sample check is skipped; everything else (stamp order, gaps) is as usual.
        """
        admitted = self._admit(msg, checked)
        if isinstance(admitted, list):
            return None, admitted
        return self._finish_one(msg, *admitted)

    #: the smallest backlog :meth:`process_many` estimates in one pass (below, one by one)
    BATCH_MIN = 6

    def process_many(self, msgs: list[JointSample]
                     ) -> list[tuple[Estimate | None, list[Event]]]:
        """Consecutive joint states of this arm, as :meth:`process` would handle them one by
        one, with two differences: the estimator works a backlog off in one pass (the
        one-arm case of :meth:`process_many_joint`: equal up to float32 rounding), and the
        adaptation is looked at once, after the last sample (a model that became ready
        meanwhile serves from the next call on, as if it had come a few samples later).
        """
        if len(msgs) < self.BATCH_MIN:
            return [self.process(m) for m in msgs]
        return ArmPipeline.process_many_joint([self], [msgs])[0]

    @staticmethod
    def process_many_joint(pipelines: list[ArmPipeline], msgs: list[list[JointSample]]
                           ) -> list[list[tuple[Estimate | None, list[Event]]]]:
        """Queued joint states of several arms whose estimators share their step-1 kernel
        (arms of one daemon, one model): what each arm's :meth:`process_many` returns, the
        recurrences of all arms stepped as one batch
        (:meth:`TwoStepEstimator.step_many_joint`, equal to float32 rounding)."""
        admitted = [p._admit_all(arm_msgs) for p, arm_msgs in zip(pipelines, msgs)]
        try:
            outs = TwoStepEstimator.step_many_joint(
                [p.estimator for p in pipelines],
                [(np.array([a[2] for a in adm]),
                  np.array([a[1].position for a in adm]).reshape(-1, N_JOINTS),
                  np.array([a[1].velocity for a in adm]).reshape(-1, N_JOINTS),
                  np.array([a[1].effort for a in adm]).reshape(-1, N_JOINTS))
                 for _, adm in admitted])
        except DataError as exc:                    # cannot happen after validation; be safe
            for p, (res, adm) in zip(pipelines, admitted):
                for k, _, t, events, _ in adm:
                    res[k] = (None, events + [p._error(t, "invalid", str(exc))])
            return [res for res, _ in admitted]
        for p, (res, adm), arm_outs in zip(pipelines, admitted, outs):
            for (k, msg, t, events, gap_s), out in zip(adm, arm_outs):
                res[k] = p._after(msg, t, out, events, gap_s)
            if adm:
                res[adm[-1][0]][1].extend(p._adapt(adm[-1][2]))
        return [res for res, _ in admitted]

    def _admit_all(self, msgs: list[JointSample]) -> tuple[list, list]:
        """:meth:`_admit` in order: the results so far (refusals filled in, a placeholder for
        each admitted sample) and ``(position in results, msg, t, events, gap_s)`` of those
        to estimate."""
        results: list[tuple[Estimate | None, list[Event]]] = []
        admitted: list[tuple] = []
        for msg in msgs:
            a = self._admit(msg)
            if isinstance(a, list):
                results.append((None, a))
            else:
                admitted.append((len(results), msg, *a))
                results.append((None, []))
        return results, admitted

    def _finish_one(self, msg: JointSample, t: float, events: list[Event],
                    gap_s: float | None) -> tuple[Estimate | None, list[Event]]:
        try:
            out = self.estimator.step_one(t, msg.position, msg.velocity, msg.effort)
        except DataError as exc:                    # cannot happen after validation; be safe
            return None, events + [self._error(t, "invalid", str(exc))]
        est, events = self._after(msg, t, out, events, gap_s)
        events.extend(self._adapt(t))
        return est, events

    def _admit(self, msg: JointSample, checked: bool = False
               ) -> tuple[float, list[Event], float | None] | list[Event]:
        """Validation (unless ``checked``) and stamp order: ``(t, events, gap_s)`` of a sample
        to estimate (``gap_s`` the time since the last one when it is a gap, else None), or the
        refusal's events."""
        self.counters.received += 1
        t = msg.stamp_ns / 1e9
        events: list[Event] = []
        if not checked:
            reason = self.validator.reason(msg)
            if reason is not None:
                return [self._error(t, "invalid", reason)]
        last = self._last_ns
        if last is not None and msg.stamp_ns <= last:
            kind = "duplicate" if msg.stamp_ns == last else "time_backwards"
            self._behind += 1
            event = self._error(t, kind, f"stamp {msg.stamp_ns} ns after {last} ns")
            if self._behind < self.config.validation.resync_after:
                return [event]
            events += [event, Event(t, EventKind.CLOCK_RESET, {          # a new timeline: accept it
                "arm": self.arm, "last_ns": last, "now_ns": msg.stamp_ns})]
            last = None
        gap_s = None
        if last is not None and msg.stamp_ns - last > self.config.estimator.max_gap_s * 1e9:
            gap_s = (msg.stamp_ns - last) / 1e9
        self._behind = 0
        self._last_ns = msg.stamp_ns
        return t, events, gap_s

    def _after(self, msg: JointSample, t: float, out, events: list[Event],
               gap_s: float | None) -> tuple[Estimate | None, list[Event]]:
        """Everything after the estimator for one sample: gate, drift, offer (not adaptation)."""
        if events and events[-1].kind == "clock_reset":
            self.line.clear()
        if gap_s is not None:
            self.counters.gaps += 1
            self.line.clear()                          # the delay line spans no gap
            if self.weak is not None:
                self.weak.clear()
            events.append(Event(t, EventKind.GAP, {"arm": self.arm, "gap_s": gap_s}))
        if not all_finite(out.wrench):
            return None, events + [self._error(t, "non_finite_output", "estimate not finite")]
        if out.restarted and gap_s is None and self.counters.estimated and not (
                events and events[-1].kind == EventKind.CLOCK_RESET):
            self.counters.jumps += 1                   # the estimator restarted on a jump
            events.append(Event(t, EventKind.JUMP, {"arm": self.arm}))
        index = self.line.estimated_at(t)
        self.counters.estimated += 1
        warming = not self.gate.calibrated          # before this sample: its last warm-up one
        decision = self.gate.update(index, t, out.external_torque,   # is still a warm-up's
                                    msg.velocity, out.wrench, msg.position)
        decision, calibrating, guarded = self.calibration.overrule(
            index, t, out, msg.effort, decision, warming, events, self.backend,
            self.model_version, self.line)
        self._gate_events(t, decision, events)
        self._contact_events(t, events)
        # a released contact (the gate's release_free) is published free, but for drift and
        # training it is still the contact's: only a sample of no contact is free there
        free = decision.free and decision.contact_started < 0
        if free and not guarded:
            self._drift(t, out.external_torque, events)
        self._offer(t, out, msg, free, events, calibrating, decision.trainable,
                    decision.contact_started)
        est = Estimate(index, msg.stamp_ns, t, msg.position, msg.velocity, msg.effort,
                       out.wrench, out.predicted_torque, out.external_torque, decision.free,
                       decision.score, self.model_version, out.restarted)
        return est, events

    def _gate_events(self, t: float, decision: GateDecision, events: list[Event]) -> None:
        """A set-up change the gate found (adaptation gets eager, as after a drift: the drift
        detector, fed free samples only, saw none of it), one it withdrew, or a
        re-calibration, as events."""
        if decision.setup_change:
            self._eager(t)
            events.append(Event(t, EventKind.GATE_SETUP_CHANGE, {
                "arm": self.arm, "setup_contact_s": self.config.gate.setup_contact_s,
                "tip_form": self.gate.contact.tip_form}))
        elif decision.recalibrated:
            events.append(Event(t, EventKind.GATE_RECALIBRATED, {
                "arm": self.arm, "max_contact_s": self.config.gate.max_contact_s}))
        elif decision.setup_withdrawn:
            events.append(Event(t, EventKind.GATE_SETUP_WITHDRAWN, {
                "arm": self.arm, "form_withdraw_s": self.config.gate.form_withdraw_s}))

    def _drift(self, t: float, residual: np.ndarray, events: list[Event]) -> None:
        """Feed a free sample's residual to the drift detector; a detection makes the
        adaptation eager (``drift`` event)."""
        if self.drift.update(t, residual):
            self.counters.drifts += 1
            events.append(Event(t, EventKind.DRIFT, {"arm": self.arm,
                                                     "level": self.drift.level(residual)}))
            self.gate.drifted(t)
            self._eager(t)

    def _eager(self, t: float) -> None:
        """Adaptation is eager (and drift-triggered offers open) for ``eager_s`` from ``t``."""
        self._adapt_until = t + self.config.adaptation.eager_s
        if self.backend is not None:
            self.backend.drift(t)

    guard = property(lambda self: self.calibration.guard, doc="The calibration guard or None.")

    @property
    def calibrating(self) -> bool:
        return self.calibration.calibrating

    @property
    def calibration_contaminated(self) -> bool:
        """The guard called too much of the calibration contact (see
        :attr:`CalibrationPhase.contaminated`)."""
        return self.calibration.contaminated

    def _contact_events(self, t: float, events: list[Event]) -> None:
        was = self._was_contact
        now = self.gate.in_contact
        if now and not was:
            events.append(Event(t, EventKind.CONTACT_START, {"arm": self.arm}))
        elif was and not now:
            events.append(Event(t, EventKind.CONTACT_END, {"arm": self.arm}))
        self._was_contact = now

    def _offer(self, t: float, out, msg: JointSample, free: bool, events: list[Event],
               calibrating: bool = False, trainable: bool = True,
               contact_started: int = -1) -> None:
        if self.backend is None or out.window is None:
            return
        if not self.mechanism.may_offer(t, self._adapt_until, calibrating):
            return
        if self.mechanism.offers_everything or (calibrating and not self.calibration.refuses):
            now = Released(np.array([t]), out.window[None], out.step1_torque[None],
                           msg.effort[None])
            self.counters.offered += offer_rows(self.backend, now, self.on_offer)
            return
        weak = self.weak
        if not free:
            if weak is not None:
                weak.clear()
            self.counters.discarded_onsets += self.line.drop_onset(contact_started)
            return
        if weak is not None and not calibrating and t >= self._adapt_until and weak.update(
                t, msg.position, out.external_torque, self.gate.scale.std):
            trainable = False           # a weak contact's form: held back
            self.counters.held_back += 1
            if weak.onset is not None:
                self.counters.held_back += self.line.drop_since(
                    weak.onset - self.config.policy.onset_margin_s)
        if trainable:                   # a free but borderline sample is skipped, not trusted
            self.line.push(t, out.window, out.step1_torque, msg.effort)
        self.counters.offered += offer_rows(self.backend, self.line.release(t), self.on_offer)

    def _adapt(self, t: float) -> list[Event]:
        if self.backend is None:
            return []
        events = []
        if self.mechanism.reset_due(t, self.config.policy.reset_every_s):
            self.backend.reset(t)
            self.estimator.swap_correction(initial_corr(self.config.adaptation))
            self.model_version += 1
            events.append(Event(t, EventKind.MODEL, {"arm": self.arm, "version": self.model_version,
                                             "reset": True}))
        for result in self.backend.tick(t):
            events.extend(self.apply(result))
        errors = getattr(self.backend, "errors", None)
        while errors:
            events.append(Event(t, EventKind.ADAPTATION_ERROR, {"arm": self.arm, "error": errors.pop(0),
                                                        "serving_version": self.model_version}))
        return events

    def refuse_setup(self, t: float, reason: str) -> Event:
        """Count and describe a set-up change notice that could not be read."""
        return self._error(t, "setup", reason)

    def setup_change(self, t: float | None = None, detail: dict[str, Any] | None = None
                     ) -> list[Event]:
        """An announced set-up change at sample time ``t`` [s] (None: the last estimated
        sample's): adaptation gets eager as after a drift. ``detail["kind"]``
        (:data:`~wrenchd.models.adaptation.adapter.SETUP_KINDS`): ``"pressure"`` (default; the
        adapter carries its buffer over), ``"instrument"`` (a new payload: the adapter forgets
        the old instrument's samples, the delay line is dropped and the calibration runs again
        from the next sample, the instrument being out of tissue during a swap). ``detail``
        (JSON values) goes into the ``setup_change`` event. An unknown kind, a time that is not
        finite or more than ``validation.setup_ahead_s`` ahead is refused (error event)."""
        detail = dict(detail or {})
        last = self.line.last_t
        kind = detail.get("kind", "pressure")
        if kind not in SETUP_KINDS:
            return [self.refuse_setup(last if last is not None else 0.0,
                                      f"unknown set-up change kind {str(kind)[:24]!r}; one of "
                                      f"{', '.join(SETUP_KINDS)}")]
        if t is None:
            if last is None:
                return [self.refuse_setup(0.0, "a set-up change before the first sample "
                                               "needs its time")]
            t = last
        if not math.isfinite(t):
            return [self.refuse_setup(last if last is not None else 0.0,
                                      f"set-up change time {t!r} is not finite")]
        ahead = self.config.validation.setup_ahead_s
        if last is not None and t > last + ahead:
            return [self.refuse_setup(last, f"set-up change stamped {t:.3f} s, more than "
                                            f"{ahead:g} s after the arm's latest sample "
                                            f"({last:.3f} s): not the robot's clock?")]
        self.counters.setup_changes += 1
        self._adapt_until = t + self.config.adaptation.eager_s
        if self.backend is not None:
            self.backend.setup_change(t, kind)
        if kind == "instrument":
            self.line.clear()
            self.calibration.restart()          # the next sample starts a calibration
        else:                                   # the gate judges a contact then soon
            self.gate.announce(t)
        self._last_setup = {"t": t, **detail}
        return [Event(t, EventKind.SETUP_CHANGE, {"arm": self.arm, **detail,
                                          "carry_over": self.backend is not None
                                          and kind == "pressure"
                                          and self.config.adaptation.body_wall.enabled})]

    def apply(self, result: RoundResult) -> list[Event]:
        """Apply one round's outcome (swap the ``Corr`` if accepted); its events, stamped with
        the arm's sample time at which it is applied (the latest estimated sample's; the
        round's own ``t`` is the adaptation backend's clock, which for the daemon's worker is
        seconds since it started)."""
        self.counters.rounds += 1
        self.body_wall = list(result.body_wall)
        t = self.line.last_t if self.line.last_t is not None else result.t
        events = [Event(t, EventKind.ROUND, {"arm": self.arm, **{
            k: v for k, v in result.summary().items() if k != "t"}})]
        if result.accepted and result.state_dict is not None:
            # a reference swap: the worker sent the kernel ready to serve
            self.estimator.swap_correction_state(result.state_dict, result.kernel)
            self.counters.swaps += 1
            self.model_version = result.version
            self.model_validation = result.val_after
            events.append(Event(t, EventKind.MODEL, {
                "arm": self.arm, "version": result.version, "val_before": result.val_before,
                "val_after": result.val_after}))
        return events

    def status(self) -> dict[str, Any]:
        """JSON-able state: counters, gate, drift, model."""
        mean, std = self.gate.bounds()
        c = self.counters
        return {
            "arm": self.arm, "policy": self.policy, "calibrating": self.calibrating,
            "model": {"version": self.model_version, "validation": self.model_validation,
                      "mode": self.estimator.mode},
            "counters": {"received": c.received, "estimated": c.estimated, "errors": c.errors,
                         "error_kinds": dict(c.error_kinds), "gaps": c.gaps,
                         "jumps": c.jumps,
                         "dropped": c.dropped, "offered": c.offered,
                         "discarded_onsets": c.discarded_onsets, "held_back": c.held_back,
                         "drifts": c.drifts,
                         "setup_changes": c.setup_changes,
                         "rounds": c.rounds, "swaps": c.swaps,
                         "calibration_samples": c.calibration_samples,
                         "calibration_contact": c.calibration_contact},
            "calibration": {"guard": self.guard is not None,
                            "contaminated": self.calibration_contaminated,
                            **self.calibration.fit()},
            "gate": {"in_contact": self.gate.in_contact, "calibrated": self.gate.calibrated,
                     "contacts": self.gate.contacts,
                     "withheld_contacts": self.gate.withheld_contacts,
                     "mean": mean.tolist(), "std": std.tolist(),
                     # per reversal bin (the steady bin last), each joint's spread factor
                     "reversal_factors": (None if self.gate.reversal is None
                                          else self.gate.reversal.factors().tolist())},
            "drift": {"detections": self.drift.detections,
                      "last_t": self.drift.last_detection_t},
            "setup": self._last_setup,
            "body_wall": {"stiffness_n_per_m": self.body_wall},
        }

    def close(self) -> None:
        if self.backend is not None:
            self.backend.close()
