"""Excitation trajectories: within the limits, at rest at both ends, analytic derivatives that
match the positions, and a regressor better conditioned than the seeded start."""

from __future__ import annotations

import numpy as np
import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.models.identification.excitation import (
    ExcitationConfig, RegressorCondition, excitation_config, optimise_excitation, sample_periods,
)

QUICK = {"iterations": 10, "samples": 50}


@pytest.fixture(scope="module")
def quick():
    return optimise_excitation(ExcitationConfig(**QUICK))


def _within_limits(config: ExcitationConfig, q, dq, ddq) -> None:
    lo, hi = np.array(config.lower), np.array(config.upper)
    assert np.all(q >= lo) and np.all(q <= hi)
    assert np.all(np.abs(dq) <= np.array(config.max_velocity))
    assert np.all(np.abs(ddq) <= np.array(config.max_acceleration))


def test_limits_rest_and_held_joints(quick):
    config = quick.config
    t, q, dq, ddq = quick.set_points(periods=3)
    assert t.size == 3 * 2000 + 1 and t[1] == 1 / 200
    _within_limits(config, q, dq, ddq)
    # some limit is reached on every excited joint (the scaling uses the room it has)
    use = np.maximum.reduce([
        (q.max(0) - q.min(0)) / (np.array(config.upper) - np.array(config.lower)),
        np.abs(dq).max(0) / np.array(config.max_velocity),
        np.abs(ddq).max(0) / np.array(config.max_acceleration)])
    assert np.all(use[:3] > 0.9 * config.margin / 2)
    np.testing.assert_allclose(dq[[0, -1]], 0.0, atol=1e-12)
    np.testing.assert_allclose(ddq[[0, -1]], 0.0, atol=1e-12)
    np.testing.assert_allclose(q[-1], q[0], atol=1e-12)
    np.testing.assert_array_equal(q[:, 3:], np.tile(config.hold[3:], (t.size, 1)))
    assert not dq[:, 3:].any() and not ddq[:, 3:].any()


def test_derivatives_match_the_positions(quick):
    t, q, dq, ddq = quick.set_points()
    dt = t[1] - t[0]
    # central differences on a 200 Hz grid of a < 0.5 Hz signal: error ~ (w dt)^2 / 6 ~ 1e-5
    np.testing.assert_allclose(np.gradient(q, dt, axis=0)[1:-1], dq[1:-1], atol=2e-4)
    np.testing.assert_allclose(np.gradient(dq, dt, axis=0)[1:-1], ddq[1:-1], atol=5e-4)


def test_optimisation_lowers_the_condition_number(quick):
    assert quick.cond_final < 0.9 * quick.cond_initial
    # on the 200 Hz set-point grid too, not only on the optimiser's own samples
    measure = RegressorCondition(quick.config)
    fine = {name: measure(*sample_periods(quick.config, traj)[1:])
            for name, traj in (("initial", quick.initial), ("final", quick.trajectory))}
    assert fine["final"] < 0.9 * fine["initial"]
    assert np.isfinite(fine["final"])
    t, q, dq, ddq = quick.set_points()
    a = measure.matrix(q, dq, ddq)
    assert a.shape == (3 * t.size, quick.parameters)
    assert np.linalg.matrix_rank(a) == quick.parameters      # every base parameter excited


def test_seeded_and_repeatable():
    one = optimise_excitation(ExcitationConfig(iterations=3, samples=40, seed=4))
    two = optimise_excitation(ExcitationConfig(iterations=3, samples=40, seed=4))
    other = optimise_excitation(ExcitationConfig(iterations=0, samples=40, seed=5))
    np.testing.assert_array_equal(one.trajectory.a, two.trajectory.a)
    assert one.cond_final == two.cond_final
    assert not np.array_equal(one.initial.a, other.initial.a)
    assert other.cond_final == other.cond_initial and other.info["iterations"] == 0


def test_all_six_joints_and_other_limits():
    config = ExcitationConfig(joints=(1, 2, 3, 4, 5, 6), iterations=2, samples=30,
                              base_frequency_hz=0.2, harmonics=3,
                              max_velocity=(0.5, 0.5, 0.05, 1.0, 1.0, 1.0),
                              max_acceleration=(0.5, 0.5, 0.05, 2.0, 2.0, 2.0))
    result = optimise_excitation(config)
    t, q, dq, ddq = result.set_points(periods=2)
    assert t[-1] == pytest.approx(10.0)
    _within_limits(config, q, dq, ddq)
    assert np.all(np.ptp(q, axis=0) > 0)
    assert result.parameters > 24 and result.cond_final <= result.cond_initial


@pytest.mark.parametrize("values, pattern", [
    ({"upper": (0.8, 0.8, 0.30, 1.4, 1.2, 1.2)}, "leaves the PSM joint limits"),
    ({"joints": (0, 2)}, "joints must be distinct numbers in 1..6"),
    ({"joints": (1, 1)}, "joints must be distinct"),
    ({"hold": (0.0, 0.0, 0.01, 0.0, 0.0, 0.0)}, "hold .* must lie inside the box"),
    ({"max_velocity": (1.0, 1.0, 0.0, 1.0, 1.0, 1.0)}, "must be > 0"),
    ({"lower": (0.9, -0.8, 0.06, -1.4, -1.2, -1.2)}, "must lie below upper"),
    ({"harmonics": 1}, "harmonics"),
    ({"lower": (0.0,) * 5}, "lower must be 6 finite numbers"),
])
def test_bad_configuration_is_refused(values, pattern):
    with pytest.raises(ConfigError, match=pattern):
        excitation_config(**values)
