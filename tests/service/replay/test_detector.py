"""The gate scored as a detector: found, delay from the 0.3 N onset, false alarms per minute."""

import numpy as np
import pytest

from wrenchd.service.replay.detector import detector_scores, detector_table, pooled

T = np.arange(0.0, 180.0, 0.01)                     # 3 minutes at 100 Hz


def ramp(a, b, peak):
    """A contact from ``a`` to ``b`` [s] whose force rises linearly to ``peak`` [N] over 1 s."""
    f = np.clip((T - a) / 1.0, 0.0, 1.0) * peak
    return np.where((T > a) & (T < b), f, 0.0)


def test_found_missed_delays_and_false_alarms():
    force = ramp(10, 14, 3.0) + ramp(50, 53, 2.5) + ramp(90, 92, 0.8) + ramp(130, 134, 1.5)
    flagged = ((T > 10.5) & (T < 14.3)          # found 0.4 s after the 0.3 N onset (10.1 s)
               | ((T > 14.4) & (T < 14.5))      # a flicker right after the release: its tail
               | ((T > 91) & (T < 91.5))        # on a 0.8 N contact: not an episode, no alarm
               | ((T > 100) & (T < 100.2))      # a false alarm
               | ((T > 121) & (T < 122)))       # a false alarm, after the change at 120 s
    s = detector_scores(T, force > 0, force, flagged, T >= 5.0, [120.0])
    assert (s["episodes"], s["found"], s["missed"], s["missed_over_N"]) == (3, 1, 2, 1)
    assert [m["start_s"] for m in s["missed_episodes"]] == pytest.approx([50.01, 130.01])
    assert s["delay_s"]["median"] == pytest.approx(0.41, abs=0.011)
    assert s["force_at_flag_N"]["median"] == pytest.approx(1.53, abs=0.05)   # 3 N x 0.51 s
    fa = s["false_alarms"]
    assert fa["count"] == 2 and fa["at_s"] == pytest.approx([100.01, 121.01])
    free_min = (175.0 - 4 - 3 - 2 - 4) / 60.0
    assert fa["free_min"] == pytest.approx(free_min, abs=0.01)
    assert fa["per_min"] == pytest.approx(2 / free_min, rel=0.01)
    assert fa["after_change"]["count"] == 1
    assert fa["after_change"]["free_min"] == pytest.approx((60 - 4) / 60, abs=0.01)


def test_a_flag_before_the_onset_is_no_delay_and_unjudged_samples_count_nothing():
    force = ramp(10, 14, 3.0)
    flagged = (T > 9.0) & (T < 14.0)
    s = detector_scores(T, force > 0, force, flagged, T >= 0.0, [])
    assert s["delay_s"]["max"] == 0.0 and s["false_alarms"]["count"] == 0
    s = detector_scores(T, force > 0, force, flagged, T >= 20.0, [])
    assert s["episodes"] == 0 and s["false_alarms"]["count"] == 0


def test_sessions_pool_into_one_row_per_policy():
    a = ramp(10, 14, 3.0)
    b = ramp(50, 53, 2.5)
    rows = [{"session": name, "policy": "gated", "gate_episodes": {"precision": p},
             "contamination": {"in_contact_after_calibration": k},
             "gate_detector": detector_scores(T, f > 0, f, flag, T >= 0, [])}
            for name, f, flag, p, k in (
                ("a", a, (T > 10.5) & (T < 14) | (T > 100) & (T < 100.2), 0.9, 0),
                ("b", b, (T > 50.2) & (T < 53), 1.0, 7))]
    p = pooled(rows)
    assert (p["episodes"], p["found"], p["false_alarms"]["count"]) == (2, 2, 1)
    assert p["delay_s"]["max"] == pytest.approx(0.41, abs=0.011)
    assert p["false_alarms"]["free_min"] == pytest.approx(sum(
        r["gate_detector"]["false_alarms"]["free_min"] for r in rows))
    assert p["min_precision"] == 0.9 and p["offered_in_contact"] == 7
    assert "| **all 2** | gated | 2 of 2 |" in detector_table(rows)


def test_the_table_has_a_row_per_scored_replay():
    force = ramp(10, 14, 3.0)
    d = detector_scores(T, force > 0, force, (T > 10.5) & (T < 14), T >= 0, [])
    rows = [{"session": "s", "policy": "gated", "gate_detector": d,
             "gate_episodes": {"precision": 1.0},
             "contamination": {"in_contact_after_calibration": 0}},
            {"session": "s", "policy": "frozen"}]
    table = detector_table(rows)
    assert table.count("\n") == 3 and "| s | gated | 1 of 1 | 0 |" in table
