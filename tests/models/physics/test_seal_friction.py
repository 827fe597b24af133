"""The cannula seal (``seal_friction``): LuGre hysteresis, breakaway spikes, stick-slip.

Motions are prescribed on one sealed joint; the seal needs no robot model (``robot=None``).
Unless a test says otherwise, magnitudes are the defaults: insertion Fc 1.0 N, spike
Fs - Fc 0.6 N, Stribeck velocity 5 mm/s, lip sawtooth 0.15 N below 2 mm/s.
"""

from __future__ import annotations

import numpy as np
import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.effects import EFFECTS, Motion
from wrenchd.models.physics.effects.drift import Drift
from wrenchd.models.physics.effects.seal import SEALED_JOINTS, SealFriction, SealParams, seal_force

P = SealParams()
INSERTION, ROLL = 0, 1                         # index into each parameter pair
FC = P.fc[INSERTION]                           # 1.0 N


def joint(which: int = INSERTION, **changes) -> dict:
    """One joint's parameters as ``seal_force`` keywords."""
    params = {key: getattr(P, key)[which] for key in SealParams.model_fields}
    params.update(changes)
    return params


def sinusoid(amplitude: float, period: float, cycles: float, rate_hz: float = 1000.0):
    """``x = amplitude sin(2 pi t / period)``: t [s], x [m], v [m/s]."""
    t = np.arange(0.0, cycles * period, 1.0 / rate_hz)
    w = 2 * np.pi / period
    return t, amplitude * np.sin(w * t), amplitude * w * np.cos(w * t)


def motion_on(column: int, t, x, v) -> Motion:
    """A Motion that moves only ``column``."""
    q = np.zeros((len(t), 6))
    dq = np.zeros((len(t), 6))
    q[:, column], dq[:, column] = x, v
    return Motion(np.asarray(t, float), q, dq, np.zeros_like(q), None)


def steady_curve(v, which: int = INSERTION) -> np.ndarray:
    """LuGre's steady sliding force (lip off): ``sign(v) g(v) + sigma2 v``."""
    g = P.fc[which] + P.fs_excess[which] * np.exp(-np.square(v / P.vs[which]))
    return np.sign(v) * g + P.sigma2[which] * v


# -- (1) direction ---------------------------------------------------------------------------
def test_force_reverses_with_velocity_at_the_steady_sliding_level():
    # 10 mm, 4 s strokes: peak 16 mm/s, mostly sliding; skip the first (from-rest) cycle.
    t, x, v = sinusoid(0.010, 4.0, 3)
    f = seal_force(t, x, v, **joint(lip_amplitude=0.0))
    later = t >= 4.0
    fwd, bwd = later & (v > 0), later & (v < 0)
    assert f[fwd].mean() > 0.9 * FC and f[bwd].mean() < -0.9 * FC
    for stroke, sign in ((fwd, 1.0), (bwd, -1.0)):
        # Sliding (|v| > 2 vs): LuGre sits on its steady friction curve within 2 %.
        sliding = stroke & (np.abs(v) > 2 * P.vs[INSERTION])
        np.testing.assert_allclose(f[sliding], steady_curve(v[sliding]), rtol=0.02)
        # Over a whole stroke the mean lies between Fc (no breakaway) and the steady curve's
        # mean (breakaway fully developed at every slow instant); the bristle needs tens of
        # micrometres after each reversal to reach the static level, so it sits in between.
        mean = sign * f[stroke].mean()
        assert 0.98 * FC < mean < 1.02 * sign * steady_curve(v[stroke]).mean()
    # Symmetric seal: the two strokes differ by less than 2 % of Fc.
    assert abs(f[fwd].mean() + f[bwd].mean()) < 0.02 * FC


def test_roll_torque_reverses_at_its_own_level():
    t, x, v = sinusoid(1.2, 2.0, 2)            # +-1.2 rad, peak 3.8 rad/s
    tau = SealFriction().torque(motion_on(3, t, x, v))
    fc_roll = P.fc[ROLL]
    sliding = (t >= 2.0) & (np.abs(v) > 2 * P.vs[ROLL])
    level = tau[sliding, 3] * np.sign(v[sliding]) - P.sigma2[ROLL] * np.abs(v[sliding])
    assert level.mean() == pytest.approx(fc_roll, rel=0.05)
    assert np.all(tau[:, [0, 1, 2, 4, 5]] == 0.0)


# -- (2) hysteresis --------------------------------------------------------------------------
def test_hysteresis_loop_dissipates_coulomb_work():
    amplitude = 0.010
    t, x, v = sinusoid(amplitude, 4.0, 2)
    coulomb = joint(fs_excess=0.0, sigma1=0.0, sigma2=0.0, lip_amplitude=0.0)
    f = seal_force(t, x, v, **coulomb)
    cycle = t >= 4.0 - 1e-9                    # the second, steady cycle
    fc_cycle, xc = f[cycle], x[cycle]
    work = np.sum(0.5 * (fc_cycle[1:] + fc_cycle[:-1]) * np.diff(xc))   # closed integral F dx
    # Coulomb friction over a closed stroke of 4 * amplitude dissipates 4 Fc A = 0.04 J; the
    # presliding corners (2 Fc / sigma0 = 40 um) round it off by well under 2 %.
    assert work == pytest.approx(4 * FC * amplitude, rel=0.02)
    # The loop's two branches at mid-stroke are 2 Fc apart.
    mid = np.abs(xc) < 0.1 * amplitude
    gap = f[cycle][mid & (v[cycle] > 0)].mean() - f[cycle][mid & (v[cycle] < 0)].mean()
    assert gap == pytest.approx(2 * FC, rel=0.02)

    # The full model dissipates more (breakaway, viscous), never less.
    f_full = seal_force(t, x, v, **joint())[cycle]
    work_full = np.sum(0.5 * (f_full[1:] + f_full[:-1]) * np.diff(xc))
    assert work < work_full < 4 * (FC + P.fs_excess[INSERTION]) * amplitude


def test_presliding_is_elastic_below_breakaway():
    # A 2 um oscillation never slides: the bristle acts as the spring sigma0 (0.1 N << Fc).
    t, x, v = sinusoid(2e-6, 1.0, 2)
    f = seal_force(t, x, v, **joint(sigma1=0.0, sigma2=0.0, lip_amplitude=0.0))
    stiffness = np.polyfit(x, f, 1)[0]
    assert stiffness == pytest.approx(P.sigma0[INSERTION], rel=0.1)
    assert np.abs(f).max() < 0.15 * FC


# -- (3) reversal spike ----------------------------------------------------------------------
def reversal(accel: float = 0.002, v_end: float = 0.02, rate_hz: float = 1000.0):
    """Constant acceleration through a reversal from -v_end to +v_end: t, x, v."""
    t = np.arange(0.0, 2 * v_end / accel, 1.0 / rate_hz)
    return t, -v_end * t + 0.5 * accel * t**2, -v_end + accel * t


@pytest.mark.parametrize("excess", [0.2, 0.6, 2.5])
def test_reversal_spike_reaches_the_static_level(excess):
    t, x, v = reversal()
    params = joint(fs_excess=excess, lip_amplitude=0.0)
    f = seal_force(t, x, v, **params)
    after = v > 0
    friction = f[after] - P.sigma2[INSERTION] * v[after]
    spike = friction.max() - FC
    # A slow (2 mm/s^2) reversal crosses presliding well inside the Stribeck region, so the
    # peak approaches Fs; it falls short only by the Stribeck decay met on the way.
    assert 0.85 * excess < spike < 1.02 * excess
    assert friction[-1] == pytest.approx(FC, abs=0.01)          # settles to Fc at 4 vs


def test_no_spike_when_static_equals_coulomb():
    t, x, v = reversal()
    f = seal_force(t, x, v, **joint(fs_excess=0.0, lip_amplitude=0.0))
    after = v > 0
    friction = f[after] - P.sigma2[INSERTION] * v[after]
    assert friction.max() - FC < 0.02 * FC


# -- (4) stick-slip --------------------------------------------------------------------------
def constant_speed(speed: float, duration: float = 2.0, rate_hz: float = 1000.0):
    t = np.arange(0.0, duration, 1.0 / rate_hz)
    return t, speed * t, np.full_like(t, speed)


def test_stick_slip_sawtooth_at_low_speed():
    speed = 0.0003                              # 0.3 mm/s
    t, x, v = constant_speed(speed)
    f = seal_force(t, x, v, **joint())
    settled = t > 0.5
    tooth = P.lip_amplitude[INSERTION] * (1 - speed / P.lip_velocity[INSERTION])   # 0.1275 N
    slips = np.count_nonzero(np.diff(f[settled]) < -0.5 * tooth)
    # One slip per lip deflection of tooth / k_lip (42.5 um): ~10.6 in 1.5 s.
    expected = speed * 1.5 / (tooth / P.lip_stiffness[INSERTION])
    assert slips >= 5 and abs(slips - expected) <= 1.5
    assert np.ptp(f[settled]) == pytest.approx(tooth, rel=0.1)


def test_no_stick_slip_above_the_critical_speed():
    t, x, v = constant_speed(0.02)              # 20 mm/s, ten times the lip velocity
    f = seal_force(t, x, v, **joint())
    settled = t > 0.5
    assert np.count_nonzero(np.diff(f[settled]) < -1e-6) == 0
    assert np.ptp(f[settled]) < 1e-6
    assert f[settled].mean() == pytest.approx(steady_curve(0.02), rel=1e-3)


def test_roll_stick_slip_through_the_effect():
    speed = 0.05                                # rad/s, a tenth of the roll lip velocity
    t, x, v = constant_speed(speed)
    tau = SealFriction().torque(motion_on(3, t, x, v))[:, 3]
    tooth = P.lip_amplitude[ROLL] * (1 - speed / P.lip_velocity[ROLL])
    slips = np.count_nonzero(np.diff(tau[t > 0.5]) < -0.5 * tooth)
    assert slips >= 5


# -- (5) parameters varying in time ----------------------------------------------------------
def test_doubling_fc_by_override_doubles_sliding_force():
    speed = 0.03
    t, x, v = constant_speed(speed, 1.0)
    motion = motion_on(2, t, x, v)
    seal = SealFriction()
    nominal = seal.torque(motion)[:, 2]
    doubled = seal.torque(motion, {"fc": np.tile(2 * np.asarray(P.fc), (len(t), 1))})[:, 2]
    viscous = P.sigma2[INSERTION] * speed
    assert doubled[-1] - viscous == pytest.approx(2 * (nominal[-1] - viscous), rel=0.01)


def test_fc_ramp_is_followed_step_by_step():
    speed = 0.03
    t, x, v = constant_speed(speed, 2.0)
    fc_t = FC * (1.0 + t)                       # 1 N growing to 3 N, one value per step (N,)
    f = SealFriction().torque(motion_on(2, t, x, v), {"fc": fc_t})[:, 2]
    sliding = t > 0.1
    friction = f[sliding] - P.sigma2[INSERTION] * speed
    np.testing.assert_allclose(friction, fc_t[sliding], rtol=0.01)


def test_drift_on_fc_adds_the_extra_sliding_force():
    speed = 0.03
    t, x, v = constant_speed(speed, 1.0)
    seal = SealFriction()
    drift = Drift({"target": "seal_friction", "param": "fc", "kind": "step", "factor": 2.0})
    drift.bind(seal)
    assert drift.stateful
    extra = drift.torque(motion_on(2, t, x, v))
    assert extra[-1, 2] == pytest.approx(FC, rel=0.01)   # 2 Fc - Fc
    assert np.all(extra[:, [0, 1, 3, 4, 5]] == 0.0)


def test_bad_overrides_are_refused():
    t, x, v = constant_speed(0.01, 0.1)
    seal = SealFriction()
    with pytest.raises(ConfigError, match="fc"):
        seal.torque(motion_on(2, t, x, v), {"fc": np.ones((len(t), 3))})
    with pytest.raises(ConfigError, match="sigma0"):
        seal.torque(motion_on(2, t, x, v), {"sigma0": np.zeros(len(t))})


# -- (6) contract ----------------------------------------------------------------------------
def test_registered_stateful_and_validated():
    assert EFFECTS["seal_friction"] is SealFriction and SealFriction.stateful
    assert "fc" in SealFriction().numeric_params()
    for bad in ({"fc": (-1.0, 0.004)}, {"fs_excess": (-0.1, 0.0)}, {"sigma0": (0.0, 0.88)},
                {"vs": (0.005,)}, {"lip_velocity": (float("nan"), 0.5)}, {"colour": 1}):
        with pytest.raises(ConfigError):
            SealFriction(bad)


def test_deterministic_input_untouched_and_only_sealed_columns():
    rng = np.random.default_rng(7)
    t, x, v = sinusoid(0.01, 1.5, 2)
    motion = motion_on(2, t, x, v)
    motion.q[:, 3] = 0.3 * np.sin(3 * t)
    motion.dq[:, 3] = 0.9 * np.cos(3 * t)
    motion.q[:, [0, 1, 4, 5]] = rng.normal(size=(len(t), 4))
    motion.dq[:, [0, 1, 4, 5]] = rng.normal(size=(len(t), 4))
    before = [a.copy() for a in (motion.t, motion.q, motion.dq, motion.ddq)]
    fc_override = np.tile(np.asarray(P.fc), (len(t), 1))
    override_before = fc_override.copy()
    seal = SealFriction()
    first = seal.torque(motion, {"fc": fc_override})
    second = seal.torque(motion, {"fc": fc_override})
    assert first.shape == (len(t), 6) and np.array_equal(first, second)
    for a, b in zip(before, (motion.t, motion.q, motion.dq, motion.ddq)):
        assert np.array_equal(a, b)
    assert np.array_equal(fc_override, override_before)
    unsealed = [j for j in range(6) if j not in SEALED_JOINTS]
    assert np.all(first[:, unsealed] == 0.0) and np.all(np.abs(first[:, 2:4]).max(0) > 0)
    # The effect is the helper, column by column.
    for col, j in enumerate(SEALED_JOINTS):
        np.testing.assert_array_equal(
            first[:, j], seal_force(motion.t, motion.q[:, j], motion.dq[:, j], **joint(col)))


def test_zero_levels_give_zero_torque():
    t, x, v = sinusoid(0.01, 1.0, 1)
    off = {"fc": (0, 0), "fs_excess": (0, 0), "sigma2": (0, 0), "lip_amplitude": (0, 0)}
    assert np.all(SealFriction(off).torque(motion_on(2, t, x, v)) == 0.0)


# -- (7) step independence -------------------------------------------------------------------
def test_sliding_force_independent_of_the_step():
    t1, x1, v1 = sinusoid(0.010, 2.0, 2, rate_hz=1000.0)
    t2, x2, v2 = sinusoid(0.010, 2.0, 2, rate_hz=2000.0)
    f1 = seal_force(t1, x1, v1, **joint())
    f2 = seal_force(t2, x2, v2, **joint())[::2]                  # the same instants as f1
    assert np.allclose(t2[::2], t1)
    sliding = np.abs(v1) > 2 * P.vs[INSERTION]
    np.testing.assert_allclose(f2[sliding], f1[sliding], rtol=0.02)
    # The whole cycle, spikes included, agrees to a few % of Fc.
    assert np.abs(f2 - f1).max() < 0.05 * FC


def test_irregular_steps_give_the_same_force():
    # Jittered sample times (0.5 to 1.5 ms): the step is taken from t, never assumed.
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 4000))
    t -= t[0]
    w = 2 * np.pi / 2.0
    f = seal_force(t, 0.01 * np.sin(w * t), 0.01 * w * np.cos(w * t), **joint())
    t1, x1, v1 = sinusoid(0.010, 2.0, 2)
    f1 = np.interp(t, t1, seal_force(t1, x1, v1, **joint()))
    v = 0.01 * w * np.cos(w * t)
    sliding = (np.abs(v) > 2 * P.vs[INSERTION]) & (t > 0.05)   # past the start from rest
    np.testing.assert_allclose(f[sliding], f1[sliding], rtol=0.02)
