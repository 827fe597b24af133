"""A gate seeded with a known free-motion scale judges from its first sample."""

from __future__ import annotations

import numpy as np
import pytest

from wrenchd.models.errors import DataError
from wrenchd.models.gate import FreeMotionGate, GateConfig

SCALE = np.array([0.14, 0.09, 0.09, 0.001, 0.0024, 0.0023])   # seal's validation RMSE [N m; N]


def _run(gate: FreeMotionGate, residual: np.ndarray) -> list:
    return [gate.update(i, i / 200.0, r) for i, r in enumerate(residual)]


def test_seeded_gate_judges_from_the_first_sample():
    rng = np.random.default_rng(0)
    free = rng.normal(size=(400, 6)) * SCALE                   # free motion at its scale
    contact = free + np.array([0.0, 0.0, 3.0, 0.0, 0.0, 0.0])   # 3 N along the shaft
    residual = np.concatenate([free, contact])
    seeded = FreeMotionGate(GateConfig())
    seeded.seed(SCALE)
    decisions = _run(seeded, residual)
    assert np.mean([d.free for d in decisions[:400]]) > 0.95
    first = next(i for i, d in enumerate(decisions) if not d.free and i >= 400)
    assert first < 400 + GateConfig().enter_samples + 2
    assert decisions[first].contact_started == 400
    # unseeded, the same contact falls in the warm-up and is learned as free motion
    plain = _run(FreeMotionGate(GateConfig()), residual)
    assert not any(d.free for d in plain)            # calls nothing during its warm-up
    assert plain[-1].score < GateConfig().enter_sigma


def test_seed_is_floored_and_checked():
    gate = FreeMotionGate(GateConfig())
    gate.seed(np.zeros(6))
    assert np.allclose(gate.bounds()[1], GateConfig().min_std)
    assert gate.calibrated
    with pytest.raises(DataError):
        gate.seed(np.ones(5))
    with pytest.raises(DataError):
        gate.seed(np.array([np.nan, 1, 1, 1, 1, 1]))


def test_rescale_moves_the_scale_and_keeps_a_contact_going():
    gate = FreeMotionGate(GateConfig())
    with pytest.raises(DataError):                   # a warming-up gate has no scale to move
        gate.rescale(SCALE)
    gate.seed(SCALE)
    push = np.array([0.0, 0.0, 3.0, 0.0, 0.0, 0.0])      # 3 N along the shaft: 33 x its scale
    decisions = _run(gate, np.tile(push, (40, 1)))
    assert not decisions[-1].free
    gate.rescale(2 * SCALE)
    np.testing.assert_allclose(gate.bounds()[1], np.maximum(2 * SCALE, GateConfig().min_std))
    assert gate.in_contact                            # the contact in progress goes on
    after = gate.update(40, 0.2, push)
    assert not after.free and after.contact_started == 0
    # a level far above the push: the push now scores under the exit bound
    gate.rescale(np.full(6, 10.0))
    assert gate.update(41, 1.5, push).score < GateConfig().exit_sigma
    with pytest.raises(DataError):
        gate.rescale(np.ones(5))
