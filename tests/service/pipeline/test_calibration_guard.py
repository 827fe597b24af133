"""The calibration guard: contacts during the calibration never train, and a step-1 model that
does not fit the arm is reported, not called contact.

Short real replays of the simulator (24 s, calibration 20 s, the pipeline's default gate and
guard). ``trocar-contact`` seed 3 touches the handle from 1.6 s to 4.9 s and from 13.2 s to
17.2 s (36 % of its first 20 s): without the guard, every one of those samples trained; seeds
4-8 touch it 8-33 % of the time, from their first seconds on. ``insufflation-change`` seed 3
is contact-free for 60 s: the guard must leave most of its calibration to the correction net
and raise no alarm. The shipped ``base`` step 1 was trained without the trocar's seal: on
these sessions it is the wrong model (its insertion residual is about 30 x its held-out RMSE).

The guard's own tests drive it with synthetic residuals: smooth noise (the step-1 residual
follows the trajectory, it is not white) in units of the ``seal`` model's held-out RMSE.
"""

from __future__ import annotations

from functools import lru_cache

import doctest

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.models.errors import ConfigError
from wrenchd.models.gate import FreeMotionGate, GateConfig
from wrenchd.service.pipeline import ArmPipeline, CalibrationGuardConfig, PipelineConfig
from wrenchd.service.pipeline import calibration
from wrenchd.service.pipeline.calibration import CalibrationGuard, SortedWindow
from wrenchd.service.replay.loop import replay

DURATION_S, CALIBRATION_S = 24.0, 20.0
HELD_OUT = np.array([0.14, 0.09, 0.09, 0.001, 0.0024, 0.0023])  # seal's validation RMSE


@lru_cache(maxsize=None)
def _session(scenario: str, seed: int):
    return run_scenario(scenario, DURATION_S, seed)


@lru_cache(maxsize=None)
def _replay(scenario: str, seed: int, action: str | None = "default", model: str = "seal"):
    """Replay with the guard's ``action`` (None: no guard; "default": the default guard)."""
    guard = (CalibrationGuardConfig(enabled=False) if action is None
             else CalibrationGuardConfig() if action == "default"
             else CalibrationGuardConfig(action=action))
    config = PipelineConfig(calibration_s=CALIBRATION_S, calibration_guard=guard)
    return replay(_session(scenario, seed), load_pretrained(model), config,
                  adaptation="inline")


def _offered_in_contact(scenario: str, seed: int, action: str | None = "default",
                        model: str = "seal") -> tuple[int, int]:
    """(offered samples truly in contact, of them during the calibration)."""
    session, result = _session(scenario, seed), _replay(scenario, seed, action, model)
    rows = np.searchsorted(session.joint_states.t, result.offered_t)
    bad = session.truth.in_contact[rows]
    return int(bad.sum()), int(bad[result.offered_t < CALIBRATION_S].sum())


def test_without_the_guard_contact_trains_during_calibration():
    # the failure the guard is for, on this very session (so the next test can fail)
    total, calibrating = _offered_in_contact("trocar-contact", 3, None)
    assert calibrating > 500


def test_warning_guard_changes_nothing_it_only_counts():
    warned, plain = _replay("trocar-contact", 3, "warn"), _replay("trocar-contact", 3, None)
    np.testing.assert_array_equal(warned.offered_t, plain.offered_t)
    np.testing.assert_array_equal(warned.wrench, plain.wrench)
    np.testing.assert_array_equal(warned.free, plain.free)
    assert plain.status["counters"]["calibration_contact"] == 0
    assert warned.status["counters"]["calibration_contact"] > 0


def test_the_guard_refuses_by_default():
    assert CalibrationGuardConfig().action == "refuse"
    assert ArmPipeline("PSM1", load_pretrained("seal"), PipelineConfig()).guard.refuses


@pytest.mark.parametrize("seed", [3, 4, 5, 6, 7, 8])
def test_calibration_with_contact_offers_no_contact_sample(seed):
    assert _offered_in_contact("trocar-contact", seed) == (0, 0)
    result = _replay("trocar-contact", seed)
    # it still calibrates: measured 765-2883 of its 4000 samples offered (the contact time
    # and the delay line's margins around each contact besides)
    assert (result.offered_t < CALIBRATION_S).sum() > 0.05 * CALIBRATION_S * 200
    assert "model_mismatch" not in [e.kind for e in result.events]   # the model fits


def test_refusing_guard_keeps_calibration_contacts_out_of_training():
    total, calibrating = _offered_in_contact("trocar-contact", 3, "refuse")
    assert calibrating == 0
    result = _replay("trocar-contact", 3, "refuse")
    assert len(result.offered_t[result.offered_t < CALIBRATION_S]) > 1000   # still calibrates
    counters = result.status["counters"]
    # the guard called contact at least the contact time (7.3 s of 20 s at 200 Hz)
    assert counters["calibration_samples"] == int(CALIBRATION_S * 200)
    assert counters["calibration_contact"] > 0.3 * counters["calibration_samples"]


@pytest.mark.parametrize("action", ["warn", "refuse"])
def test_contaminated_calibration_is_reported(action):
    result = _replay("trocar-contact", 3, action)
    kinds = [e.kind for e in result.events]
    assert "calibration_contaminated" in kinds
    event = next(e for e in result.events if e.kind == "calibration_contaminated")
    assert event.t == pytest.approx(CALIBRATION_S, abs=0.01)
    assert event.detail["fraction"] > 0.3
    calibration = result.status["calibration"]
    assert calibration["guard"] and calibration["contaminated"]
    assert not calibration["model_mismatch"]             # contact is no misfit


def test_contact_free_calibration_is_left_to_train():
    result = _replay("insufflation-change", 3)
    kinds = [e.kind for e in result.events]
    assert "calibration_contaminated" not in kinds and "model_mismatch" not in kinds
    calibration = result.status["calibration"]
    assert calibration["guard"] and not calibration["contaminated"]
    assert not calibration["model_mismatch"] and 0.5 < calibration["fit_ratio"] < 5.0
    calibrating = result.offered_t < CALIBRATION_S
    # measured 0.58 of a contact-free 20 s calibration trains (the delay line's margins
    # around what the guard calls contact besides)
    assert calibrating.sum() > 0.4 * CALIBRATION_S * 200


def test_wrong_step1_model_is_reported_not_called_contact():
    result = _replay("insufflation-change", 3, model="base")
    events = [e for e in result.events if e.kind == "model_mismatch"]
    assert len(events) == 1                               # once per calibration
    event = events[0]
    # judged from 5 s on; the seal's misfit is on the insertion joint
    assert 5.0 <= event.t < 6.5 and event.detail["joint"] == 2
    assert event.detail["fit_ratio"] > event.detail["threshold"] == 15.0
    calibration = result.status["calibration"]
    assert calibration["model_mismatch"] and calibration["fit_ratio"] > 15.0
    calibrated = next(e for e in result.events if e.kind == "calibrated")
    assert calibrated.detail["model_mismatch"]
    counters = result.status["counters"]
    # not everything is contact: measured 1091 of 4000 (all before the 5 s verdict)
    assert counters["calibration_contact"] < 0.35 * counters["calibration_samples"]
    assert (result.offered_t < CALIBRATION_S).sum() > 0.4 * CALIBRATION_S * 200


def test_wrong_step1_model_still_keeps_contact_out():
    # the misfit joint follows its own level; the others still see the contacts
    assert _offered_in_contact("trocar-contact", 3, model="base") == (0, 0)
    assert _replay("trocar-contact", 3, model="base").status["calibration"]["model_mismatch"]


def _guard(**config) -> CalibrationGuard:
    return CalibrationGuard(FreeMotionGate(GateConfig()), CalibrationGuardConfig(**config),
                            HELD_OUT)


def _smooth(rng: np.random.Generator, n: int, width: int = 100) -> np.ndarray:
    """(n, 6) zero-mean, unit-RMS noise, a moving sum of ``width`` samples (0.5 s)."""
    c = np.cumsum(rng.normal(size=(n + width, 6)), axis=0)
    x = c[width:] - c[:-width]
    return x / x.std(axis=0)


def _free_flags(guard: CalibrationGuard, residual: np.ndarray) -> np.ndarray:
    return np.array([guard.judge(i, i / 200.0, r).free for i, r in enumerate(residual)])


def test_robust_level_lets_a_set_up_the_validation_never_saw_calibrate():
    # free motion at 3 x the held-out RMSE on every joint (a set-up adds residual)
    residual = 3.0 * HELD_OUT * _smooth(np.random.default_rng(0), 4000)
    robust = _guard()
    free = _free_flags(robust, residual)
    assert free[2000:].mean() > 0.95                 # measured 1.0 over the last 10 s
    seeded_only = _free_flags(_guard(robust_factor=1e-3), residual)
    assert seeded_only[2000:].mean() < 0.5           # measured 0.0: all contact
    assert not robust.mismatch and robust.ratio == pytest.approx(3.0, rel=0.25)


def test_the_window_holds_a_sample_per_5_ms_whatever_the_rate():
    """At 1 kHz the robust level is taken over one sample in five (the quantiles of a
    minute of samples would stall estimation once a second); at 200 Hz, with jitter, over
    every one: the same window either way."""
    residual = 3.0 * HELD_OUT * _smooth(np.random.default_rng(2), 5000, width=500)
    fast = _guard()
    for i, r in enumerate(residual):
        fast.judge(i, i / 1000.0, r)
    assert fast._n == 1000
    jitter = np.random.default_rng(3).uniform(-2e-4, 2e-4, 1000)
    slow = _guard()
    for i in range(1000):
        slow.judge(i, i / 200.0 + jitter[i], residual[5 * i])
    every_fifth = np.abs(residual[::5])
    np.testing.assert_array_equal(fast._window[:fast._n], every_fifth)
    np.testing.assert_array_equal(slow._window[:slow._n], every_fifth)


def test_misfit_joint_is_a_mismatch_and_follows_its_own_level():
    rng = np.random.default_rng(1)
    n = 4000
    residual = HELD_OUT * _smooth(rng, n)
    # a seal the model does not know: +-2 N along the shaft, 20 x its held-out RMSE
    residual[:, 2] += 2.0 * np.sign(np.sin(2 * np.pi * 0.2 * np.arange(n) / 200.0))
    guard = _guard()
    free = _free_flags(guard, residual.copy())
    assert guard.mismatch and int(np.argmax(guard.ratios)) == 2
    assert guard.ratios[2] > 15.0 and guard.ratios[[0, 1, 3, 4, 5]].max() < 2.0
    assert free[:1000].mean() < 0.05 and free[2000:].mean() > 0.95
    # without the verdict the guard calls everything contact
    starved = _free_flags(_guard(mismatch_ratio=1e6, follow_ratio=1e6), residual.copy())
    assert starved[2000:].mean() < 0.05
    # a contact on the shoulder joints is still seen in the mismatched window
    contact = residual.copy()
    contact[2000:2600, 0] += 2.0
    contact[2000:2600, 1] += 1.0
    assert _free_flags(_guard(), contact)[2020:2600].mean() < 0.05
    guard.start()                                    # a new calibration: a new verdict
    assert not guard.mismatch and guard.ratios is None and guard.ratio is None


def test_a_joint_the_model_does_not_fit_follows_its_level_without_a_mismatch():
    """Unseen motion or a set-up the step-1 model never saw: 10 x the held-out RMSE on the
    wrist, under mismatch_ratio, over follow_ratio. The guard follows that level instead of
    keeping the residual step 2 must learn from it; a contact on the shoulder is still seen."""
    rng = np.random.default_rng(4)
    n = 4000
    residual = HELD_OUT * _smooth(rng, n)
    residual[:, 3:] *= 10.0
    guard = _guard()
    free = _free_flags(guard, residual.copy())
    assert not guard.mismatch and 3.0 < guard.ratios[3:].min() and guard.ratio < 15.0
    assert free[2000:].mean() > 0.95
    bounded = _free_flags(_guard(follow_ratio=1e6), residual.copy())
    assert bounded[2000:].mean() < 0.5
    contact = residual.copy()
    contact[2000:2600, 0] += 2.0
    contact[2000:2600, 1] += 1.0
    assert _free_flags(_guard(), contact)[2020:2600].mean() < 0.05


def test_guard_scale_comes_from_the_step1_checkpoint():
    seal = load_pretrained("seal")
    assert len(seal.validation_rmse) == 6
    assert ArmPipeline("PSM1", seal, PipelineConfig()).guard is not None
    off = PipelineConfig(calibration_guard=CalibrationGuardConfig(enabled=False))
    assert ArmPipeline("PSM1", seal, off).guard is None
    assert ArmPipeline("PSM1", seal, PipelineConfig(calibration_s=0)).guard is None
    with pytest.raises(ConfigError):
        ArmPipeline("PSM1", seal, PipelineConfig(
            calibration_guard=CalibrationGuardConfig(residual_scale=(0.1, 0.1))))


def test_a_new_calibration_judges_the_fit_afresh():
    # an instrument notice starts a new calibration: a fresh window and a new verdict
    session = run_scenario("insufflation-change", 20.0, 3)
    config = PipelineConfig(calibration_s=8.0)
    result = replay(session, load_pretrained("base"), config, adaptation="inline",
                    setup_changes=[(10.0, {"kind": "instrument"})])
    mismatch = [e.t for e in result.events if e.kind == "model_mismatch"]
    starts = [e.t for e in result.events if e.kind == "calibrating"]
    assert len(starts) == 2 and len(mismatch) == 2
    for start, said in zip(starts, mismatch):
        assert 5.0 <= said - start < 6.5


def test_a_calibration_shorter_than_the_delay_line_still_trains():
    # the guard goes on judging through the gate's warm-up after the calibration, so the
    # calibration's samples wait out their delay instead of being dropped with the line
    session = run_scenario("insufflation-change", 8.0, 3)            # contact-free
    result = replay(session, load_pretrained("seal"), PipelineConfig(calibration_s=2.0),
                    adaptation="inline")
    calibration = result.offered_t[result.offered_t < 2.0]
    assert len(calibration) > 0.5 * 2.0 * 200                        # measured 286 of 400
    assert result.status["calibration"]["fit_ratio"] is not None     # judged after it


def _warmup_run(judge_warmup: bool, raw_load_n: float = 0.0,
                decisions: list | None = None, contact_n: float = 3.0,
                confirm: bool = False) -> tuple[list[bool], list]:
    """A calibration of 10 s at 200 Hz with a trocar's 2 N swinging in the step-1 residual
    on insertion (the correction net takes it out: the corrected residual is noise), then a
    ``contact_n`` insertion contact 1 s into the gate's 5 s warm-up (``raw_load_n``: a load
    in the step-1 residual alone, which step 2 takes out, from the contact's start to 13.5 s;
    ``confirm``: ``calibration_guard.warmup_confirm``). The verdicts on the contact's samples
    and the calibrated event; ``decisions``: every ``(t, decision)`` from 11 s on."""
    from types import SimpleNamespace

    from wrenchd.service.pipeline.calibration import CalibrationPhase
    from wrenchd.service.pipeline.delay_line import DelayLine
    from wrenchd.service.pipeline.records import Counters

    config = PipelineConfig(calibration_s=10.0, calibration_guard=CalibrationGuardConfig(
        judge_warmup=judge_warmup, warmup_confirm=confirm))
    gate = FreeMotionGate(config.gate)
    heldout = np.array([0.05, 0.05, 0.2, 0.005, 0.005, 0.005])
    phase = CalibrationPhase("PSM1", config, SimpleNamespace(validation_rmse=heldout), gate,
                             Counters())
    line = DelayLine(config.policy)
    rng = np.random.default_rng(0)
    verdicts, events = [], []
    for k in range(int((15.0 if decisions is not None else 13.0) * 200)):
        t = k / 200.0
        noise = rng.normal(0.0, 1.0, 6) * heldout
        trocar = np.zeros(6)
        trocar[2] = 2.0 * np.sin(2 * np.pi * 0.7 * t) + 0.5 * np.sign(np.sin(2 * np.pi * 1.3 * t))
        contact = np.zeros(6)
        if 11.0 <= t < 12.0:
            contact[2] = contact_n
        external = noise + contact                   # what step 2 leaves: noise and contact
        out = SimpleNamespace(step1_torque=np.zeros(6), external_torque=external)
        effort = trocar + external                   # the step-1 residual carries the trocar
        if 11.0 <= t < 13.5:
            effort[2] += raw_load_n
        warming = not gate.calibrated
        decision = gate.update(k, t, external)
        decision, calibrating, _ = phase.overrule(k, t, out, effort, decision, warming, events,
                                                  None, 0, line)
        if 11.0 <= t < 12.0:
            verdicts.append(decision.free)
        if decisions is not None and t >= 11.0:
            decisions.append((t, decision))
    return verdicts, [e for e in events if e.kind == "calibrated"]


def test_the_gates_warm_up_after_the_calibration_is_judged_on_the_corrected_residual():
    """Judged on the raw step-1 residual, the guard cannot tell a 3 N insertion contact from
    the trocar's swing it was seeded and widened on; a second gate on the corrected residual,
    started from twice the calibration's own level (``judge_warmup``), finds it within 0.2 s
    (measured: 191 of its 200 samples flagged, from the 10th; the guard alone, none)."""
    judged, (calibrated,) = _warmup_run(True)
    raw, _ = _warmup_run(False)
    assert calibrated.detail["gate_prior_samples"] > 1000     # a prior to start from
    assert not any(judged[40:]) and judged.index(False) < 40
    assert sum(not free for free in raw) < 0.5 * sum(not free for free in judged)


def test_a_contact_the_corrected_residual_has_ended_is_published_free_while_the_guard_holds():
    """The guard, on the raw step-1 residual, holds a contact for as long as a load that step
    2 takes out lasts (here 20 N, over the guard's widened scale, to 13.5 s); once the second
    gate, on the corrected residual, has ended the 3 N contact it held too (12 s, plus its
    exit), the rest is published free, and none of it trains until the guard has ended it
    as well (measured: published free from 12.5 s, the guard's end at 14.0 s)."""
    decisions: list = []
    _warmup_run(True, raw_load_n=20.0, decisions=decisions)
    contact = [t for t, d in decisions if not d.free]
    assert contact and 11.0 < contact[0] < 11.1 and 12.0 < contact[-1] < 13.0
    held = [(t, d) for t, d in decisions if contact[-1] < t < 13.5]
    assert held and all(d.free and d.contact_started >= 0 and not d.trainable for _, d in held)
    assert any(d.trainable for t, d in decisions if t >= 14.5)    # after the guard's end


@pytest.mark.parametrize("confirm", [True, False])
def test_what_only_the_raw_residual_shows_in_the_warm_up_is_published_once_confirmed(confirm):
    """No contact, but a 20 N load in the step-1 residual alone from 11 s to 13.5 s (what a
    reversal the correction net has learnt does to the raw residual): the guard calls it
    contact, the second gate, on the corrected residual, does not. With ``warmup_confirm``
    it is published free; either way none of it trains."""
    decisions: list = []
    _warmup_run(True, raw_load_n=20.0, decisions=decisions, contact_n=0.0, confirm=confirm)
    held = [d for t, d in decisions if 11.1 < t < 13.5]
    assert held and all(d.contact_started >= 0 and not d.trainable for d in held)
    published = [d for d in held if not d.free]
    assert (not published) if confirm else len(published) == len(held)


def test_doctest():
    assert doctest.testmod(calibration).failed == 0


@pytest.mark.parametrize("ties", [False, True])
def test_the_sorted_window_gives_numpys_quantiles_exactly(ties):
    """Grown in steps of any size, with ties or without: the numbers np.quantile gives (the
    guard's verdicts were made with those; a replay's outcomes must not move)."""
    rng = np.random.default_rng(7)
    for _ in range(40):
        rows = np.abs(rng.normal(size=(3000, 6))) * rng.uniform(0.01, 10.0, 6)
        if ties:
            rows = np.round(rows, 1)
        window, n = SortedWindow(), 0
        while n < len(rows):
            n = min(len(rows), n + int(rng.integers(1, 700)))
            got = window.quantiles(rows[:n], (0.25, 0.5))
            assert np.array_equal(got, np.quantile(rows[:n], (0.25, 0.5), axis=0))
    with pytest.raises(ValueError, match="shrank"):
        window.quantiles(rows[:10], (0.5,))
