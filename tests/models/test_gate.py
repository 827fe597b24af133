"""The free-motion gate on synthetic residuals: bounds, hysteresis, contact onset, the joint
score, recalibration, the block-fed scale."""

import numpy as np
import pytest

from wrenchd.models.errors import DataError
from wrenchd.models.gate import FreeMotionGate, GateConfig

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
    # found while the force still ramps: by the joint score (one joint at z, five at ~1:
    # sqrt((z^2 + 5) / 6) > joint_sigma) or at the latest where it crosses the peak bound
    # enter_sigma x scale (floor 0.1 N)
    z_joint = np.sqrt(cfg.joint_sigma ** 2 * 6 - 5)
    early = 1500 + int(np.argmax(force[1500:] > z_joint * 0.1))
    crossing = 1500 + int(np.argmax(force[1500:] > cfg.enter_sigma * 0.1))
    assert early - 15 <= onset <= crossing + cfg.enter_samples + 5
    assert not free[onset:2300].any()                  # one contact, the dip included
    assert free[2500:].mean() > 0.99                   # and it ends
    starts = [d.contact_started for d in out if d.contact_started >= 0]
    # the index of the first sample of the run above the bound that started the contact
    assert onset - min(starts) + 1 in (cfg.enter_samples, cfg.joint_samples)
    end = onset + int(np.argmax(free[onset:]))          # the first free sample after it
    # every sample of the contact, the last (that ends it) included, says where it began
    assert {d.contact_started for d in out[onset:end]} == {min(starts)}


def test_a_weak_contact_on_several_joints_is_caught_by_the_joint_score():
    """Four joints at 2.5 scale units for 1.5 s: under the peak bound, over the joint bound."""
    r = noise(3000)
    scale = np.array([0.05, 0.05, 0.1, 0.0025, 0.0025, 0.0025])   # noise RMS (floor on joint 3)
    r[1500:1800, [1, 3, 4, 5]] += 2.5 * scale[[1, 3, 4, 5]]
    cfg = GateConfig(warmup_samples=500)
    out = run(FreeMotionGate(cfg), r)
    free = np.array([d.free for d in out])
    assert not free[1540:1800].any()
    assert free[2100:].mean() > 0.99
    peak_only = run(FreeMotionGate(GateConfig(warmup_samples=500, joint_sigma=50.0,
                                              joint_exit_sigma=50.0)), r)
    assert np.mean([d.free for d in peak_only[1500:1800]]) > 0.9   # the peak alone misses it


def test_one_noisy_sample_does_not_start_a_contact():
    r = noise(2000)
    r[1500, 0] += 5.0
    out = run(FreeMotionGate(GateConfig(warmup_samples=500)), r)
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
        FreeMotionGate(GateConfig(joint_sigma=1.0, joint_exit_sigma=1.5))
    with pytest.raises(DataError):
        FreeMotionGate(GateConfig(min_std=(0.1,) * 5))


def test_the_block_fed_scale_is_the_per_sample_exponential_rms():
    """Squares handed to river once per learn_block: the same exponential memory."""
    rng = np.random.default_rng(1)
    r = rng.normal(0, 0.05, (20000, 6)) * np.linspace(1, 1.8, 20000)[:, None]
    cfg = GateConfig(warmup_samples=1000, max_growth=10.0, min_std=(1e-4,) * 6,
                     learn_sigma=1e3, enter_sigma=1e3, joint_sigma=1e3)
    gate = FreeMotionGate(cfg)
    run(gate, r)
    ms = (r[:1000] ** 2).mean(0)
    for row in r[1000:]:
        ms = cfg.alpha * row ** 2 + (1 - cfg.alpha) * ms
    np.testing.assert_allclose(gate.bounds()[1], np.sqrt(ms), rtol=2e-3)


def test_nothing_trains_for_max_contact_s_after_a_recalibration():
    """What follows a re-calibration may be the rest of a very long contact: free (published
    so), but not trainable for another ``max_contact_s``."""
    r = noise(4000)
    r[1000:, 2] += 1.5                                # a lasting step from 5 s on
    cfg = GateConfig(warmup_samples=500, max_contact_s=2.0)
    out = run(FreeMotionGate(cfg), r)
    k = next(i for i, d in enumerate(out) if d.recalibrated)
    after = out[k + 1:]
    window = int(2.0 * RATE) - 1
    assert any(d.free for d in after[:window])              # published free again at once,
    assert not any(d.trainable for d in after[:window])     # but kept out of training,
    assert np.mean([d.trainable for d in after[window + 10:]]) > 0.5   # then trains again
