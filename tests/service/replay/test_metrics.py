"""Replay metrics: which samples the gate's episode precision and recall are scored on."""

from __future__ import annotations

import numpy as np

from wrenchd.service.replay.metrics import episode_gate_scores, episode_scoring


def test_episodes_are_scored_away_from_their_edges_and_only_above_the_force_floor():
    t = np.arange(0, 10.0, 0.01)                   # 100 Hz
    contact = ((t >= 2.0) & (t < 4.0)) | ((t >= 6.0) & (t < 7.0))
    force = np.where((t >= 2.0) & (t < 4.0), 3.0, 0.0)
    force[(t >= 6.0) & (t < 7.0)] = 0.8            # a weak episode: never scored
    scored, label = episode_scoring(t, contact, force, min_peak_n=1.0, margin_s=0.1)
    near_edges = np.zeros(len(t), dtype=bool)
    for edge in (2.0, 4.0, 6.0, 7.0):
        near_edges |= np.abs(t - edge) <= 0.1 + 1e-9
    assert not scored[near_edges].any()
    assert not scored[(t >= 6.0) & (t < 7.0)].any()
    strong = (t >= 2.2) & (t < 3.8)
    assert scored[strong].all() and label[strong].all()
    free = (t < 1.8) | ((t > 4.2) & (t < 5.8)) | (t > 7.2)
    assert scored[free].all() and not label[free].any()
    assert not (label & ~scored).any()


def test_a_gate_that_flags_exactly_the_contacts_scores_one_after_the_calibration():
    t = np.arange(0, 10.0, 0.01)
    contact = ((t >= 2.0) & (t < 4.0)) | ((t >= 6.0) & (t < 8.0))
    force = np.where(contact, 3.0, 0.0)
    judged = t >= 5.0                                  # the first episode is in the calibration
    perfect = episode_gate_scores(t, contact, force, contact, judged)
    assert perfect["precision"] == 1.0 and perfect["recall"] == 1.0
    half = contact & (t < 7.0)                         # misses the second half of the episode
    scores = episode_gate_scores(t, contact, force, half, judged)
    assert scores["precision"] == 1.0
    assert abs(scores["recall"] - 0.9 / 1.8) < 0.02, scores       # 6.1-7.0 of 6.1-7.9 s
    always = episode_gate_scores(t, contact, force, np.ones(len(t), dtype=bool), judged)
    assert always["recall"] == 1.0 and always["precision"] < 0.5


def test_onset_delay_and_the_force_a_contact_is_found_at():
    """Two 2 s episodes whose force ramps 0 -> 2 N over their first second; the gate flags
    the first from 0.5 s in (1 N), the second never."""
    t = np.arange(0, 10.0, 0.01)
    contact = ((t >= 2.0) & (t < 4.0)) | ((t >= 6.0) & (t < 8.0))
    force = np.zeros(len(t))
    for start in (2.0, 6.0):
        inside = (t >= start) & (t < start + 2.0)
        force[inside] = np.minimum(2.0 * (t[inside] - start), 2.0)
    flagged = (t >= 2.5) & (t < 4.0)
    s = episode_gate_scores(t, contact, force, flagged, np.ones(len(t), dtype=bool))
    assert s["onset"]["episodes"] == 2 and s["onset"]["unfound"] == 1
    assert abs(s["onset"]["delay_s"]["median"] - 0.5) < 0.011
    assert abs(s["onset"]["force_at_flag_N"]["max"] - 1.0) < 0.021
    # labelled samples: 2.1-3.9 and 6.1-7.9 s; missed before a flag: 2.1-2.5 and all of the
    # second, none after
    assert abs(s["missed_before_flag"] - (0.4 + 1.8) / 3.6) < 0.02
    assert abs(s["missed_before_flag"] - (1 - s["recall"])) < 1e-9
    # flagged from the first sample over 0.5 N (0.25 s in): 2.26-3.9 and 6.26-7.9 of 3.6 s
    assert abs(s["recall_if_flagged_above_N"]["0.5"] - 2 * 1.64 / 3.6) < 0.02
    assert s["recall_if_flagged_above_N"]["0.3"] > s["recall_if_flagged_above_N"]["1"]
