"""The free-motion gate on synthetic residuals: bounds, hysteresis, contact onset, the joint
score, recalibration, the block-fed scale."""

import numpy as np
import pytest
from pydantic import ValidationError

from wrenchd.models.errors import DataError
from wrenchd.models.gate import FreeMotionGate, GateConfig, warmup_mean_square

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
    cfg = GateConfig(warmup_samples=500, release_free=False)   # the flag follows the hysteresis
    out = run(FreeMotionGate(cfg), r)
    free = np.array([d.free for d in out])
    assert free[1000:1500].mean() > 0.99
    onset = 1500 + int(np.argmax(~free[1500:]))
    # found while the force still ramps: by the joint score (one joint at z, five at ~1:
    # sqrt((z^2 + 5) / 6) > joint_sigma, z capped at joint_cap_sigma) or at the latest within
    # 0.2 s of where it crosses the peak bound enter_sigma x scale (floor 0.1 N), the noise
    # breaking the first runs over it
    z_joint = np.sqrt(cfg.joint_sigma ** 2 * 6 - 5)
    early = 1500 + int(np.argmax(force[1500:] > z_joint * 0.1))
    crossing = 1500 + int(np.argmax(force[1500:] > cfg.enter_sigma * 0.1))
    assert early - 15 <= onset <= crossing + int(0.2 * RATE)
    assert not free[onset:2300].any()                  # one contact, the dip included
    assert free[2500:].mean() > 0.99                   # and it ends
    starts = [d.contact_started for d in out if d.contact_started >= 0]
    # the index of the first sample of the run above the bound that started the contact
    assert onset - min(starts) + 1 in (cfg.enter_samples, cfg.joint_samples)
    end = onset + int(np.argmax(free[onset:]))          # the first free sample after it
    # every sample of the contact, the last (that ends it) included, says where it began
    assert {d.contact_started for d in out[onset:end]} == {min(starts)}


def dipped_contact() -> np.ndarray:
    """Noise with 1.5 N on the insertion from sample 1500 to 2300 (z = 15 at the floor), the
    force back to zero for 10 samples at 2000."""
    r = noise(3000)
    r[1500:2300, 2] += 1.5
    r[2000:2010, 2] -= 1.5
    return r


def test_a_released_contact_is_published_free_and_kept_from_training():
    """``release_free``: the published flag is free from a contact's first sample under the exit
    bounds, but the samples stay the contact's (its onset, never trainable) until it ends."""
    cfg = GateConfig(warmup_samples=500)
    assert cfg.release_free                                     # the default
    gate = FreeMotionGate(cfg)
    out = run(gate, dipped_contact())
    free = np.array([d.free for d in out])
    started = np.array([d.contact_started for d in out])
    trainable = np.array([d.trainable for d in out])
    assert gate.contacts == 1                                   # one contact, the dip included
    onset = 1500 + int(np.argmax(~free[1500:]))
    assert onset < 1500 + cfg.enter_samples + 5
    start = started[onset]
    assert free[2001:2010].all()                                # the dip: published free,
    assert not free[2010 + cfg.enter_samples + 2:2300].any()    # contact again on re-entry
    end = 2300 + int(np.argmax(started[2300:] < 0))             # the first sample of no contact
    assert free[2302:].all()                                    # published free at once,
    assert end - 2300 >= cfg.exit_s * RATE - 2                  # the contact ends exit_s later
    assert (started[onset:end] == start).all() and not trainable[onset:end].any()
    assert trainable[end + 10:].mean() > 0.6                    # max |z| < 2 of six: 0.75
    held = np.array([d.free for d in run(FreeMotionGate(cfg.model_copy(
        update={"release_free": False})), dipped_contact())])
    assert not held[onset:end - 1].any()                        # the flag held until the end


def test_a_contact_in_the_warm_up_is_not_learnt_as_free_motion():
    """A 1.5 s contact in the 5 s warm-up (yaw and pitch at 20 noise units, a wrist joint at
    20): the robust warm-up's scale is the free motion's; the plain mean square learns the
    contact and misses the next, weaker one (5 units on yaw and pitch for a second)."""
    r = noise(3000)
    r[200:500, [0, 1]] += 1.0
    r[200:500, 3] += 0.05
    r[1600:1800, [0, 1]] += 0.25
    robust, plain = (FreeMotionGate(GateConfig(warmup_samples=1000, robust_warmup=on))
                     for on in (True, False))
    out_robust, out_plain = run(robust, r[:1000]), run(plain, r[:1000])
    rms = np.sqrt(np.mean(noise(3000)[:1000] ** 2, axis=0))
    # after the warm-up the robust bounds on yaw and pitch follow the noise, the plain ones
    # are widened by the contact the warm-up saw
    np.testing.assert_allclose(robust.bounds()[1][:2], rms[:2], rtol=0.15)
    assert (plain.bounds()[1][:2] > 5 * rms[:2]).all()
    out_robust += [robust.update(i, i / RATE, r[i]) for i in range(1000, 3000)]
    out_plain += [plain.update(i, i / RATE, r[i]) for i in range(1000, 3000)]
    assert not any(d.free for d in out_robust[1640:1800])
    assert np.mean([d.free for d in out_plain[1600:1800]]) > 0.9
    # training is judged on the plain warm-up's scale: a free sample 3 robust sigmas out on
    # yaw (over train_sigma there, under it on the plain scale) still trains
    quiet = np.zeros(6)
    quiet[0] = 3.0 * robust.bounds()[1][0]
    d = robust.update(3000, 3000 / RATE, quiet)
    assert d.free and d.score > robust.config.train_sigma and d.trainable


def test_warmup_mean_square_leaves_out_samples_far_out_on_any_joint():
    rng = np.random.default_rng(3)
    r = rng.normal(0.0, [1.0, 2.0, 0.5, 0.1, 0.1, 0.1], (5000, 6))
    np.testing.assert_allclose(warmup_mean_square(r, 6.0), np.mean(r ** 2, axis=0), rtol=0.01)
    spoiled = r.copy()
    spoiled[:1500, [2, 4]] += [10.0, 2.0]                      # 30 % of the window in contact
    ms = warmup_mean_square(spoiled, 6.0)
    np.testing.assert_allclose(ms, np.mean(r[1500:] ** 2, axis=0), rtol=0.05)
    assert ms[2] < 0.01 * np.mean(spoiled[:, 2] ** 2)


def test_a_calibrated_gate_takes_over_a_contact_and_ends_it_by_its_hysteresis():
    cfg = GateConfig(warmup_samples=500)
    gate = FreeMotionGate(cfg)
    with pytest.raises(DataError):
        gate.take_over_contact(0, 0.0)                         # still warming up
    r = noise(2000)
    run(gate, r[:500])
    gate.take_over_contact(420, 500 / RATE)
    assert gate.in_contact and gate.contact_start == 420 and gate.contacts == 1
    out = [gate.update(i, i / RATE, r[i]) for i in range(500, 2000)]
    end = int(np.argmax([d.contact_started < 0 for d in out]))
    assert cfg.exit_s * RATE - 2 <= end <= cfg.exit_s * RATE + 5   # quiet: over after exit_s
    assert all(d.contact_started == 420 and not d.trainable for d in out[:end])
    assert np.mean([d.trainable for d in out[end + 10:]]) > 0.6   # max |z| < 2 of six: 0.75


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


def test_bad_configuration_is_refused_when_loaded():
    with pytest.raises(ValidationError, match="exit bound"):
        GateConfig(enter_sigma=2.0, exit_sigma=3.0)
    with pytest.raises(ValidationError, match="exit bound"):
        GateConfig(joint_sigma=1.0, joint_exit_sigma=1.5)
    with pytest.raises(ValidationError, match="min_std"):
        GateConfig.model_validate({"min_std": [0.1] * 5})


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


def test_a_fresh_gate_trains_nothing_for_exit_s():
    """A contact too weak for the enter bounds may be going on when the warm-up ends (or the
    gate takes over from the calibration guard): its samples are published free, but none
    trains until the gate has seen ``exit_s`` of them, as at the end of a contact it found."""
    cfg = GateConfig(warmup_samples=500, exit_s=0.5)
    out = run(FreeMotionGate(cfg), noise(1000))
    settled = 500 + int(cfg.exit_s * RATE) - 1                 # the warm-up ends at sample 499
    assert all(d.free for d in out[500:settled]) and not any(d.trainable for d in out[500:settled])
    assert np.mean([d.trainable for d in out[settled + 1:]]) > 0.6   # peak over 2 sigma: 1 in 4

    gate = FreeMotionGate(cfg)
    gate.seed(np.full(6, 0.05))
    gate.settle(10.0)                                          # a hand-over at t = 10 s
    r = noise(300)
    assert not any(gate.update(i, 10.0 + i / RATE, x).trainable for i, x in enumerate(r[:99]))
    assert np.mean([gate.update(i, 10.5 + i / RATE, x).trainable
                    for i, x in enumerate(r[100:])]) > 0.6


def test_a_prior_keeps_the_warm_up_scale_within_one_and_max_growth_times_it():
    """A warm-up on a contact would start the gate wide, one on a quiet stretch narrow: with
    a prior (the calibration's free-motion RMS) the warm-up's scale stays within it."""
    prior = np.array([0.05, 0.05, 0.1, 0.0025, 0.0025, 0.0025])
    cfg = GateConfig(warmup_samples=500)
    loud = noise(600, std=0.5)                       # ten times the prior's level
    quiet = noise(600, std=0.005)
    for r, expect in ((loud, cfg.max_growth * prior), (quiet, prior)):
        gate = FreeMotionGate(cfg)
        gate.reset(prior=prior)
        run(gate, r)
        np.testing.assert_allclose(gate.bounds()[1], np.maximum(expect, cfg.min_std), rtol=0.05)
        free = FreeMotionGate(cfg)                    # without the prior: the warm-up's own
        run(free, r)
        assert not np.allclose(free.bounds()[1], gate.bounds()[1], rtol=0.3)
    with pytest.raises(DataError):
        FreeMotionGate(cfg).reset(prior=np.full(5, 0.1))


@pytest.mark.parametrize("joints", [[2], [0, 1, 2, 3, 4, 5]])
def test_after_a_drift_a_contact_must_clear_higher_enter_bounds_for_drift_caution_s(joints):
    """A push 1.15x the enter bounds (peak score, or the joint score on every joint) enters
    before a drift and after ``drift_caution_s``, not within it (bounds 1.25x higher)."""
    cfg = GateConfig(warmup_samples=500)
    gate = FreeMotionGate(cfg)
    run(gate, noise(1000))
    bound = cfg.enter_sigma if len(joints) == 1 else cfg.joint_sigma
    push = np.zeros(6)
    push[joints] = 1.15 * bound * gate.scale.std[joints]

    def entered(start: int) -> bool:
        out = [gate.update(i, i / RATE, push) for i in range(start, start + 60)]
        for i in range(start + 60, start + 400):          # free again, the contact over
            gate.update(i, i / RATE, np.zeros(6))
        return any(not d.free for d in out)

    assert entered(1000)
    gate.drifted(2000 / RATE)
    assert not entered(2000)                               # within drift_caution_s
    assert entered(2000 + int(cfg.drift_caution_s * RATE) + 10)
