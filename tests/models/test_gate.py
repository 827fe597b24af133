"""The free-motion gate on synthetic residuals: bounds, hysteresis, contact onset, recalibration."""

import numpy as np
import pytest

from models.errors import DataError
from models.gate import FreeMotionGate, GateConfig

RATE = 200.0


def run(gate: FreeMotionGate, residuals: np.ndarray):
    return [gate.update(i, i / RATE, r) for i, r in enumerate(residuals)]


def noise(n: int, std: float = 0.05, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, std, (n, 6)) * [1, 1, 2, 0.05, 0.05, 0.05]


def test_nothing_is_free_while_warming_up_then_noise_is_free():
    cfg = GateConfig(warmup_samples=300)
    out = run(FreeMotionGate(cfg), noise(2000))
    assert not any(d.free for d in out[:300])
    assert np.mean([d.free for d in out[300:]]) > 0.99


def test_a_contact_is_detected_and_not_chopped_by_a_dip():
    r = noise(3000)
    force = np.zeros(3000)
    force[1500:1900] = np.linspace(0, 1.5, 400)       # a ramp, as a grasp builds up force
    force[1900:2300] = 1.5
    force[2000:2010] = 0.0                             # the force crosses zero for 50 ms
    r[:, 2] += force
    cfg = GateConfig(warmup_samples=500)
    out = run(FreeMotionGate(cfg), r)
    free = np.array([d.free for d in out])
    assert free[1000:1500].mean() > 0.99
    onset = 1500 + int(np.argmax(~free[1500:]))
    # found while the force still ramps: where it crosses enter_sigma x scale (floor 0.1 N)
    crossing = 1500 + int(np.argmax(force[1500:] > cfg.enter_sigma * 0.1))
    assert crossing - 15 <= onset <= crossing + 15
    assert not free[onset:2300].any()                  # one contact, the dip included
    assert free[2500:].mean() > 0.99                   # and it ends
    starts = [d.contact_started for d in out if d.contact_started >= 0]
    assert min(starts) == onset - 2                    # the index of the first sample above


def test_one_noisy_sample_does_not_start_a_contact():
    r = noise(2000)
    r[1500, 0] += 5.0
    out = run(FreeMotionGate(GateConfig(warmup_samples=500, enter_samples=3)), r)
    assert all(d.free for d in out[1000:])


def test_contact_samples_do_not_widen_the_bounds():
    gate = FreeMotionGate(GateConfig(warmup_samples=500))
    r = noise(4000)
    r[1000:3000, 0] += 2.0
    run(gate, r)
    _, std = gate.bounds()
    assert std[0] < 0.1


def test_a_lasting_change_recalibrates_instead_of_an_endless_contact():
    cfg = GateConfig(warmup_samples=500, max_contact_s=5.0)
    r = noise(5000)
    r[1000:, 0] += 1.0                                 # a new set-up, for good
    out = run(FreeMotionGate(cfg), r)
    assert any(d.recalibrated for d in out)
    assert np.mean([d.free for d in out[-1000:]]) > 0.9


def test_bad_configuration_is_refused():
    with pytest.raises(DataError):
        FreeMotionGate(GateConfig(enter_sigma=2.0, exit_sigma=3.0))
    with pytest.raises(DataError):
        FreeMotionGate(GateConfig(min_std=(0.1,) * 5))
