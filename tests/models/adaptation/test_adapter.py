"""The lifelong adaptation core: validated swaps, versions, determinism, drift."""

import copy

import numpy as np
import torch

from wrenchd.models.estimator.corr_finetune import CorrFineTuner
from wrenchd.models.adaptation import AdaptationConfig, Adapter


def samples(n: int, seed: int = 0, gain: float = 0.3):
    """Windows (n, 10, 12), step-1 torques and measured torques = step 1 + a smooth effect."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (n, 12))
    windows = np.repeat(x[:, None, :], 10, axis=1)
    step1 = rng.normal(0, 0.5, (n, 6))
    effect = gain * np.tanh(x[:, :6] * 2.0)                 # what the Corr has to learn
    return windows, step1, step1 + effect + rng.normal(0, 0.01, (n, 6))


def run_rounds(adapter: Adapter, n_rounds: int):
    return [r for k in range(n_rounds) if (r := adapter.round(10.0 * k)) is not None]


def test_accepted_rounds_lower_the_held_out_error_and_number_versions():
    adapter = Adapter(AdaptationConfig(min_train_samples=200, round_steps=30, interval_s=1.0,
                                       skip_idle=False))
    adapter.add(*samples(3000))
    results = run_rounds(adapter, 12)
    accepted = [r for r in results if r.accepted]
    assert accepted, [r.summary() for r in results]
    for r in results:                                     # a swap never raises the error
        if r.accepted:
            assert r.val_after < r.val_before * (1 - adapter.config.min_improvement)
    assert [r.version for r in accepted] == list(range(1, len(accepted) + 1))
    assert accepted[-1].val_after < 0.5 * results[0].val_before


def test_a_diverging_candidate_is_never_swapped_in():
    adapter = Adapter(AdaptationConfig(min_train_samples=200, lr=50.0, round_steps=20,
                                       weight_decay=0.0, skip_idle=False))
    adapter.add(*samples(2000))
    results = run_rounds(adapter, 5)
    assert results and not any(r.accepted for r in results)
    assert adapter.version == 0
    x, s, y = adapter._split(np.stack(adapter.holdout))
    with torch.no_grad():                                 # the serving net still does nothing
        np.testing.assert_allclose(adapter.corr(x, s).numpy(), s.numpy(), atol=1e-6)


def test_a_round_with_nothing_new_is_skipped_unless_eager():
    adapter = Adapter(AdaptationConfig(min_train_samples=200, interval_s=1.0, skip_idle=True))
    adapter.add(*samples(1500))
    assert adapter.round(0.0) is not None
    assert adapter.round(1.0) is None and adapter.skipped == 1      # due, nothing offered
    adapter.add(*samples(10, seed=1))
    assert adapter.round(2.0) is not None and adapter.rounds == 2
    adapter.on_drift(3.0)                         # eager: a round even on the same buffer
    assert adapter.round(3.0) is not None and adapter.skipped == 1


def test_refused_rounds_back_off_the_interval_until_one_is_accepted():
    """Candidates that never improve (a diverging rate): after ``backoff_after`` refusals in
    a row the interval doubles per refusal, up to ``backoff_max`` intervals; a set-up change
    ends the back-off."""
    adapter = Adapter(AdaptationConfig(min_train_samples=200, lr=50.0, round_steps=5,
                                       weight_decay=0.0, interval_s=1.0, backoff_after=3,
                                       backoff_max=4.0))
    adapter.add(*samples(1500))
    times = []
    for k in range(200):                          # a tick every 0.1 s, new samples each
        t = 0.1 * k
        adapter.add(*samples(2, seed=k + 1))
        r = adapter.round(t)
        if r is not None:
            assert not r.accepted
            times.append(round(r.t, 6))
    assert np.allclose(np.diff(times)[:6], [1, 1, 2, 4, 4, 4]), times
    adapter.on_setup_change(20.0, kind="pressure")
    adapter.round(20.0)
    assert adapter._interval(eager=False) == 1.0


def test_same_seed_same_data_same_model():
    states = []
    for _ in range(2):
        adapter = Adapter(AdaptationConfig(min_train_samples=200, seed=7, skip_idle=False))
        adapter.add(*samples(1500, seed=3))
        run_rounds(adapter, 4)
        states.append({k: v.clone() for k, v in adapter.corr.state_dict().items()})
    for k in states[0]:
        assert torch.equal(states[0][k], states[1][k])


def test_drift_makes_rounds_eager_and_restarts_the_holdout():
    cfg = AdaptationConfig(min_train_samples=200, interval_s=10.0, eager_interval_s=1.0)
    adapter = Adapter(cfg)
    adapter.add(*samples(1500))
    assert adapter.round(0.0) is not None and adapter.round(1.0) is None
    adapter.on_drift(2.0)
    assert len(adapter.holdout) == 0
    r = adapter.round(2.0)
    assert r is not None and r.eager
    assert adapter.round(3.0) is not None                 # eager: every second
    assert not adapter.eager(2.0 + cfg.eager_s + 1)


def test_rounds_train_on_the_buffer_rows_normalised_once():
    """The rings keep their rows' network input and target: a mini-batch drawn from them is,
    to the bit, the raw rows at the same draws normalised then, after the reservoir has been
    overwritten and the holdout cleared; the holdout keeps the newest rows, oldest first."""
    cfg = AdaptationConfig(min_train_samples=200, recent_size=300, reservoir_size=200,
                           holdout_size=50, round_steps=3)
    adapter = Adapter(cfg)
    w, s, m = samples(1200, seed=4)
    adapter.add(w[:700], s[:700], m[:700])
    assert adapter.round(0.0) is not None
    adapter.on_drift(1.0)
    adapter.add(w[700:], s[700:], m[700:])               # more evictions and replacements
    assert adapter.round(1.0) is not None
    rows = np.concatenate([w.reshape(1200, -1), s, m], axis=1).astype(np.float32)
    held = rows[np.arange(1200) % cfg.holdout_every == cfg.holdout_every - 1]
    np.testing.assert_array_equal(adapter.holdout, held[-cfg.holdout_size:])
    state = adapter._rng.bit_generator.state
    inp, target = adapter._batch(cfg.batch_size)
    rng = np.random.default_rng()
    rng.bit_generator.state = state
    n_recent = int(round(cfg.batch_size * cfg.recent_fraction))
    raw = np.concatenate([
        adapter.recent.data()[rng.integers(0, adapter.recent.n, n_recent)],
        adapter.reservoir.data()[rng.integers(0, adapter.reservoir.n,
                                              cfg.batch_size - n_recent)]])
    want_inp, want_target = adapter._net_io(raw, adapter._scaling(adapter.corr), tensors=False)
    np.testing.assert_array_equal(inp, want_inp)
    np.testing.assert_array_equal(target, want_target)


def _stepped_adapter(refit_shrink: float) -> Adapter:
    """An adapter trained on one regime, then offered samples after a step change of the
    measured torques (a drift): the recent ring holds only the new regime, the reservoir
    mostly the old one. Without the trocar physics: these samples hold no trocar, and the
    refit's tests replay the net's own steps."""
    cfg = AdaptationConfig(min_train_samples=200, recent_size=500, reservoir_size=1000,
                           round_steps=20, interval_s=1.0, refit_shrink=0.0,
                           trocar_physics=False)
    adapter = Adapter(cfg)
    adapter.add(*samples(2000, seed=5))
    assert any(r.accepted for r in run_rounds(adapter, 6))
    w, s, m = samples(700, seed=6, gain=0.5)
    adapter.on_drift(100.0)
    adapter.add(w, s, m + np.array([0.3, -0.2, 0.1, 0.0, 0.2, -0.1]))
    adapter.config = cfg.model_copy(update={"refit_shrink": refit_shrink})
    return adapter


def test_the_refit_moves_only_the_output_layer_towards_a_step_change():
    """One round after the change: with the refit the candidate's held-out error on the new
    regime is well below Adam's alone, from the same mini-batches (the refit draws nothing),
    and the hidden layer is Adam's, to the bit."""
    off, on = _stepped_adapter(0.0), _stepped_adapter(1.0)
    r_off, r_on = off.round(100.0), on.round(100.0)
    assert r_off.val_before == r_on.val_before
    assert r_on.val_after < 0.8 * r_off.val_after, (r_on.summary(), r_off.summary())
    assert r_on.accepted and r_off.accepted      # both serve their candidates: comparable
    assert off._rng.bit_generator.state == on._rng.bit_generator.state
    first_off, first_on = off.corr.net[0], on.corr.net[0]
    assert torch.equal(first_off.weight, first_on.weight)
    assert torch.equal(first_off.bias, first_on.bias)
    assert not torch.equal(off.corr.net[2].weight, on.corr.net[2].weight)


def test_refit_off_is_adam_alone_to_the_bit():
    """``refit_shrink`` 0: the candidate is exactly the fine-tuner's Adam steps on the round's
    mini-batches, as before the refit existed; a huge shrink leaves the layer as Adam's."""
    adapter, huge = _stepped_adapter(0.0), _stepped_adapter(1e9)
    twin = _stepped_adapter(0.0)
    assert adapter.round(100.0).accepted and huge.round(100.0).accepted
    cfg = twin.config
    scaling = twin._round_scaling()
    for ring in (twin.recent, twin.reservoir, twin._holdout):
        ring.normalise(scaling, twin._net_rows)
    tuner = CorrFineTuner(twin.corr.net, lr=cfg.lr, weight_decay=cfg.weight_decay)
    for _ in range(cfg.round_steps):
        tuner.step(*twin._batch(cfg.batch_size), with_loss=False)
    want = copy.deepcopy(twin.corr)
    tuner.write_to(want.net)
    for k, v in want.state_dict().items():
        assert torch.equal(adapter.corr.state_dict()[k], v), k
        np.testing.assert_allclose(huge.corr.state_dict()[k].numpy(), v.numpy(), atol=1e-6)


def wall_samples(t: np.ndarray, pressure: np.ndarray, seed: int = 0):
    """Samples whose measured yaw and pitch torques hold the body wall at ``pressure`` (the
    simulator's effect): windows whose newest row is (q, dq) of a yaw/pitch sweep."""
    from wrenchd.models.physics.effects.base import Motion
    from wrenchd.models.physics.effects.body_wall import BodyWall

    rng = np.random.default_rng(seed)
    n = len(t)
    q = np.zeros((n, 6))
    dq = np.zeros((n, 6))
    q[:, 0] = 0.5 * np.sin(2 * np.pi * 0.13 * t)
    q[:, 1] = 0.4 * np.sin(2 * np.pi * 0.08 * t + 0.3)
    dq[:, 0] = 0.5 * 2 * np.pi * 0.13 * np.cos(2 * np.pi * 0.13 * t)
    dq[:, 1] = 0.4 * 2 * np.pi * 0.08 * np.cos(2 * np.pi * 0.08 * t + 0.3)
    x = np.concatenate([q, dq], axis=1)
    windows = np.repeat(x[:, None, :], 10, axis=1)
    step1 = rng.normal(0, 0.2, (n, 6))
    m = Motion(t, q, dq, np.zeros_like(q), None)
    wall = np.stack([BodyWall().torque(m.slice(slice(i, i + 1)), {"pressure_mmhg": p})[0]
                     for i, p in enumerate(pressure)])
    return windows, step1, step1 + wall, q, dq


def test_announced_change_carries_the_buffer_over():
    """Samples at 12 mmHg, then an announced step to 20 mmHg: once the new segment has a
    bin, every buffered sample from before the change has its yaw and pitch targets moved by
    (k_after - k_before) g(q) (within the tracker's estimate), later ones are untouched, and
    the other joints never change."""
    from wrenchd.models.body_wall_tracker import wall_regressors

    rate = 100.0
    t = np.arange(0, 90.0, 1 / rate)
    pressure = np.where(t < 60.0, 12.0, 20.0)
    windows, step1, measured, q, dq = wall_samples(t, pressure)
    config = AdaptationConfig(min_train_samples=100, round_steps=2, recent_size=2000,
                              reservoir_size=2000)
    adapter = Adapter(config)
    before = t < 60.0
    adapter.add(windows[before], step1[before], measured[before], t[before])
    adapter.on_setup_change(60.0)
    adapter.add(windows[~before], step1[~before], measured[~before], t[~before])
    original = {}
    for ring in (adapter.recent, adapter.reservoir, adapter._holdout):
        original[id(ring)] = ring.rows[:ring.n].copy()
    adapter.round(90.0)
    k_then, k_now = adapter.body_wall.stiffness(0), adapter.body_wall.stiffness(1)
    assert abs(k_then - 580.0) < 10.0 and abs(k_now - 900.0) < 15.0
    kcol = 10 * 12 + 6
    moved = 0
    for ring in (adapter.recent, adapter.reservoir, adapter._holdout):
        n = ring.n
        diff = ring.rows[:n].astype(float) - original[id(ring)].astype(float)
        old = ring.stamp[:n] < 60.0
        g, _ = wall_regressors(*adapter._positions(original[id(ring)]),
                               config.body_wall.incision_m)
        np.testing.assert_allclose(diff[old][:, kcol:kcol + 2], (k_now - k_then) * g[old],
                                   atol=1e-4)
        assert not diff[~old].any()
        assert not diff[:, :kcol].any() and not diff[:, kcol + 2:].any()
        assert (ring.shift[:n][old] == k_now - k_then).all()
        moved += int(old.sum())
    assert moved > 1000


def test_no_announcement_no_carry_over_and_unknown_times_stay():
    rate = 100.0
    t = np.arange(0, 40.0, 1 / rate)
    windows, step1, measured, *_ = wall_samples(t, np.full(len(t), 12.0))
    adapter = Adapter(AdaptationConfig(min_train_samples=100, round_steps=2))
    adapter.add(windows, step1, measured, t)
    adapter.add(windows[:500], step1[:500], measured[:500])          # no times
    rows = adapter.recent.rows[:adapter.recent.n].copy()
    adapter.round(40.0)
    assert (adapter.recent.rows[:adapter.recent.n] == rows).all()
    adapter.on_setup_change(40.0)
    adapter.add(windows[:1500], step1[:1500], measured[:1500], t[:1500] + 40.0)
    adapter.round(60.0)
    unknown = np.isnan(adapter.recent.stamp[:adapter.recent.n])
    assert unknown.sum() == 400 and (adapter.recent.shift[:adapter.recent.n][unknown] == 0).all()


def test_a_restarted_clock_keeps_what_was_carried_and_starts_the_tracker_afresh():
    """The robot's clock restarts (the pipeline's clock_reset): rows carried before keep
    their targets, are never carried again, and the new timeline's rows are not shifted by
    the old timeline's segments."""
    rate = 100.0
    t = np.arange(0, 60.0, 1 / rate)
    windows, step1, measured, *_ = wall_samples(t, np.where(t < 30.0, 12.0, 20.0))
    adapter = Adapter(AdaptationConfig(min_train_samples=100, round_steps=2))
    adapter.add(windows[t < 30.0], step1[t < 30.0], measured[t < 30.0], t[t < 30.0])
    adapter.on_setup_change(30.0)
    adapter.add(windows[t >= 30.0], step1[t >= 30.0], measured[t >= 30.0], t[t >= 30.0])
    adapter.round(60.0)
    n = adapter.recent.n
    assert (adapter.recent.shift[:n] != 0).any()
    carried = adapter.recent.rows[:n].copy()
    # a new timeline from 0 s, at 20 mmHg
    t2 = np.arange(0, 20.0, 1 / rate)
    w2, s2, m2, *_ = wall_samples(t2, np.full(len(t2), 20.0), seed=1)
    adapter.add(w2, s2, m2, t2)
    assert adapter.body_wall.starts == [] and adapter.body_wall.latest < 20.0
    adapter.round(80.0)
    ring = adapter.recent
    fresh = ~np.isnan(ring.stamp[:ring.n])
    assert fresh.sum() == 1600 and (ring.shift[:ring.n] == 0).all()
    kept = ~fresh
    assert kept.sum() > 0
    # the rows left from before the restart are exactly as they were carried
    old_rows = {row.tobytes() for row in carried}
    assert all(row.tobytes() in old_rows for row in ring.rows[:ring.n][kept])


def test_a_detected_drift_carries_the_buffer_over_when_asked():
    """The pressure step of the announced case, but told only by a drift detection 2 s after
    it: with ``drift_carry_over`` (and ``drift_lead_s`` = 2) the old rows move as after an
    announcement; without, the drift leaves the buffer as it was."""
    rate = 100.0
    t = np.arange(0, 90.0, 1 / rate)
    windows, step1, measured, *_ = wall_samples(t, np.where(t < 60.0, 12.0, 20.0))
    shifts = {}
    for carry in (False, True):
        config = AdaptationConfig(min_train_samples=100, round_steps=2, recent_size=2000,
                                  reservoir_size=2000, drift_carry_over=carry,
                                  drift_lead_s=2.0)
        adapter = Adapter(config)
        seen = t < 62.0
        adapter.add(windows[seen], step1[seen], measured[seen], t[seen])
        adapter.on_drift(62.0)
        adapter.add(windows[~seen], step1[~seen], measured[~seen], t[~seen])
        adapter.round(90.0)
        rings = (adapter.recent, adapter.reservoir)
        shifts[carry] = (np.concatenate([r.shift[:r.n] for r in rings]),
                         np.concatenate([r.stamp[:r.n] for r in rings]),
                         adapter.body_wall.starts)
    shift, stamp, starts = shifts[True]
    assert starts == [60.0]
    old = stamp < 60.0
    assert old.any() and np.all(shift[old] > 200.0), shift[old]    # k 580 -> 900 N/m
    assert not shift[stamp >= 62.0].any()
    shift, _, starts = shifts[False]
    assert starts == [] and not shift.any()


def test_a_drift_with_nothing_to_carry_or_just_after_a_change_starts_no_segment():
    rate = 100.0
    t = np.arange(0, 90.0, 1 / rate)
    windows, step1, measured, *_ = wall_samples(t, np.where(t < 60.0, 12.0, 20.0))
    adapter = Adapter(AdaptationConfig(min_train_samples=100, round_steps=2))
    adapter.on_drift(0.0)                    # the pipeline's eager start: no sample yet
    assert adapter.body_wall.starts == []
    seen = t < 62.0
    adapter.add(windows[seen], step1[seen], measured[seen], t[seen])
    adapter.on_setup_change(60.0)            # announced ...
    adapter.on_drift(62.0)                   # ... and then detected: the same change
    assert adapter.body_wall.starts == [60.0]
    adapter.on_drift(95.0)                   # a later drift is a change of its own
    assert adapter.body_wall.starts == [60.0, 95.0]


def test_a_drift_while_adapting_to_a_change_starts_no_segment():
    """A drift detected while the rounds are still eager for the latest change (its eager_s,
    extended by its first carry-over) is that change's residual, not a new change: taken for
    one, its stiffness (fitted on a bin or two of free motion) would carry the whole buffer by
    thousands of N/m."""
    rate = 100.0
    t = np.arange(0, 80.0, 1 / rate)
    windows, step1, measured, *_ = wall_samples(t, np.where(t < 60.0, 12.0, 20.0))
    adapter = Adapter(AdaptationConfig(min_train_samples=100, round_steps=2))
    seen = t < 60.0
    adapter.add(windows[seen], step1[seen], measured[seen], t[seen])
    adapter.on_setup_change(60.0)
    adapter.add(windows[~seen], step1[~seen], measured[~seen], t[~seen])
    adapter.round(80.0)                      # the first carry-over: eager until 110 s
    assert adapter.recent.shift[:adapter.recent.n].any()
    adapter.on_drift(95.0)                   # past eager_s after the notice, still adapting
    assert adapter.body_wall.starts == [60.0]
    adapter.on_drift(111.0)                  # adapted: a change of its own
    assert adapter.body_wall.starts == [60.0, 111.0]


def test_a_drift_from_the_daemon_starts_its_segment_at_its_sample_time():
    """The daemon's worker runs the rounds on its own clock (seconds since it started) while
    the samples carry the robot's: a drift is placed among the samples by its sample time,
    and makes the rounds eager on the worker's clock."""
    from wrenchd.models.adaptation.host import AdapterHost

    rate = 100.0
    t = 1000.0 + np.arange(0, 90.0, 1 / rate)              # the robot's clock
    windows, step1, measured, *_ = wall_samples(t, np.where(t < 1060.0, 12.0, 20.0))
    host = AdapterHost({"PSM1": AdaptationConfig(min_train_samples=100, round_steps=2)})
    host.call("PSM1", "samples", 30.0, (windows, step1, measured, t))
    host.call("PSM1", "drift", 31.0, 1062.0)               # worker clock 31 s
    adapter = host.adapters["PSM1"]
    assert adapter.body_wall.starts == [1062.0 - adapter.config.drift_lead_s]
    assert adapter._next_round == 31.0
    assert adapter._eager_until == 31.0 + adapter.config.eager_s


def test_an_idle_tick_is_one_that_does_nothing():
    """The host's idle_tick: a tick it calls idle returns no round whatever rows came before
    it, and a tick at the next round's time is not idle (the replay worker skips the idle
    ones and adds their rows with the next call)."""
    from wrenchd.models.adaptation.host import AdapterHost

    host = AdapterHost({"PSM1": AdaptationConfig(min_train_samples=64, interval_s=2.0)})
    rng = np.random.default_rng(0)
    width = host.adapters["PSM1"].width
    rows = rng.standard_normal((200, width)).astype(np.float32)
    host.call("PSM1", "rows", 0.0, (rows, np.linspace(0.0, 1.0, 200)))
    assert not host.idle_tick("PSM1", 1.0)                 # enough rows, no round yet
    assert host.call("PSM1", "tick", 1.0) is not None
    assert host.idle_tick("PSM1", 2.9)                     # the next round is due at 3.0 s
    host.call("PSM1", "rows", 2.9, (rows, np.linspace(1.0, 2.9, 200)))
    assert host.call("PSM1", "tick", 2.9) is None
    assert not host.idle_tick("PSM1", 3.0) and host.call("PSM1", "tick", 3.0) is not None
    host.call("PSM1", "fail", 3.1)
    assert not host.idle_tick("PSM1", 3.1)                 # an injected failure must run
    assert host.idle_tick("PSM9", 3.1)                     # not an adapting arm


def test_the_trocar_physics_carries_the_body_wall_to_motion_the_net_has_not_seen():
    """Rounds on 40 s of a yaw/pitch sweep under the body wall; then a sweep elsewhere in the
    workspace: the served correction with the trocar physics predicts the wall there to
    within a tenth of its size, the net alone does not."""
    from wrenchd.models.physics.effects.base import Motion
    from wrenchd.models.physics.effects.body_wall import BodyWall

    t = np.arange(0, 40.0, 0.01)
    windows, step1, measured, _, _ = wall_samples(t, np.full(len(t), 12.0))
    served = {}
    for physics in (True, False):
        adapter = Adapter(AdaptationConfig(min_train_samples=200, interval_s=1.0,
                                           trocar_physics=physics))
        adapter.add(windows, step1, measured, t)
        assert any(r.accepted for r in run_rounds(adapter, 10))
        served[physics] = adapter.corr.kernel()
    t2 = np.arange(0, 10.0, 0.01)
    q, dq = np.zeros((len(t2), 6)), np.zeros((len(t2), 6))
    q[:, 0] = -0.6 + 0.3 * np.sin(2 * np.pi * 0.2 * t2)
    dq[:, 0] = 0.3 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * t2)
    q[:, 1] = 0.5 + 0.2 * np.cos(2 * np.pi * 0.17 * t2)
    dq[:, 1] = -0.2 * 2 * np.pi * 0.17 * np.sin(2 * np.pi * 0.17 * t2)
    wall = BodyWall({"pressure_mmhg": 12.0}).torque(Motion(t2, q, dq, np.zeros_like(q), None))
    w2 = np.repeat(np.concatenate([q, dq], 1)[:, None], 10, axis=1)
    s2 = np.zeros((len(t2), 6), np.float32)
    size = np.sqrt(np.mean(wall[:, :2] ** 2))
    err = {k: np.sqrt(np.mean((v.correct(w2, s2)[:, :2] - wall[:, :2]) ** 2))
           for k, v in served.items()}
    assert err[True] < 0.1 * size < err[False], (err, size)


def test_the_trocar_physics_is_fitted_in_its_first_rounds_then_held():
    """A stiffer wall (12 -> 20 mmHg) after ``trocar_fit_s``: the wall's parameters stay as
    the first rounds fitted them (the net follows the change); re-fitted in every round
    (``inf``) they move to it."""
    t = np.arange(0, 40.0, 0.01)
    before = t < 20.0
    windows, step1, measured, _, _ = wall_samples(t, np.where(before, 12.0, 20.0))
    held = {}
    for fit_s in (15.0, np.inf):
        adapter = Adapter(AdaptationConfig(min_train_samples=200, interval_s=1.0,
                                           trocar_fit_s=fit_s))
        adapter.add(windows[before], step1[before], measured[before], t[before])
        thetas = {}
        for k in range(40):
            if k == 20:
                adapter.add(windows[~before], step1[~before], measured[~before], t[~before])
            adapter.round(float(k))
            thetas[k] = adapter.corr.trocar_theta.clone()
        assert np.abs(thetas[14].numpy()).max() > 0
        held[fit_s] = torch.equal(thetas[14], thetas[39])
    assert held[15.0] and not held[np.inf]
