"""Drift of the free-motion residual level: a lasting rise is found, a contact's onset is not."""

import numpy as np

from wrenchd.models.drift_detector import DriftConfig, ResidualDriftDetector

RATE = 200.0
FLOOR = np.array([0.02, 0.02, 0.1, 0.002, 0.002, 0.002])


def residuals(n: int, level: np.ndarray, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(0.0, 1.0, (n, 6)) * FLOOR * level[:, None]


def feed(det: ResidualDriftDetector, r: np.ndarray, skip: np.ndarray | None = None):
    hits = []
    for i, row in enumerate(r):
        if skip is not None and skip[i]:
            continue                                    # the gate called these contact
        if det.update(i / RATE, row):
            hits.append(i / RATE)
    return hits


def test_a_lasting_rise_is_detected_once_after_the_delay():
    level = np.ones(12000)
    level[6000:] = 3.0                                   # the set-up changes at 30 s
    det = ResidualDriftDetector(FLOOR, DriftConfig(cooldown_s=100.0))
    hits = feed(det, residuals(12000, level))
    assert len(hits) == 1
    assert 30.0 + det.config.delay_s <= hits[0] < 30.0 + det.config.delay_s + 3.0


def test_steady_noise_is_no_drift():
    assert feed(ResidualDriftDetector(FLOOR), residuals(20000, np.ones(20000))) == []


def test_contact_onsets_before_the_gate_fires_are_no_drift():
    """Every 10 s a contact: 1 s of rising residual the gate still calls free, then 2 s the
    gate calls contact (a hole in the free samples)."""
    n = 24000
    level, skip = np.ones(n), np.zeros(n, dtype=bool)
    for start in range(2000, n - 1000, 2000):
        level[start:start + 200] = np.linspace(1, 6, 200)
        skip[start + 200:start + 600] = True
    r = residuals(n, level)
    assert feed(ResidualDriftDetector(FLOOR), r, skip) == []
    # the same onsets without the delay line are taken for drifts
    assert feed(ResidualDriftDetector(FLOOR, DriftConfig(delay_s=0.0)), r, skip) != []
