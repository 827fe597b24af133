"""The play operator: presliding friction with a memory of the last reversal."""

from __future__ import annotations

import numpy as np
import pytest
from wrenchd.models.errors import DataError
from wrenchd.models.physics.hysteresis import play, play_step


def test_reverses_over_twice_the_width_after_a_reversal():
    # One joint: forward 0.05 rad, back 0.05 rad, in 0.005 rad steps; width 0.01 rad.
    q = np.concatenate([np.arange(0, 0.0501, 0.005), np.arange(0.045, -0.0001, -0.005)])[:, None]
    p, z = play(q, np.array([0.01]))
    # Forward: follower still until q is 0.01 ahead, then p = +1.
    np.testing.assert_allclose(p[:4, 0], [0.0, 0.5, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(p[2:11, 0], 1.0, atol=1e-12)
    # Backward from 0.05: linear from +1 to -1 over 0.02 rad, then -1.
    np.testing.assert_allclose(p[11:16, 0], [0.5, 0.0, -0.5, -1.0, -1.0], atol=1e-12)
    assert z[0] == pytest.approx(q[-1, 0] + 0.01)
    assert np.all(np.abs(p) <= 1.0 + 1e-12)


def test_rate_independent():
    """The same path sampled ten times as densely gives the same output at the same points."""
    s = np.linspace(0.0, 4 * np.pi, 401)
    q = np.c_[0.03 * np.sin(s), 0.002 * np.cos(s)]
    fine = np.c_[0.03 * np.sin(np.linspace(0.0, 4 * np.pi, 4001)),
                 0.002 * np.cos(np.linspace(0.0, 4 * np.pi, 4001))]
    width = np.array([0.01, 0.001])
    np.testing.assert_allclose(play(fine, width)[0][::10], play(q, width)[0], atol=1e-9)


def test_causal_and_streams_like_the_batch():
    rng = np.random.default_rng(0)
    q = np.cumsum(rng.normal(0, 0.003, size=(300, 6)), axis=0)
    width = np.full(6, 0.01)
    whole, last = play(q, width)
    # Changing the future leaves the past alone.
    changed = q.copy()
    changed[150:] += 0.5
    np.testing.assert_array_equal(play(changed, width)[0][:150], whole[:150])
    # In chunks, carrying the follower, and one sample at a time for two streams.
    a, z = play(q[:77], width)
    b, z = play(q[77:], width, z)
    np.testing.assert_array_equal(np.concatenate([a, b]), whole)
    np.testing.assert_array_equal(z, last)
    follower, started, rows = np.zeros((2, 6)), np.zeros(2, dtype=bool), []
    for row in q:
        p, follower = play_step(np.stack([row, row]), width, follower, started)
        started[:] = True
        rows.append(p[1])
    np.testing.assert_allclose(np.array(rows), whole, atol=1e-15)


def test_refusals():
    with pytest.raises(DataError):
        play(np.zeros((5, 6)), np.zeros(6))
    with pytest.raises(DataError):
        play(np.zeros((5, 6)), np.ones(5))
    with pytest.raises(DataError):
        play(np.zeros((5, 6)), np.ones(6), np.zeros(3))
