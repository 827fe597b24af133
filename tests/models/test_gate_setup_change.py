"""The gate tells a lasting set-up change from a lasting contact at the tip by the tip force
it implies: one that swings with the pose is re-learnt within ``setup_contact_s``, one that
keeps its direction is never trained on; the scale a re-learning starts from is the
contact's level, not one sample's."""

import numpy as np

from wrenchd.models.contact_hysteresis import SETUP_STRIDE
from wrenchd.models.gate import FreeMotionGate, GateConfig
from wrenchd.models.residual_scale import warmup_mean_square

RATE = 200.0
N = 200 * 60                                   # a minute of samples
CHANGE = 2000                                   # the load or the contact from 10 s on


def pose(n: int) -> np.ndarray:
    """(n,) yaw angle of a slow periodic motion [rad]."""
    t = np.arange(n) / RATE
    return 0.8 * np.sin(2 * np.pi * t / 6.5)


def noise(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, 0.02, (n, 6)) * [1, 1, 5, 0.1, 0.1, 0.1]


def lever(yaw: np.ndarray) -> np.ndarray:
    """(n, 3, 2) how a world force in the horizontal plane loads yaw and pitch [m], a lever
    of 0.2 m turned by the yaw (the tip force seen through J^T)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return 0.2 * np.stack([np.stack([-s, c], -1), np.stack([c, s], -1),
                           np.zeros((len(yaw), 2))], 1)


def run(gate, residual, force):
    return [gate.update(i, i / RATE, r, None, f) for i, (r, f) in
            enumerate(zip(residual, force))]


def session(load: str):
    """Residuals and tip forces: free motion, then from CHANGE on either a weight on a link
    (its torque on yaw and pitch a smooth function of the pose; the tip force J^-T of it
    turns with the pose) or a steady 2 N push at the tip (of the same torque size)."""
    yaw = pose(N)
    r, f = noise(N), np.random.default_rng(1).normal(0.0, 0.1, (N, 3))
    jac = lever(yaw)                                          # (n, 3, 2)
    if load == "setup":                     # 2 N of weight on a link that turns against yaw
        tau = np.einsum("nij,i->nj", lever(-yaw), [0.0, 2.0, 0.0])
        push = np.linalg.solve(jac[:, :2, :].transpose(0, 2, 1), tau[..., None])[..., 0]
        world = np.concatenate([push, np.zeros((N, 1))], 1)
    else:
        world = np.tile([2.0, 0.0, 0.0], (N, 1))
        tau = np.einsum("nij,ni->nj", jac, world)
    r[CHANGE:, :2] += tau[CHANGE:]
    f[CHANGE:] += world[CHANGE:]
    return r, f


def test_a_load_that_follows_the_pose_is_re_learnt_and_trains_again():
    cfg = GateConfig(warmup_samples=1000)
    out = run(FreeMotionGate(cfg), *session("setup"))
    k = next(i for i, d in enumerate(out) if d.setup_change)
    assert out[k].recalibrated
    assert CHANGE < k <= CHANGE + (cfg.setup_contact_s + 1.0) * RATE
    probation = int(cfg.setup_probation_s * RATE)
    assert not any(d.trainable for d in out[k:k + probation])
    assert np.mean([d.trainable for d in out[k + probation:]]) > 0.5


def test_a_steady_push_at_the_tip_of_the_same_size_is_never_trained_on():
    cfg = GateConfig(warmup_samples=1000)               # max_contact_s (60 s) is not reached
    out = run(FreeMotionGate(cfg), *session("push"))
    assert not any(d.setup_change or d.recalibrated for d in out)
    assert not any(d.trainable for d in out[CHANGE:])
    assert np.mean([not d.free for d in out[CHANGE + 200:]]) > 0.95


def test_without_a_tip_force_only_max_contact_s_ends_a_lasting_contact():
    cfg = GateConfig(warmup_samples=1000, max_contact_s=30.0)
    r, _ = session("setup")
    out = [FreeMotionGate.update(g, i, i / RATE, x) for g in [FreeMotionGate(cfg)]
           for i, x in enumerate(r)]
    k = next(i for i, d in enumerate(out) if d.recalibrated)
    assert not any(d.setup_change for d in out)
    assert k > CHANGE + 29.0 * RATE


def test_a_re_learnt_scale_is_the_contact_level_not_one_sample():
    """After a lasting change the scale restarts on the RMS of the contact's residual (its
    samples within the trim bound), on every joint, not on whatever the last sample was."""
    cfg = GateConfig(warmup_samples=1000, max_contact_s=20.0, setup_contact_s=0.0)
    r = 3.0 * noise(N, seed=3)                       # three times the floor on every joint
    r[CHANGE:, 0] += 0.45                           # 7.5 x the noise: a clear, lasting step
    gate = FreeMotionGate(cfg)
    for i, x in enumerate(r):
        if gate.update(i, i / RATE, x).recalibrated:
            break
    assert CHANGE + 20.0 * RATE <= i <= CHANGE + 21.0 * RATE
    level = np.sqrt(np.mean(r[CHANGE + 50:i] ** 2, axis=0))   # the contact's samples
    np.testing.assert_allclose(gate.bounds()[1], level, rtol=0.15)


def test_a_load_the_gate_keeps_ending_and_finding_again_counts_as_one_lasting_contact():
    """A residual about the exit bounds ends the contact now and then (here the load is
    off for 0.6 s every 3 s) and the next sample run over the enter bounds starts another:
    contacts less than setup_gap_s apart are judged as one."""
    r, f = session("setup")
    off = (np.arange(N) - CHANGE) % 600 >= 480                  # 0.6 s of every 3 s
    r[CHANGE:, :2] = np.where(off[CHANGE:, None], noise(N - CHANGE, seed=4)[:, :2],
                              r[CHANGE:, :2])
    f[CHANGE:] = np.where(off[CHANGE:, None], 0.0, f[CHANGE:])
    chained = run(FreeMotionGate(GateConfig(warmup_samples=1000)), r, f)
    assert sum(d.contact_started >= 0 and not out.contact_started >= 0
               for out, d in zip(chained, chained[1:])) >= 2    # found again
    k = next(i for i, d in enumerate(chained) if d.setup_change)
    assert k <= CHANGE + 11.0 * RATE
    # judged contact by contact, only a later one lasts setup_contact_s
    apart = run(FreeMotionGate(GateConfig(warmup_samples=1000, setup_gap_s=0.0)), r, f)
    assert next(i for i, d in enumerate(apart) if d.setup_change) > CHANGE + 11.0 * RATE


def test_a_lasting_force_of_several_newtons_is_a_contact_whatever_its_direction_does():
    """A grasp of several newtons held for seconds may swing with the pose too (a handle
    pulled about); over setup_max_force_n it is never taken for a set-up change."""
    r, f = session("setup")
    r[CHANGE:, :2] = noise(N)[CHANGE:, :2] + 4.0 * (r[CHANGE:, :2] - noise(N)[CHANGE:, :2])
    f[CHANGE:] *= 4.0                                         # 8 N of weight instead of 2 N
    cfg = GateConfig(warmup_samples=1000)
    out = run(FreeMotionGate(cfg), r, f)
    assert np.sqrt(np.mean(np.sum(f[CHANGE:] ** 2, axis=1))) > cfg.setup_max_force_n
    assert not any(d.setup_change for d in out)
    assert not any(d.trainable for d in out[CHANGE:])


def run_announced(gate, residual, force, at, until_setup=False):
    """:func:`run`, with a set-up change announced before sample ``at``; to the set-up
    change found where ``until_setup``."""
    out = []
    for i, (r, f) in enumerate(zip(residual, force)):
        if i == at:
            gate.announce(i / RATE)
        out.append(gate.update(i, i / RATE, r, None, f))
        if until_setup and out[-1].setup_change:
            break
    return out


def test_an_announced_change_is_re_learnt_within_announced_setup_s_of_its_announcement():
    cfg = GateConfig(warmup_samples=1000)
    r, f = session("setup")
    at = CHANGE + 400                           # announced 2 s into the hold it causes
    held = FreeMotionGate(cfg)
    run(held, r[:at], f[:at])
    before = held.bounds()[1]                   # the scale when the change is announced
    gate = FreeMotionGate(cfg)
    out = run_announced(gate, r, f, at, until_setup=True)
    k = len(out) - 1
    assert out[k].setup_change
    assert at + (cfg.announced_setup_s - 0.1) * RATE <= k <= at + (
        cfg.announced_setup_s + 0.1) * RATE, k
    # from the seconds since the announcement, widened, never narrower than before it
    after = gate.bounds()[1]
    assert (after >= before).all()
    level = np.sqrt(warmup_mean_square(r[at:k:SETUP_STRIDE], cfg.warmup_trim_sigma))
    np.testing.assert_allclose(after[:2], cfg.announced_widen * level[:2], rtol=0.05)
    # unannounced, the same change waits for setup_contact_s
    late = next(i for i, d in enumerate(run(FreeMotionGate(cfg), r, f)) if d.setup_change)
    assert late >= CHANGE + cfg.setup_contact_s * RATE


def test_a_push_at_the_tip_after_an_announced_change_is_still_a_contact():
    """The announcement makes the check early, not its verdict: a steady push that starts
    when a change is announced keeps its direction, and is never trained on."""
    cfg = GateConfig(warmup_samples=1000)
    out = run_announced(FreeMotionGate(cfg), *session("push"), CHANGE)
    assert not any(d.setup_change or d.recalibrated for d in out)
    assert not any(d.trainable for d in out[CHANGE:])


def test_a_contact_long_after_an_announcement_waits_for_setup_contact_s():
    cfg = GateConfig(warmup_samples=1000)
    r, f = session("setup")
    out = run_announced(FreeMotionGate(cfg), r, f, CHANGE - int(
        (cfg.announced_setup_s + 1.0) * RATE))
    k = next(i for i, d in enumerate(out) if d.setup_change)
    assert k >= CHANGE + cfg.setup_contact_s * RATE
