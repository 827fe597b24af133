"""The body wall tracker: stiffness per bin from yaw and pitch residuals, carried over across
announced set-up changes."""

import numpy as np
import pytest

from wrenchd.models.body_wall_tracker import BodyWallTracker, BodyWallTrackerConfig, wall_regressors
from wrenchd.models.errors import DataError
from wrenchd.models.physics.effects.base import Motion
from wrenchd.models.physics.effects.body_wall import BodyWall


def motion(n, seed=0, rate_hz=200.0):
    """Yaw and pitch sweeping +-0.5 rad at two frequencies, the rest still."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    q = np.zeros((n, 6))
    dq = np.zeros((n, 6))
    f1, f2 = 0.11 + 0.02 * rng.random(), 0.07 + 0.02 * rng.random()
    q[:, 0] = 0.5 * np.sin(2 * np.pi * f1 * t)
    q[:, 1] = 0.4 * np.sin(2 * np.pi * f2 * t + 0.3)
    dq[:, 0] = 0.5 * 2 * np.pi * f1 * np.cos(2 * np.pi * f1 * t)
    dq[:, 1] = 0.4 * 2 * np.pi * f2 * np.cos(2 * np.pi * f2 * t + 0.3)
    q[:, 2] = 0.12
    return t, q, dq


def wall_torque(q, dq, pressure):
    m = Motion(np.zeros(len(q)), q, dq, np.zeros_like(q), None)
    return BodyWall().torque(m, {"pressure_mmhg": pressure})[:, :2]


def test_regressors_rebuild_the_effect():
    """k g + c h is the body wall effect's own torque (its defaults: k = 100 + 40 * 12)."""
    _, q, dq = motion(500)
    g, h = wall_regressors(q, dq, BodyWall().params.incision_m)
    k = 100.0 + 40.0 * 12.0
    np.testing.assert_allclose(k * g + 5.0 * h, wall_torque(q, dq, 12.0), atol=1e-12)


def test_stiffness_step_across_an_announced_change():
    """12 -> 20 mmHg at 60 s with noise and a joint offset: each segment's stiffness within
    3 % of the truth (580, 900 N/m), and older samples are carried over by the difference."""
    t, q, dq = motion(200 * 120)
    rng = np.random.default_rng(1)
    tau = np.where((t < 60.0)[:, None], wall_torque(q, dq, 12.0), wall_torque(q, dq, 20.0))
    residual = tau + np.array([0.05, -0.03]) + 0.02 * rng.standard_normal(tau.shape)
    tracker = BodyWallTracker()
    tracker.announce(60.0)
    for a in range(0, len(t), 250):                      # in pieces, as the pipeline offers
        b = a + 250
        tracker.add(t[a:b], q[a:b], dq[a:b], residual[a:b])
    assert tracker.stiffness(0) == pytest.approx(580.0, rel=0.03)
    assert tracker.stiffness(1) == pytest.approx(900.0, rel=0.03)
    shift = tracker.carry_over(np.array([10.0, 59.9, 60.0, 100.0, np.nan]))
    assert shift[0] == shift[1] == pytest.approx(tracker.stiffness(1) - tracker.stiffness(0))
    assert shift[2] == shift[3] == shift[4] == 0.0
    # no bin straddles the change: the new segment's bins start at it
    starts = [b for b, s, _, _ in tracker.bins if s == 1]
    assert starts[0] == 60.0 and all(b >= 60.0 for b in starts)
    assert tracker.starts == [60.0]
    assert tracker.stiffnesses() == [tracker.stiffness(0), tracker.stiffness(1)]


def wall_at(t, q, dq, changes):
    """Body wall torques for pressures 12 mmHg, then each ``(time, pressure)`` from its time."""
    pressure = np.full(len(t), 12.0)
    for at, p in changes:
        pressure[t >= at] = p
    out = np.zeros((len(t), 2))
    for p in np.unique(pressure):
        m = pressure == p
        out[m] = wall_torque(q[m], dq[m], p)
    return out


def add_in_pieces(tracker, t, q, dq, tau, lo, hi):
    m = np.flatnonzero((t >= lo) & (t < hi))
    for a in range(0, len(m), 250):
        i = m[a:a + 250]
        tracker.add(t[i], q[i], dq[i], tau[i])


def test_a_late_notice_drops_the_bins_that_mixed_the_two_set_ups():
    """The change at 60 s is told only once samples up to 75 s were added: the old segment's
    bins from 60 s on (one closed, one open) held the new set-up and are dropped, so the
    old stiffness stays the truth (unhandled, the mixed bins pulled it 11 % up, to 644 N/m)."""
    t, q, dq = motion(200 * 120)
    tau = wall_at(t, q, dq, [(60.0, 20.0)])
    tracker = BodyWallTracker()
    add_in_pieces(tracker, t, q, dq, tau, 0.0, 75.0)
    assert max(b for b, s, _, _ in tracker.bins) == 60.0      # the mixed bin was closed
    tracker.announce(60.0)
    assert all(b + 10.0 <= 60.0 for b, s, _, _ in tracker.bins if s == 0)
    add_in_pieces(tracker, t, q, dq, tau, 75.0, 120.0)
    assert tracker.stiffness(0) == pytest.approx(580.0, rel=1e-6)
    assert tracker.stiffness(1) == pytest.approx(900.0, rel=1e-6)
    # the new segment's bins start at the change: 60-70 s saw no sample, 70-80 s its last 5 s
    assert min(b for b, s, _, _ in tracker.bins if s == 1) == 70.0


def test_a_notice_older_than_the_last_one_moves_the_later_segments_up():
    """Told of 90 s first, then (late) of 60 s: the segment from 90 s becomes the third, the
    samples of 60-90 s (added as the first segment's) are dropped, nothing else moves."""
    t, q, dq = motion(200 * 120)
    tau = wall_at(t, q, dq, [(60.0, 20.0), (90.0, 28.0)])
    tracker = BodyWallTracker()
    tracker.announce(90.0)
    add_in_pieces(tracker, t, q, dq, tau, 0.0, 120.0)
    k_late = tracker.stiffness(1)
    tracker.announce(60.0)
    assert tracker.starts == [60.0, 90.0]
    assert tracker.stiffness(0) == pytest.approx(580.0, rel=1e-6)
    assert tracker.stiffness(1) is None
    assert tracker.stiffness(2) == k_late == pytest.approx(100.0 + 40.0 * 28.0, rel=1e-6)
    assert {s for _, s, _, _ in tracker.bins} == {0, 2}
    shift = tracker.carry_over(np.array([10.0, 70.0, 100.0]))
    assert shift[0] == pytest.approx(k_late - 580.0, rel=1e-6)
    assert shift[1] == shift[2] == 0.0                     # segment 1 is not known


def test_nothing_is_carried_before_the_new_segment_has_a_bin():
    t, q, dq = motion(200 * 65)
    tracker = BodyWallTracker()
    tracker.add(t[t < 60.0], q[t < 60.0], dq[t < 60.0], wall_torque(q, dq, 12.0)[t < 60.0])
    tracker.announce(60.0)
    after = t >= 60.0
    tracker.add(t[after], q[after], dq[after], wall_torque(q, dq, 20.0)[after])
    # 5 s after the change: its first 10 s bin is still open
    assert tracker.stiffness(1) is None
    assert (tracker.carry_over(np.array([1.0, 30.0])) == 0.0).all()


def test_unannounced_tracker_never_carries_over():
    t, q, dq = motion(200 * 40)
    tracker = BodyWallTracker()
    tracker.add(t, q, dq, wall_torque(q, dq, 12.0))
    assert tracker.stiffness(0) == pytest.approx(580.0, rel=1e-6)
    assert (tracker.carry_over(t) == 0.0).all()


def test_sparse_bins_and_bad_rows_are_ignored():
    """A bin with fewer than min_bin_samples samples does not count; NaN rows are dropped."""
    t, q, dq = motion(200 * 30)
    tau = wall_torque(q, dq, 12.0)
    tau[::7] = np.nan
    tracker = BodyWallTracker(BodyWallTrackerConfig(min_bin_samples=5000))
    tracker.add(t, q, dq, tau)
    assert tracker.bins == [] and tracker.stiffness(0) is None
    tracker = BodyWallTracker()
    tracker.add(t, q, dq, tau)
    assert tracker.stiffness(0) == pytest.approx(580.0, rel=1e-6)


def test_bad_input_is_refused():
    tracker = BodyWallTracker()
    with pytest.raises(DataError, match="expected"):
        tracker.add(np.zeros(3), np.zeros((3, 6)), np.zeros((3, 6)), np.zeros((3, 6)))
    with pytest.raises(DataError, match="finite"):
        tracker.announce(float("nan"))
    with pytest.raises(ValueError):
        BodyWallTrackerConfig(bin_s=0.0)


def test_binning_does_not_depend_on_how_samples_arrive():
    """Three rows at a time (as the pipeline offers) or all at once: the same bins and
    stiffnesses to rounding, and a notice after samples bins the earlier ones first."""
    t, q, dq = motion(200 * 90)
    tau = np.where((t < 60.0)[:, None], wall_torque(q, dq, 12.0), wall_torque(q, dq, 20.0))
    whole, pieces = BodyWallTracker(), BodyWallTracker()
    whole.add(t[t < 60.0], q[t < 60.0], dq[t < 60.0], tau[t < 60.0])
    for a in np.flatnonzero(t < 60.0)[::3]:
        pieces.add(t[a:a + 3], q[a:a + 3], dq[a:a + 3], tau[a:a + 3])
    assert pieces.latest == whole.latest == t[t < 60.0][-1]
    for tracker in (whole, pieces):
        tracker.announce(60.0)
        late = t >= 60.0
        tracker.add(t[late], q[late], dq[late], tau[late])
    assert [b[:2] + (b[3],) for b in pieces.bins] == [b[:2] + (b[3],) for b in whole.bins]
    np.testing.assert_allclose([b[2] for b in pieces.bins], [b[2] for b in whole.bins],
                               rtol=1e-9)
    assert pieces.stiffness(1) == pytest.approx(whole.stiffness(1), rel=1e-9)
    assert whole.stiffness(1) == pytest.approx(900.0, rel=1e-3)
