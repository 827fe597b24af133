"""The gate's motion-conditioned spread: friction spikes where a joint turns round are learnt
as free motion's, a contact between reversals is still found."""

import numpy as np
import pytest
from pydantic import ValidationError

from wrenchd.models.gate import FreeMotionGate, GateConfig, ReversalSpread

RATE = 200.0
STD = np.array([0.05, 0.05, 0.1, 0.0025, 0.0025, 0.0025])    # residual noise [N m; N]


def reversing_session(n: int = 24000, seed: int = 0, spike: float = 8.0):
    """Noise, the insertion (joint 2) reversing every 2.5 s (a 0.2 Hz sine, 2 cm/s peak)
    with a friction spike of ``spike`` noise units over the first 60 ms after each reversal,
    and a 1 s contact of 5 noise units on yaw and pitch at 101.2 s (no reversal near it)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    velocity = np.zeros((n, 6))
    velocity[:, [0, 1, 3, 4, 5]] = 0.3                     # the other joints move steadily
    velocity[:, 2] = 0.02 * np.sin(2 * np.pi * 0.2 * t)
    r = rng.normal(0.0, STD, (n, 6))
    sign = np.sign(velocity[:, 2])
    turns = np.flatnonzero(np.diff(sign) != 0) + 1
    for k in turns:
        r[k:k + 12, 2] += spike * STD[2] * sign[k]         # friction opposes the new motion
    contact = (t >= 101.2) & (t < 102.2)
    r[contact, :2] += 5.0 * STD[:2]
    return t, r, velocity, turns, contact


def run(gate: FreeMotionGate, t, r, velocity=None):
    return [gate.update(i, t[i], r[i], None if velocity is None else velocity[i])
            for i in range(len(t))]


def test_spikes_at_reversals_are_free_motion_once_learnt_and_a_contact_is_still_found():
    t, r, v, turns, contact = reversing_session()
    cfg = GateConfig(warmup_samples=1000)
    with_motion = FreeMotionGate(cfg)
    out = run(with_motion, t, r, v)
    plain = run(FreeMotionGate(cfg), t, r)                 # no velocities: one spread
    late = turns[turns > 60 * RATE]                        # after a minute of learning
    spikes = np.zeros(len(t), dtype=bool)
    for k in late:
        spikes[k:k + 40] = True
    flagged = np.array([not d.free for d in out])
    flagged_plain = np.array([not d.free for d in plain])
    # without the velocities most late spikes start a contact; with them, none does
    assert np.mean([flagged_plain[k:k + 40].any() for k in late]) > 0.8
    assert not flagged[spikes].any()
    # the contact (no reversal within a second of it) is found by both, within 0.2 s
    for f in (flagged, flagged_plain):
        onset = np.flatnonzero(contact)[0]
        assert f[onset:onset + 40].any() and f[contact].mean() > 0.8
    # the insertion's first bin learnt a spread of several noise units; the steady one is 1
    factors = with_motion.reversal.factors()
    assert factors.shape == (len(cfg.reversal_bins_s) + 1, 6)
    assert 3.0 < factors[0, 2] <= cfg.max_reversal_factor
    assert (factors[-1] == 1.0).all()
    # training is judged on the plain scale: a spike sample is free but never trains
    assert not any(out[k + 2].trainable for k in late)


def test_the_spread_stays_within_its_bounds_and_a_slow_joint_is_reversing():
    spread = ReversalSpread((0.05, 0.1), (0.01,) * 6, alpha=0.01, max_factor=3.0)
    v = np.full(6, 0.5)
    v[1] = 0.0                                             # joint 1 stands still
    for i in range(2000):
        spread.factors_sq(i / RATE, v.tolist())
        spread.learn([100.0] * 6)                          # 10 scale units everywhere
    f = spread.factors()
    assert f[0, 1] == pytest.approx(3.0)                   # capped at max_factor
    assert (f[:, [0, 2, 3, 4, 5]] == 1.0).all()            # moving steadily: nothing learnt
    assert (f[1:, 1] == 1.0).all()                         # still joint: always the first bin


def test_bad_reversal_settings_are_refused():
    with pytest.raises(ValidationError, match="increasing"):
        GateConfig(reversal_bins_s=(0.1, 0.05))
    with pytest.raises(ValidationError, match="slow_velocity"):
        GateConfig(slow_velocity=(0.01,) * 5)
    assert FreeMotionGate(GateConfig(reversal_bins_s=())).reversal is None


def test_a_spike_over_the_learnt_spread_at_a_reversal_waits_out_the_hold():
    """Every sixth reversal's spike is 7.5 times the others: the learnt spread (a mean square,
    capped at ``max_reversal_factor``) does not cover it. Its peak score starts a contact unless a joint's peak waits
    ``reversal_hold_s`` after its reversal; the yaw-pitch contact is found either way."""
    t, r, v, turns, contact = reversing_session(spike=8.0)
    sign = np.sign(v[:, 2])
    big = turns[::6]
    for k in big:
        r[k:k + 12, 2] += 52.0 * STD[2] * sign[k]
    late = big[big > 60 * RATE]
    onset = np.flatnonzero(contact)[0]
    flagged = {}
    for hold in (0.0, 0.06):
        out = run(FreeMotionGate(GateConfig(warmup_samples=1000, reversal_hold_s=hold)), t, r, v)
        flagged[hold] = np.array([not d.free for d in out])
        assert flagged[hold][onset:onset + 40].any() and flagged[hold][contact].mean() > 0.8
    assert np.mean([flagged[0.0][k:k + 40].any() for k in late]) > 0.5
    assert not any(flagged[0.06][k:k + 40].any() for k in late)
    with pytest.raises(ValidationError):
        GateConfig(reversal_hold_s=-0.1)
