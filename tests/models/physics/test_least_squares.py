"""Rigid body + friction by least squares, and the causal acceleration filter."""

from __future__ import annotations

import numpy as np
import pytest
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.physics.causal_acceleration import (
    CausalAcceleration,
    CausalAccelerationConfig,
)
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.physics.least_squares import (
    PLAIN_LEAST_SQUARES,
    LeastSquaresConfig,
    RigidBodyFrictionModel,
    smoothed_acceleration,
)

DT = 0.005


def motion(seconds=10.0, seed=0):
    """Sums of sines per joint (0.2 to 1.5 Hz): positions, velocities, accelerations."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds / DT)) * DT
    f = rng.uniform(0.2, 1.5, size=(3, 6))
    amp = rng.uniform(0.05, 0.2, size=(3, 6)) * np.array([1, 1, 0.2, 1, 1, 1])
    ph = rng.uniform(0, 2 * np.pi, size=(3, 6))
    w = 2 * np.pi * f
    arg = w[None] * t[:, None, None] + ph[None]
    q = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0]) + (amp * np.sin(arg)).sum(1)
    dq = (amp * w * np.cos(arg)).sum(1)
    ddq = -(amp * w ** 2 * np.sin(arg)).sum(1)
    return q, dq, ddq


def test_fit_reproduces_torques_the_columns_can_express():
    q, dq, ddq = motion()
    rigid = RigidBodyModel()
    for config in (LeastSquaresConfig(), PLAIN_LEAST_SQUARES):
        cols = RigidBodyFrictionModel.columns(rigid, q, dq, ddq, config)
        assert cols.shape == (len(q), 6, RigidBodyFrictionModel.n_columns(config))
        truth = np.random.default_rng(1).normal(size=cols.shape[2]) * 0.01
        tau = cols @ truth
        model = RigidBodyFrictionModel.fit(q, dq, ddq, tau, rigid, config)
        err = np.abs(model.predict(q, dq, ddq, rigid) - tau).max()
        assert err < 1e-3 * np.abs(tau).max(), err
        again = RigidBodyFrictionModel.from_dict(model.to_dict())
        np.testing.assert_array_equal(again.coefficients, model.coefficients)
        assert again.config == config
    assert RigidBodyFrictionModel.n_columns(LeastSquaresConfig()) == 90
    assert RigidBodyFrictionModel.n_columns(PLAIN_LEAST_SQUARES) == 84


def test_predict_is_the_columns_times_the_coefficients():
    """predict builds only the rigid body's columns; the friction columns it adds joint by
    joint give the full regressor's torques, with the presliding column given or not."""
    q, dq, ddq = motion(seconds=2.0, seed=3)
    rigid = RigidBodyModel()
    rng = np.random.default_rng(2)
    for config in (LeastSquaresConfig(hysteresis_width=(0.01,) * 6), PLAIN_LEAST_SQUARES):
        model = RigidBodyFrictionModel(rng.normal(size=RigidBodyFrictionModel.n_columns(config)),
                                       1, config)
        full = RigidBodyFrictionModel.columns(rigid, q, dq, ddq, config) @ model.coefficients
        np.testing.assert_allclose(model.predict(q, dq, ddq, rigid), full, rtol=1e-12,
                                   atol=1e-12 * np.abs(full).max())
        p = RigidBodyFrictionModel.presliding(q, config)
        if p is not None:
            shifted = p * 0.5
            full = (RigidBodyFrictionModel.columns(rigid, q, dq, ddq, config, shifted)
                    @ model.coefficients)
            np.testing.assert_allclose(model.predict(q, dq, ddq, rigid, shifted), full,
                                       rtol=1e-12, atol=1e-12 * np.abs(full).max())


def test_bad_parameter_sets_are_refused():
    d = RigidBodyFrictionModel(np.zeros(90), 1).to_dict()
    d["coefficients"] = d["coefficients"][:-1]
    with pytest.raises(ConfigError):
        RigidBodyFrictionModel.from_dict(d)
    with pytest.raises(ConfigError):
        RigidBodyFrictionModel.from_dict({"rank": 3})
    q, dq, ddq = motion(1.0)
    with pytest.raises(DataError):
        RigidBodyFrictionModel.fit(q, dq, ddq, np.zeros((len(q), 5)))


def test_causal_acceleration_tracks_the_derivative_without_the_future():
    _, dq, _ = motion(20.0)
    ca = CausalAcceleration.fit([dq], DT)
    _, held_dq, held_ddq = motion(10.0, seed=3)           # other frequencies and phases
    est = ca.estimate(held_dq)
    err = np.sqrt(np.mean((est - held_ddq)[ca.taps:] ** 2, 0))
    # Noise-free smooth motion: a few per cent of the acceleration's RMS.
    assert np.all(err < 0.05 * held_ddq.std(0)), (err, held_ddq.std(0))
    # Causal: changing the future does not change the past.
    changed = held_dq.copy()
    changed[500:] += 1.0
    np.testing.assert_array_equal(ca.estimate(changed)[:500], est[:500])


def test_causal_acceleration_streams_like_the_batch():
    _, dq, _ = motion(3.0)
    ca = CausalAcceleration.fit([dq], DT, CausalAccelerationConfig(taps=16))
    batch = ca.estimate(dq)
    state, rows = ca.initial_state(1), []
    for v in dq:
        a, state = ca.step(v[None], state)
        rows.append(a[0])
    np.testing.assert_allclose(np.array(rows), batch, atol=1e-12)
    first, s = ca.run(dq[:7], ca.initial_state(1))
    rest, _ = ca.run(dq[7:], s)
    np.testing.assert_allclose(np.concatenate([first, rest]), batch, atol=1e-12)


def test_a_lookahead_filter_reads_the_future_and_does_not_stream():
    _, dq, _ = motion(20.0)
    _, held_dq, held_ddq = motion(10.0, seed=3)
    causal = CausalAcceleration.fit([dq], DT)
    ahead = CausalAcceleration.fit([dq], DT, CausalAccelerationConfig(lookahead_s=5 * DT))
    assert ahead.lookahead == 5 and causal.lookahead == 0

    def err(ca):
        return np.sqrt(np.mean((ca.estimate(held_dq) - held_ddq)[ca.taps:-ca.taps] ** 2))

    # Five samples of the future halve the error at least (the target is the centred
    # derivative, which reads ten ahead).
    assert err(ahead) < 0.5 * err(causal), (err(ahead), err(causal))
    changed = held_dq.copy()
    changed[500:] += 1.0
    est, est_changed = ahead.estimate(held_dq), ahead.estimate(changed)
    np.testing.assert_array_equal(est_changed[:495], est[:495])
    assert not np.allclose(est_changed[495:500], est[495:500])
    with pytest.raises(ConfigError, match="cannot stream"):
        ahead.step(held_dq[:1], ahead.initial_state(1))
    with pytest.raises(ConfigError, match="cannot stream"):
        ahead.run(held_dq[:10], ahead.initial_state(1))
    with pytest.raises(ConfigError, match="taps"):
        CausalAcceleration.fit([dq], DT, CausalAccelerationConfig(taps=8, lookahead_s=8 * DT))


def test_causal_acceleration_refusals():
    with pytest.raises(DataError):
        CausalAcceleration.fit([np.zeros((5, 6))], DT)         # shorter than the target window
    with pytest.raises(ValueError):
        CausalAccelerationConfig(groups=((0, 1), (2,)))
    with pytest.raises(ConfigError):
        CausalAcceleration(np.zeros((6, 1)), DT)
    with pytest.raises(DataError):
        smoothed_acceleration(np.zeros((3, 6)), DT)


def test_presliding_columns_recover_known_friction():
    """Torques simulated from the columns with a presliding friction: the fit recovers the six
    presliding coefficients, and the columns without them cannot express those torques."""
    q, dq, ddq = motion(12.0, seed=5)
    rigid = RigidBodyModel()
    config = LeastSquaresConfig(hysteresis_width=(0.01, 0.01, 0.001, 0.01, 0.01, 0.01),
                                rcond=1e-10)
    cols = RigidBodyFrictionModel.columns(rigid, q, dq, ddq, config)
    assert cols.shape[2] == RigidBodyFrictionModel.n_columns(config) == 96
    truth = np.random.default_rng(2).normal(size=cols.shape[2]) * 0.01
    fh = np.array([0.05, 0.04, 0.3, 0.002, 0.001, 0.001])      # [N m, N m, N, N m, ...]
    truth[-6:] = fh
    tau = cols @ truth
    model = RigidBodyFrictionModel.fit(q, dq, ddq, tau, rigid, config)
    np.testing.assert_allclose(model.coefficients[-6:], fh, rtol=1e-6)
    assert np.abs(model.predict(q, dq, ddq, rigid) - tau).max() < 1e-6 * np.abs(tau).max()
    without = RigidBodyFrictionModel.fit(q, dq, ddq, tau, rigid,
                                         LeastSquaresConfig(rcond=1e-10))
    miss = np.sqrt(np.mean((without.predict(q, dq, ddq, rigid) - tau) ** 2, axis=0))
    assert np.all(miss > 0.1 * fh), (miss, fh)
    # A stream that continues: the presliding state carried over gives the whole segment's
    # columns; restarting at the cut does not.
    from wrenchd.models.physics.hysteresis import play

    width = np.array(config.hysteresis_width)
    _, follower = play(q[:1000], width)
    carried = play(q[1000:], width, follower)[0]
    whole = model.predict(q, dq, ddq, rigid)
    np.testing.assert_allclose(model.predict(q[1000:], dq[1000:], ddq[1000:], rigid, carried),
                               whole[1000:], atol=1e-12)
    assert not np.allclose(model.predict(q[1000:], dq[1000:], ddq[1000:], rigid),
                           whole[1000:], atol=1e-6)
    again = RigidBodyFrictionModel.from_dict(model.to_dict())
    assert again.config == config
    with pytest.raises(ValueError):
        LeastSquaresConfig(hysteresis_width=(0.01, 0.0, 0.001, 0.01, 0.01, 0.01))
    with pytest.raises(DataError):
        model.predict(q, dq, ddq, rigid, carried)                # wrong length
