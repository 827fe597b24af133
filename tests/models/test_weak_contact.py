"""Free samples whose residual a tip force explains are held back from training: a weak
contact under the gate's bounds keeps its form (``weak_contact_*`` of the gate's config)."""

import numpy as np
import pytest

from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.models.gate import GateConfig
from wrenchd.models.weak_contact import WeakContactWatch

RATE = 1000.0
STD = np.array([0.025, 0.05, 0.45, 0.002, 0.0025, 0.003])   # a gate's scale on the real PSM
KIN = WrenchMap().kinematics


def motion(n: int) -> np.ndarray:
    t = np.arange(n)[:, None] / RATE
    period = np.array([6.5, 5.1, 7.3, 4.3, 3.7, 5.9])
    amp = np.array([0.7, 0.5, 0.05, 1.0, 0.7, 0.7])
    return np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0]) + amp * np.sin(2 * np.pi * t / period)


def free_error(n: int, seed: int = 0) -> np.ndarray:
    """Free-motion model error at the scale's level, smooth over tens of milliseconds."""
    rng = np.random.default_rng(seed)
    raw = rng.normal(0.0, 1.0, (n // 20 + 2, 6))
    idx = np.arange(n) / 20.0
    lo = idx.astype(int)
    w = (idx - lo)[:, None]
    return ((1 - w) * raw[lo] + w * raw[lo + 1]) * STD


def tip(q: np.ndarray, force) -> np.ndarray:
    return np.einsum("nji,nj->ni", KIN.jacobian(q, "hybrid")[:, :3, :],
                     np.broadcast_to(force, (len(q), 3)))


def run(watch: WeakContactWatch, q: np.ndarray, r: np.ndarray, t0: float = 0.0):
    held, onsets = [], []
    for i in range(len(q)):
        held.append(watch.update(t0 + i / RATE, q[i], r[i], STD))
        if watch.onset is not None:
            onsets.append(watch.onset)
    return np.array(held), onsets


def test_free_motion_error_as_large_as_a_weak_contact_is_not_held_back():
    q = motion(20_000)
    r = 3.0 * free_error(len(q))             # a tip force fitted to it: about 0.9 N, over the bound
    held, onsets = run(WeakContactWatch(GateConfig(), KIN), q, r)
    assert held.mean() < 0.02 and len(onsets) <= 2
    held, _ = run(WeakContactWatch(GateConfig(weak_contact_misfit=0.99), KIN), q, r)
    assert held.mean() > 0.3                 # by its form alone


def test_a_weak_push_at_the_tip_is_held_back_from_its_start():
    n, start = 9_000, 6_000
    q = motion(n)
    r = free_error(n, seed=1)
    r[start:] += tip(q[start:], [0.0, 1.2, -0.6])               # 1.3 N, under the gate's bounds
    held, onsets = run(WeakContactWatch(GateConfig(), KIN), q, r)
    assert held[start + 400:].all()                             # within 0.4 s, to its end
    assert len(onsets) == 1 and start / RATE - 0.31 <= onsets[0] <= start / RATE + 0.4


def test_a_push_weaker_than_weak_contact_force_n_trains():
    n, start = 9_000, 6_000
    q = motion(n)
    r = free_error(n, seed=2) * 0.2
    r[start:] += tip(q[start:], [0.0, 0.4, 0.0])
    held, _ = run(WeakContactWatch(GateConfig(), KIN), q, r)
    assert not held[start:].any()
    held, _ = run(WeakContactWatch(GateConfig(weak_contact_force_n=0.2), KIN), q, r)
    assert held[start + 400:].mean() > 0.95


def test_a_lasting_tip_like_error_trains_again_after_weak_contact_max_s():
    n, start = 15_000, 2_000
    q = motion(n)
    r = free_error(n, seed=3)
    r[start:] += tip(q[start:], [1.5, 0.0, 0.0])
    cfg = GateConfig(weak_contact_max_s=5.0)
    held, onsets = run(WeakContactWatch(cfg, KIN), q, r)
    assert held[start + 500:start + 4_500].all()
    assert not held[start + 5_500:].any() and len(onsets) == 1


def test_clear_forgets_the_run():
    q = motion(3_000)
    r = tip(q, [0.0, 0.0, 2.0])
    watch = WeakContactWatch(GateConfig(), KIN)
    held, _ = run(watch, q, r)
    assert held[-1]
    watch.clear()
    assert not watch.holding
    held, _ = run(watch, q[:100], r[:100], t0=3.0)               # under half a window again
    assert not held.any()


@pytest.mark.parametrize("bad", [{"weak_contact_misfit": 0.0}, {"weak_contact_s": -1.0},
                                 {"weak_contact_max_s": 0.0}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        GateConfig(**bad)
