"""One arm's pipeline: validation, gaps, swaps that keep the state, contact kept out of training."""

import numpy as np
import pytest

from wrenchd.models.series import JointSample
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.service.pipeline import ArmPipeline, PipelineConfig, PolicyConfig


#: a position step no arm makes in one sample [rad, rad, m, rad, rad, rad]
SPLICE = np.array([0.0, 0.4, 0.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def seal():
    return load_pretrained("seal")


@pytest.fixture(scope="module")
def trocar():
    return run_scenario("trocar", 6.0, 4).joint_states


def msg(js, i, t=None, **change):
    fields = {"position": js.position[i].copy(), "velocity": js.velocity[i].copy(),
              "effort": js.effort[i].copy()}
    fields.update(change)
    stamp = int(round((js.t[i] if t is None else t) * 1e9))
    return JointSample(stamp, "", (), **fields)


def test_bad_samples_are_counted_events_and_never_estimated(seal, trocar):
    p = ArmPipeline("PSM1", seal, PipelineConfig(policy=PolicyConfig(name="frozen")))
    for i in range(20):
        est, _ = p.process(msg(trocar, i))
        assert est is not None
    nan_velocity = trocar.velocity[20].copy()
    nan_velocity[2] = np.nan
    bad = [
        (msg(trocar, 20, velocity=nan_velocity), "invalid"),
        (msg(trocar, 20, effort=np.full(6, 1e6)), "invalid"),
        (JointSample(int(trocar.t[20] * 1e9), "", (), np.zeros(7), np.zeros(7), np.zeros(7)),
         "invalid"),
        (msg(trocar, 19), "duplicate"),
        (msg(trocar, 10), "time_backwards"),
    ]
    for m, kind in bad:
        est, events = p.process(m)
        assert est is None
        assert [(e.kind, e.detail["error"]) for e in events] == [("error", kind)]
    assert p.counters.errors == len(bad)
    assert p.counters.error_kinds == {"invalid": 3, "duplicate": 1, "time_backwards": 1}
    est, _ = p.process(msg(trocar, 20))                 # the stream goes on
    assert est is not None and not est.restarted


def test_a_position_jump_restarts_the_state_as_a_jump_event(seal, trocar):
    p = ArmPipeline("PSM1", seal, PipelineConfig(policy=PolicyConfig(name="frozen")))
    for i in range(50):
        est, events = p.process(msg(trocar, i))
        assert not events or i == 0
    spliced = trocar.position[50].copy()
    spliced[1] += 0.4                                   # 0.4 rad in one sample: a splice
    est, events = p.process(msg(trocar, 50, position=spliced))
    assert est.restarted and [e.kind for e in events] == ["jump"]
    est, events = p.process(msg(trocar, 51, position=trocar.position[51] + spliced
                                - trocar.position[50]))
    assert not est.restarted and not events
    assert p.status()["counters"]["jumps"] == 1 and p.status()["counters"]["gaps"] == 0


def test_a_gap_restarts_the_recurrent_state(seal, trocar):
    p = ArmPipeline("PSM1", seal, PipelineConfig(policy=PolicyConfig(name="frozen")))
    for i in range(50):
        p.process(msg(trocar, i))
    est, events = p.process(msg(trocar, 200))           # 0.75 s later
    assert est.restarted and [e.kind for e in events] == ["gap"]
    assert p.counters.gaps == 1


def test_a_model_swap_keeps_the_recurrent_state(seal, trocar):
    from wrenchd.service.pipeline import initial_corr

    p = ArmPipeline("PSM1", seal, PipelineConfig(policy=PolicyConfig(name="frozen")))
    ref = ArmPipeline("PSM1", seal, PipelineConfig(policy=PolicyConfig(name="frozen")))
    for i in range(100):
        a, _ = p.process(msg(trocar, i))
        b, _ = ref.process(msg(trocar, i))
        if i == 50:                                      # an identical (zero) Corr swapped in
            p.estimator.swap_correction(initial_corr(p.config.adaptation))
        np.testing.assert_allclose(a.wrench, b.wrench, rtol=1e-9, atol=1e-9)
        assert a.restarted == b.restarted == (i == 0)


def test_contact_never_reaches_training_on_a_contact_session(seal):
    """The gated policy on trocar-contact after its calibration: the training offers hold no
    sample that the simulator labels as in contact, on this session."""
    session = run_scenario("trocar-contact", 75.0, 6, contact_free_s=25.0)
    js, truth = session.joint_states, session.truth
    cfg = PipelineConfig(calibration_s=20.0)
    p = ArmPipeline("PSM1", seal, cfg)
    offered: list[float] = []
    p.on_offer = lambda ts: offered.extend(ts.tolist())
    flags = np.zeros(len(js), bool)
    calibrated = []
    for i in range(len(js)):
        est, events = p.process(msg(js, i))
        flags[i] = est.free
        calibrated += [e for e in events if e.kind == "calibrated"]
    # the gate's warm-up after the calibration is bounded by the guard's free samples of its
    # last gate_prior_s (30 s: the whole 20 s calibration here, less what the guard refused)
    assert len(calibrated) == 1
    assert 3000 < calibrated[0].detail["gate_prior_samples"] <= 4000
    idx = np.searchsorted(js.t, offered)
    assert truth.in_contact[js.t > 25.0].sum() > 1000    # the session has contacts to refuse
    # measured 4374 (2767 of the calibration's 4000: the guard's refusals and the delay
    # line's margins around them); 4884 with the gate's warm-up unbounded
    # (calibration_guard.gate_prior_s = 0), its scale wider and fewer contacts found
    assert len(offered) > 4000
    assert not truth.in_contact[idx].any()
    # the gate sees strong contacts (weak, lateral ones at shallow insertion can sit under its
    # bound: their joint torques are as small as the free-motion residual)
    strong = truth.in_contact & (np.linalg.norm(truth.external_wrench[:, :3], axis=1) > 3.0)
    assert strong.sum() > 100 and (~flags[strong]).mean() > 0.95
    assert p.counters.discarded_onsets > 0               # onsets were dropped from the line


def test_a_backlog_processed_at_once_gives_what_one_by_one_gives(seal, trocar):
    """process_many (the daemon's backlog path) against process, sample by sample, on a
    stream with a NaN, a duplicate, a stamp going backwards and a gap: the same refusals and
    events, estimates equal to float32 rounding, the same gate verdicts and restarts."""
    stream = [msg(trocar, i) for i in range(400)]
    stream[30] = msg(trocar, 30, velocity=np.full(6, np.nan))
    stream[60] = msg(trocar, 59)                                  # duplicate
    stream[90] = msg(trocar, 80)                                  # backwards
    stream[200:] = [msg(trocar, i, t=trocar.t[i] + 0.3) for i in range(200, 400)]   # a gap
    config = PipelineConfig(policy=PolicyConfig(name="frozen"), calibration_s=0.5)
    one = ArmPipeline("PSM1", seal, config)
    many = ArmPipeline("PSM1", seal, config)
    ref = [one.process(m) for m in stream]
    got, rng, i = [], np.random.default_rng(1), 0
    while i < len(stream):
        k = int(rng.integers(1, 30))
        got += many.process_many(stream[i:i + k])
        i += k
    assert len(got) == len(ref)
    batched = 0
    for (a, ev_a), (b, ev_b) in zip(ref, got):
        assert [e.kind for e in ev_a] == [e.kind for e in ev_b]
        assert (a is None) == (b is None)
        if a is not None:
            np.testing.assert_allclose(b.wrench, a.wrench, rtol=1e-4, atol=1e-5)
            np.testing.assert_allclose(b.external_torque, a.external_torque, atol=1e-5)
            assert (a.free, a.restarted, a.index) == (b.free, b.restarted, b.index)
            batched += 1
    assert batched == 400 - 3 and one.counters == many.counters


def test_arms_stepped_together_give_what_each_alone_gives(seal):
    """process_many_joint (three arms of one daemon sharing the step-1 kernel, their
    recurrences as one batch, each arm with its own number of queued samples, none
    included) against each arm's own process, sample by sample: equal to float32 rounding,
    same refusals, events, restarts and gate verdicts (arm 1 jumps, arm 2 gets a NaN and a
    gap, arm 3 starts late)."""
    sessions = [run_scenario("trocar", 3.0, s).joint_states for s in (4, 5, 6)]
    streams = [[msg(js, i) for i in range(len(js))] for js in sessions]
    streams[1][40] = msg(sessions[1], 40, velocity=np.full(6, np.nan))
    streams[1][300:] = [msg(sessions[1], i, t=sessions[1].t[i] + 0.2)
                        for i in range(300, len(sessions[1]))]
    streams[2] = streams[2][100:]
    streams[0][200:] = [msg(sessions[0], i, position=sessions[0].position[i] + SPLICE)
                          for i in range(200, len(sessions[0]))]
    config = PipelineConfig(policy=PolicyConfig(name="frozen"), calibration_s=0.5)
    alone = [ArmPipeline(f"PSM{k}", seal, config) for k in (1, 2, 3)]
    joint = [ArmPipeline(f"PSM{k}", seal, config) for k in (1, 2, 3)]
    for p in joint[1:]:
        p.estimator.share_step1(joint[0].estimator)
    ref = [[p.process(m) for m in stream] for p, stream in zip(alone, streams)]
    got: list[list] = [[], [], []]
    pos, rng = [0, 0, 0], np.random.default_rng(2)
    while any(pos[a] < len(streams[a]) for a in range(3)):
        chunks = []
        for a in range(3):
            k = int(rng.integers(0, 9))
            chunks.append(streams[a][pos[a]:pos[a] + k])
            pos[a] += len(chunks[-1])
        for a, res in enumerate(ArmPipeline.process_many_joint(joint, chunks)):
            got[a] += res
    compared = 0
    for r_arm, g_arm in zip(ref, got):
        assert len(r_arm) == len(g_arm)
        for (a, ev_a), (b, ev_b) in zip(r_arm, g_arm):
            assert [e.kind for e in ev_a] == [e.kind for e in ev_b]
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_allclose(b.wrench, a.wrench, rtol=1e-4, atol=1e-5)
                assert (a.free, a.restarted, a.index) == (b.free, b.restarted, b.index)
                compared += 1
    assert compared == sum(len(s) for s in streams) - 1
    assert [p.counters for p in alone] == [p.counters for p in joint]


def test_arms_stepped_together_one_sample_each(seal):
    """The daemon's usual case, each arm's samples handled as they come (one per arm per
    pass, the streams checked and stepped as one batch): what each arm's own process gives,
    to float32 rounding, restarts after a gap and a jump and a refused NaN sample included."""
    sessions = [run_scenario("trocar", 1.0, s).joint_states for s in (4, 5, 6)]
    streams = [[msg(js, i) for i in range(len(js))] for js in sessions]
    streams[1][40] = msg(sessions[1], 40, velocity=np.full(6, np.nan))
    streams[2][120:] = [msg(sessions[2], i, t=sessions[2].t[i] + 0.2)
                        for i in range(120, len(sessions[2]))]
    streams[0][150:] = [msg(sessions[0], i, position=sessions[0].position[i] + SPLICE)
                          for i in range(150, len(sessions[0]))]
    config = PipelineConfig(policy=PolicyConfig(name="frozen"), calibration_s=0.5)
    alone = [ArmPipeline(f"PSM{k}", seal, config) for k in (1, 2, 3)]
    joint = [ArmPipeline(f"PSM{k}", seal, config) for k in (1, 2, 3)]
    for p in joint[1:]:
        p.estimator.share_step1(joint[0].estimator)
    n = min(len(s) for s in streams)
    restarts = 0
    for i in range(n):
        ref = [p.process(stream[i]) for p, stream in zip(alone, streams)]
        got = [res[0] for res in ArmPipeline.process_many_joint(
            joint, [[stream[i]] for stream in streams])]
        for (a, ev_a), (b, ev_b) in zip(ref, got):
            assert [e.kind for e in ev_a] == [e.kind for e in ev_b]
            assert (a is None) == (b is None)
            if a is not None:
                np.testing.assert_allclose(b.wrench, a.wrench, rtol=1e-4, atol=1e-5)
                np.testing.assert_allclose(b.predicted_torque, a.predicted_torque,
                                           rtol=1e-4, atol=1e-5)
                assert (a.free, a.restarted, a.index) == (b.free, b.restarted, b.index)
                restarts += a.restarted
    assert restarts == 5         # each arm's first sample, arm 3 after its gap, arm 1's jump
    assert [p.counters for p in alone] == [p.counters for p in joint]


def test_samples_waiting_from_before_a_contacts_onset_margin_are_offered_after_it(seal):
    """The delay line at a contact: samples queued within ``onset_margin_s`` of the gate's
    onset are dropped, older ones wait through the contact and are offered after it (the
    sample that ends a contact carries its onset; read as "onset unknown", it once dropped the
    whole line at every contact's end)."""
    js = run_scenario("trocar", 20.0, 4).joint_states
    effort = js.effort.copy()
    push = (js.t >= 12.0) & (js.t < 14.0)
    effort[push, 2] += 3.0                         # 3 N along the shaft: 30x the gate's floor
    cfg = PipelineConfig(calibration_s=0.0,
                         policy=PolicyConfig(release_delay_s=2.5, onset_margin_s=0.5))
    p = ArmPipeline("PSM1", seal, cfg)
    offered: list[float] = []
    p.on_offer = lambda ts: offered.extend(ts.tolist())
    free = np.array([p.process(msg(js, i, effort=effort[i]))[0].free for i in range(len(js))])
    onset = js.t[int(np.argmax(~free & (js.t > 10.0)))]
    assert 12.0 <= onset < 12.2 and not free[push][20:].any()   # found within ~10 samples
    offered = np.asarray(offered)
    line = (js.t >= onset - 2.45) & (js.t < onset - 0.55)     # waited past the margin
    assert np.isin(js.t[line], offered).mean() > 0.5      # (borderline samples never wait)
    margin = (js.t >= onset - 0.45) & (js.t < 14.0)
    assert not np.isin(js.t[margin], offered).any()
    assert p.counters.discarded_onsets < 0.6 * 200          # ~0.5 s at 200 Hz dropped


def test_the_gates_last_warm_up_sample_is_the_guards_to_judge(seal):
    """The sample that ends the gate's warm-up after the calibration is still a warm-up's
    (the gate calls it nothing): the calibration guard judges it like the ones before (taken
    as the gate's verdict, it was published as contact). The delay line is emptied there on
    purpose: its samples were judged by the guard alone, and a contact too weak for it may be
    in progress when the gate takes over."""
    js = run_scenario("insufflation-change", 12.0, 3).joint_states    # contact-free
    cfg = PipelineConfig(calibration_s=4.0)
    p = ArmPipeline("PSM1", seal, cfg)
    warmup = p.gate.config.warmup_samples
    flags, waiting = [], []
    for i in range(len(js)):
        est, _ = p.process(msg(js, i))
        flags.append(est.free)
        waiting.append(p.line.waiting)
    end = int(np.argmax(js.t >= 4.0)) + warmup              # the warm-up's last sample
    assert p.gate.calibrated
    assert all(flags[end - 5:end + 2])
    assert waiting[end - 1] > 0 and waiting[end] == 0


def test_a_released_contact_is_published_free_but_neither_offered_nor_a_drift_level(seal):
    """The gate's ``release_free``: once a push is over, its samples are published free within
    a few samples, while the contact goes on (``exit_s``) for training and drift: none of them
    is offered, and the drift detector does not see them."""
    js = run_scenario("trocar", 20.0, 4).joint_states
    effort = js.effort.copy()
    push = (js.t >= 12.0) & (js.t < 14.0)
    effort[push, 2] += 3.0
    cfg = PipelineConfig(calibration_s=0.0,
                         policy=PolicyConfig(release_delay_s=0.5, onset_margin_s=0.5))
    p = ArmPipeline("PSM1", seal, cfg)
    offered: list[float] = []
    p.on_offer = lambda ts: offered.extend(ts.tolist())
    levels: list[float] = []
    drift_update = p.drift.update
    p.drift.update = lambda t, r: levels.append(t) or drift_update(t, r)
    free, ends = [], []
    for i in range(len(js)):
        est, events = p.process(msg(js, i, effort=effort[i]))
        free.append(est.free)
        ends += [e.t for e in events if e.kind == "contact_end"]
    free = np.asarray(free)
    after = js.t >= 14.0
    released = js.t[after][int(np.argmax(free[after]))]
    assert released < 14.05                                  # published free at once
    end = min(e for e in ends if e > 14.0)
    assert end - released >= cfg.gate.exit_s - 0.01         # the contact ended exit_s later
    window = js.t[(js.t >= released) & (js.t < end)]
    assert not np.isin(window, np.asarray(offered)).any()
    assert not np.isin(window, np.asarray(levels)).any()
    assert np.isin(js.t[(js.t > end + 0.1) & (js.t < 19.0)], np.asarray(offered)).mean() > 0.5


def test_setup_change_makes_an_event_reaches_the_adapter_and_refuses_bad_times(seal, trocar):
    p = ArmPipeline("PSM1", seal, PipelineConfig())
    events = p.setup_change(None, {"note": "early"})
    assert [(e.kind, e.detail["error"]) for e in events] == [("error", "setup")]
    for i in range(50):
        p.process(msg(trocar, i))
    events = p.setup_change(None, {"pressure_mmhg": 20.0})
    assert [e.kind for e in events] == ["setup_change"]
    assert events[0].t == pytest.approx(trocar.t[49])
    assert events[0].detail == {"arm": "PSM1", "pressure_mmhg": 20.0, "carry_over": True}
    events = p.setup_change(float(trocar.t[30]))
    assert events[0].t == pytest.approx(trocar.t[30])
    assert p.backend.adapter.body_wall.starts == pytest.approx([trocar.t[30], trocar.t[49]])
    events = p.setup_change(float("inf"))
    assert [(e.kind, e.detail["error"]) for e in events] == [("error", "setup")]
    # a stamp from another clock (here the epoch's) is refused; 5 s ahead is still taken
    last = float(trocar.t[49])
    events = p.setup_change(1.7e9)
    assert [(e.kind, e.detail["error"]) for e in events] == [("error", "setup")]
    assert "more than 5 s after the arm's latest sample" in events[0].detail["reason"]
    assert p.backend.adapter.body_wall.starts == pytest.approx([trocar.t[30], last])
    assert [e.kind for e in p.setup_change(last + 5.0)] == ["setup_change"]
    assert p.gate.contact.announced_t == pytest.approx(last + 5.0)   # its check comes soon
    status = p.status()
    assert status["counters"]["setup_changes"] == 3
    assert status["counters"]["error_kinds"] == {"setup": 3}
    assert status["setup"]["t"] == pytest.approx(last + 5.0)
    frozen = ArmPipeline("PSM1", seal, PipelineConfig(policy=PolicyConfig(name="frozen")))
    frozen.process(msg(trocar, 0))
    assert frozen.setup_change(None)[0].detail["carry_over"] is False


def test_a_form_call_on_a_residual_that_ends_soon_after_is_withdrawn_with_an_event(seal):
    """Wrist torques no tip force makes, swinging with the pose, from 17 s: the gate takes
    them for a set-up change on their form. Where they stop 1.5 s later it withdraws that
    call (``gate_setup_withdrawn``); where they last, or with ``form_withdraw_s`` = 0, not."""
    from wrenchd.models.series import JointStates, Session
    from wrenchd.service.replay.loop import replay

    js = run_scenario("free-space-seal", 26.0, 3).joint_states

    def run(end_s: float, withdraw_s: float = 5.0) -> list[tuple[float, str]]:
        effort = js.effort.copy()
        m = (js.t >= 17.0) & (js.t < end_s)
        q = js.position[m]
        effort[m, 3:] += 0.03 * np.sin(q[:, 3:] * [3.0, 4.0, 5.0]
                                       + q[:, :3] * [2.0, 3.0, 20.0] + 1.0)
        session = Session(JointStates(js.t, js.position, js.velocity, effort))
        config = PipelineConfig(calibration_s=10.0)
        config = config.model_copy(update={"gate": config.gate.model_copy(
            update={"form_withdraw_s": withdraw_s})})
        result = replay(session, seal, config, policy="frozen")    # the gate alone judges
        return [(e.t, e.kind) for e in result.events
                if e.kind in ("gate_setup_change", "gate_setup_withdrawn")]

    called, withdrawn = run(21.5)
    assert called[1] == "gate_setup_change" and 17.0 < called[0] < 21.5
    assert withdrawn[1] == "gate_setup_withdrawn" and 21.5 < withdrawn[0] < 23.0
    assert [k for _, k in run(21.5, withdraw_s=0.0)] == ["gate_setup_change"]
    assert [k for _, k in run(26.0)] == ["gate_setup_change"]


def test_a_drift_raises_the_gate_s_enter_bounds_for_a_while(seal):
    """Free motion whose residual grows by 0.3 N m on joint 1 from 17 s (under the gate's
    bounds, so free): the drift detector fires, and the gate enters contacts only over
    higher bounds for ``gate.drift_caution_s`` from then."""
    js = run_scenario("free-space-seal", 30.0, 3).joint_states
    config = PipelineConfig(calibration_s=10.0, policy=PolicyConfig(name="frozen"))
    p = ArmPipeline("PSM1", seal, config)
    drifts = []
    for i in range(len(js.t)):
        effort = js.effort[i] + (0.3 * np.eye(6)[0] if js.t[i] >= 17.0 else 0.0)
        _, events = p.process(msg(js, i, effort=effort))
        drifts += [e.t for e in events if e.kind == "drift"]
    assert len(drifts) == 1 and 17.0 < drifts[0] < 25.0
    assert p.gate.caution_until == pytest.approx(drifts[0] + config.gate.drift_caution_s)
