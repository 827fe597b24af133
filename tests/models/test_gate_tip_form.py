"""A contact at the tip is a force there: the gate's tip-form check (``tip_setup_s``, with the
arm's kinematics) re-learns within seconds a lasting residual no tip force makes and whose tip
force swings with the pose, and keeps a push at the tip a contact however long it lasts."""

import numpy as np
import pytest

from wrenchd.models.contact_hysteresis import HOLD_ROWS, SETUP_STRIDE, tip_force_misfit
from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.models.gate import FreeMotionGate, GateConfig

RATE = 200.0
N = int(40 * RATE)
CHANGE = int(15 * RATE)                          # the load or the contact from 15 s on
STD = np.array([0.02, 0.02, 0.1, 0.002, 0.002, 0.002])   # the free residual's spread
WRENCH = WrenchMap()


def motion(n: int = N) -> np.ndarray:
    """(n, 6) a slow periodic motion of the PSM over its workspace [rad; m]."""
    t = np.arange(n)[:, None] / RATE
    period = np.array([6.5, 5.1, 7.3, 4.3, 3.7, 5.9])
    centre = np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
    amp = np.array([0.7, 0.5, 0.05, 1.0, 0.7, 0.7])
    return centre + amp * np.sin(2 * np.pi * t / period)


def session(load: str | None, seed: int = 0):
    """(positions, residuals, wrenches): free motion's noise, and from CHANGE on a steady
    2 N push at the tip, a 2 N push at the tip whose direction turns with the yaw, or torques
    no tip force makes, which follow the pose."""
    q = motion()
    r = np.random.default_rng(seed).normal(0.0, 1.0, (N, 6)) * STD
    if load == "push":
        jac = WRENCH.kinematics.jacobian(q[CHANGE:], "hybrid")
        r[CHANGE:] += np.einsum("nji,j->ni", jac[:, :3, :], [0.0, 2.0, 0.0])
    elif load == "turning push":
        jac = WRENCH.kinematics.jacobian(q[CHANGE:], "hybrid")
        yaw = 4.0 * q[CHANGE:, 0]
        f = 2.0 * np.stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)], 1)
        r[CHANGE:] += np.einsum("nji,nj->ni", jac[:, :3, :], f)
    elif load == "setup":                 # about 8 x the spread on every joint, with the pose
        r[CHANGE:] += 8.0 * STD * np.sin(q[CHANGE:] * [3.0, 4.0, 40.0, 2.0, 3.0, 2.5] + 1.0)
    return q, r, WRENCH.wrench_batch(q, r)


def run(gate: FreeMotionGate, q, r, w, *, positions: bool = True):
    return [gate.update(i, i / RATE, r[i], None, w[i], q[i] if positions else None)
            for i in range(N)]


def test_a_tip_force_leaves_nothing_a_moment_or_noise_leaves_about_half():
    q = motion(50)
    jac = WRENCH.kinematics.jacobian(q, "hybrid")
    push = np.einsum("nji,j->ni", jac[:, :3, :], [1.0, -2.0, 0.5])
    twist = np.einsum("nji,j->ni", jac[:, 3:, :], [0.01, 0.0, 0.0])
    noise = np.random.default_rng(0).normal(0.0, 1.0, (50, 6)) * STD
    assert tip_force_misfit(jac, push, STD).max() < 1e-9
    assert np.median(tip_force_misfit(jac, twist, STD)) > 0.3
    assert 0.3 < np.mean(tip_force_misfit(jac, noise, STD)) < 0.7


def test_a_residual_no_tip_force_makes_is_re_learnt_within_seconds():
    cfg = GateConfig(warmup_samples=1000)
    gate = FreeMotionGate(cfg, WRENCH.kinematics)
    out = run(gate, *session("setup"))
    k = next(i for i, d in enumerate(out) if d.setup_change)
    assert CHANGE < k <= CHANGE + (2 * cfg.tip_setup_s + 0.5) * RATE
    assert k < CHANGE + cfg.setup_contact_s * RATE
    # re-learnt as an announced change is: widened, so the rest of it is free motion
    assert np.mean([d.free for d in out[k + 200:]]) > 0.95
    assert gate.setup_changes == 1


def test_without_positions_or_kinematics_the_same_residual_waits_for_setup_contact_s():
    cfg = GateConfig(warmup_samples=1000)
    for gate, positions in ((FreeMotionGate(cfg, WRENCH.kinematics), False),
                            (FreeMotionGate(cfg), True)):
        out = run(gate, *session("setup"), positions=positions)
        k = next(i for i, d in enumerate(out) if d.setup_change or d.recalibrated)
        assert k >= CHANGE + cfg.setup_contact_s * RATE


@pytest.mark.parametrize("tip_setup_s", [2.0, 0.5])
def test_a_steady_push_at_the_tip_stays_a_contact(tip_setup_s):
    cfg = GateConfig(warmup_samples=1000, tip_setup_s=tip_setup_s)
    out = run(FreeMotionGate(cfg, WRENCH.kinematics), *session("push"))
    assert not any(d.setup_change or d.recalibrated for d in out)
    assert not any(d.trainable for d in out[CHANGE:])
    assert np.mean([not d.free for d in out[CHANGE + 100:]]) > 0.95


def test_a_push_at_the_tip_that_turns_with_the_pose_is_no_set_up_change_before_setup_contact_s():
    """Its tip force swings as a set-up change's does; its form is a tip force's."""
    cfg = GateConfig(warmup_samples=1000)
    out = run(FreeMotionGate(cfg, WRENCH.kinematics), *session("turning push"))
    end = CHANGE + int(cfg.setup_contact_s * RATE)
    assert not any(d.setup_change or d.recalibrated for d in out[:end])
    assert np.mean([not d.free for d in out[CHANGE + 100:end]]) > 0.95
    # the 10 s check on the swing alone calls it one (a push that turns round for 10 s)
    assert any(d.setup_change for d in out[end:])


def test_a_contact_s_tail_is_not_judged_on_its_form():
    """A push that ends while the gate still holds the contact (a long ``exit_s``): the
    samples after it are free motion's error, which no tip force explains and whose fitted
    force swings. Only the samples over the exit bounds are judged on their form."""
    cfg = GateConfig(warmup_samples=1000, exit_s=2.5)
    q, r, _ = session("push")
    end = CHANGE + int(1.0 * RATE)                      # a 1 s push, then free motion
    r[end:] = np.random.default_rng(5).normal(0.0, 1.0, (N - end, 6)) * STD
    out = run(FreeMotionGate(cfg, WRENCH.kinematics), q, r, WRENCH.wrench_batch(q, r))
    assert not out[CHANGE + 100].free
    assert not any(d.setup_change for d in out[:CHANGE + int(cfg.setup_contact_s * RATE)])


def called_on_form(until_s: float, cfg: GateConfig):
    """A residual no tip force makes from CHANGE until ``until_s`` [s] after it, then free
    motion again: (decisions, gate, the scale just before the call)."""
    q, r, _ = session("setup")
    end = CHANGE + int(until_s * RATE)
    r[end:] = np.random.default_rng(7).normal(0.0, 1.0, (N - end, 6)) * STD
    gate = FreeMotionGate(cfg, WRENCH.kinematics)
    w = WRENCH.wrench_batch(q, r)
    out, before = [], None
    for i in range(N):
        std = gate.scale.std.copy()
        out.append(gate.update(i, i / RATE, r[i], None, w[i], q[i]))
        if out[-1].setup_change:
            before = std
    return out, gate, before


def test_a_form_call_whose_residual_ends_soon_after_is_withdrawn_and_the_scale_comes_back():
    """Taken for a set-up change on its form, then gone within ``form_withdraw_s``: on the
    scale before the call the residual is free motion's again, so it was a contact."""
    cfg = GateConfig(warmup_samples=1000)
    out, gate, before = called_on_form(3.0, cfg)
    k = next(i for i, d in enumerate(out) if d.setup_change)
    (back,) = [i for i, d in enumerate(out) if d.setup_withdrawn]
    end = CHANGE + int(3.0 * RATE)
    assert k < end <= back <= end + (cfg.exit_s + 0.5) * RATE
    np.testing.assert_allclose(gate.scale.std, before, rtol=0.05)
    assert gate.withdrawn == 1 and gate.setup_changes == 1

    kept, kept_gate, _ = called_on_form(3.0, GateConfig(warmup_samples=1000, form_withdraw_s=0))
    assert not any(d.setup_withdrawn for d in kept) and kept_gate.withdrawn == 0
    assert np.all(kept_gate.scale.std > 1.5 * before)          # still the widened scale


def test_a_lasting_residual_called_on_its_form_is_not_withdrawn():
    cfg = GateConfig(warmup_samples=1000)
    gate = FreeMotionGate(cfg, WRENCH.kinematics)
    out = run(gate, *session("setup"))
    assert any(d.setup_change for d in out)
    assert not any(d.setup_withdrawn for d in out) and gate.withdrawn == 0


def test_a_form_call_made_while_the_contact_s_end_was_pending_stands():
    """A residual no tip force makes, on and off (a set-up change swinging with the pose is
    quiet at times): a call made just as it went quiet, the contact's end pending, is not
    withdrawn when the residual, back for 1.4 s, goes quiet again."""
    cfg = GateConfig(warmup_samples=1000)
    q, r, _ = session("setup")
    quiet = np.random.default_rng(9).normal(0.0, 1.0, (N, 6)) * STD
    off = np.zeros(N, bool)
    for a, b in ((1.9, 3.0), (5.0, 5.6), (7.0, 25.0)):       # [s] after CHANGE
        off[CHANGE + int(a * RATE):CHANGE + int(b * RATE)] = True
    r[off] = quiet[off]
    gate = FreeMotionGate(cfg, WRENCH.kinematics)
    calls = []
    for i, w in enumerate(WRENCH.wrench_batch(q, r)):
        if gate.update(i, i / RATE, r[i], None, w, q[i]).setup_change:
            calls.append((i, gate.contact.exiting))
    assert [e for _, e in calls] == [True]
    assert CHANGE + 5.0 * RATE < calls[0][0] < CHANGE + 5.6 * RATE
    assert gate.withdrawn == 0


def run_announced(cfg: GateConfig, load: str, at: int):
    """The session with a set-up change announced at sample ``at``: (decisions, gate)."""
    q, r, w = session(load)
    gate = FreeMotionGate(cfg, WRENCH.kinematics)
    out = []
    for i in range(N):
        if i == at:
            gate.announce(i / RATE)
        out.append(gate.update(i, i / RATE, r[i], None, w[i], q[i]))
    return out, gate


def first_flag(out) -> int:
    return next(i for i, d in enumerate(out) if not d.free and i >= CHANGE)


def test_a_residual_no_tip_force_makes_just_after_an_announcement_is_never_published():
    """Withheld (``announced_hold_s``, on by default) until its announced check calls it a
    set-up change; without the hold the same residual is published as a contact until
    then."""
    held = GateConfig(warmup_samples=1000)
    out, gate = run_announced(held, "setup", CHANGE)
    (k,) = [i for i, d in enumerate(out) if d.setup_change]
    assert abs(k - (CHANGE + held.announced_setup_s * RATE)) <= SETUP_STRIDE + 1
    assert all(d.free for d in out[CHANGE:k + 1])
    assert not any(d.trainable for d in out[CHANGE:k + 1])
    assert gate.contact.withheld is False and gate.withheld_contacts == 1

    plain, _ = run_announced(GateConfig(warmup_samples=1000, announced_hold_s=0), "setup", CHANGE)
    assert np.mean([not d.free for d in plain[CHANGE:k]]) > 0.5


@pytest.mark.parametrize("load", ["push", "turning push"])
def test_a_push_at_the_tip_just_after_an_announcement_is_published_within_rows(load):
    """Its form is a tip force's: published from the first ``HOLD_ROWS`` rows of it, and
    from there as without the hold (a push that turns with the pose is taken for a set-up
    change at the announced check either way: its force swings)."""
    held = GateConfig(warmup_samples=1000)
    out, _ = run_announced(held, load, CHANGE)
    plain, _ = run_announced(GateConfig(warmup_samples=1000, announced_hold_s=0), load, CHANGE)
    k, k0 = first_flag(out), first_flag(plain)
    assert k0 < k <= k0 + (HOLD_ROWS + 1) * SETUP_STRIDE
    assert [(d.free, d.setup_change, d.trainable) for d in out[k:]] == [
        (d.free, d.setup_change, d.trainable) for d in plain[k:]]
    call = next((i for i, d in enumerate(out) if d.setup_change), N)
    assert not any(d.trainable for d in out[CHANGE:call])
    if load == "push":
        assert not any(d.setup_change or d.recalibrated for d in out)


def test_a_contact_begun_after_the_hold_is_published_at_once():
    cfg = GateConfig(warmup_samples=1000)
    at = CHANGE - int(1.5 * RATE)
    out, _ = run_announced(cfg, "push", at)
    plain, _ = run_announced(GateConfig(warmup_samples=1000, announced_hold_s=0), "push", at)
    assert first_flag(out) == first_flag(plain)


def test_the_hold_must_end_before_the_announced_check():
    with pytest.raises(ValueError, match="announced_hold_s"):
        GateConfig(announced_hold_s=4.0, announced_setup_s=3.0)
