"""The contact gate scored as a detector: contacts found, how late, and false alarms.

Detection theory scores a change detector by what it misses, how late it fires and how often
it fires for nothing (river's drift evaluation, CapyMOA); a surgeon and the adaptation need
the same: every contact found fast, few false contacts. On the published flag (``~free``)
after the pipeline's calibration:

* **episodes**: true contact runs peaking at or over ``MIN_PEAK_N``; each is *found* when a
  sample of it is flagged. Its *delay* runs from its onset (the first sample whose true force
  exceeds ``ONSET_N``) to its first flag (0 when flagged before the onset), with the true
  force at that flag. ``missed_over_N``: the episodes over ``FOUND_OVER_N`` never found.
* **false alarms**: runs of flagged samples with no true contact within ``FA_MARGIN_S`` of
  them (a release's tail is the contact's), per minute of true free motion; overall and in
  the ``AFTER_CHANGE_S`` after each set-up change the session records.

>>> t = np.arange(0, 60, 0.01)
>>> force = np.where((t > 10) & (t < 12), 3.0, 0.0)              # one 3 N contact
>>> flagged = ((t > 10.2) & (t < 12.1)) | ((t > 40) & (t < 40.5))  # found, and one false alarm
>>> s = detector_scores(t, force > 0, force, flagged, t >= 0, ())
>>> s["found"], round(s["delay_s"]["median"], 1), s["false_alarms"]["count"]
(1, 0.2, 1)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from wrenchd.service.replay.events_scored import true_runs

#: episodes peaking at or over this true force count [N]; their onset is the first sample
#: over ``ONSET_N`` [N]; those over ``FOUND_OVER_N`` must never be missed [N]
MIN_PEAK_N, ONSET_N, FOUND_OVER_N = 1.0, 0.3, 2.0
#: a flagged run within this of a true contact is that contact's (the gate's exit_s), not a
#: false alarm [s]
FA_MARGIN_S = 0.5
#: false alarms are also counted in this long after each set-up change [s]
AFTER_CHANGE_S = 60.0


def _stats(x: list[float]) -> dict[str, float | None]:
    return {"median": float(np.median(x)) if x else None,
            "p95": float(np.quantile(x, 0.95)) if x else None,
            "max": float(np.max(x)) if x else None}


def _minutes(t: np.ndarray, mask: np.ndarray) -> float:
    """Time [min] the (N,) ``mask`` holds, each sample counting its step to the next."""
    if len(t) < 2:
        return 0.0
    dt = np.diff(t, append=t[-1] + np.median(np.diff(t)))
    return float(dt[mask].sum()) / 60.0


def detector_scores(t: np.ndarray, contact: np.ndarray, force_n: np.ndarray,
                    flagged: np.ndarray, judged: np.ndarray,
                    changes_s: Sequence[float]) -> dict[str, Any]:
    """Episodes found, delays and false alarms (see the module docstring).

    Args:
        t: (N,) sample times [s], increasing.
        contact: (N,) truly in contact.
        force_n: (N,) true tip force magnitude [N].
        flagged: (N,) the gate published contact.
        judged: (N,) samples the gate judges (after the calibration).
        changes_s: times of the session's set-up changes [s].
    Returns:
        JSON-ready: ``episodes``, ``found``, ``missed``, ``missed_over_N`` and their
        ``missed_episodes``, ``delay_s`` and ``force_at_flag_N`` (median, p95, max), each
        found episode's delay (``delay_each_s``, in order),
        ``false_alarms`` (``count``, ``per_min``, ``free_min``, ``after_change``).
    """
    contact = np.asarray(contact, dtype=bool)
    flagged = np.asarray(flagged, dtype=bool) & judged
    delays, forces, missed = [], [], []
    near = np.zeros(len(t), dtype=bool)                  # within FA_MARGIN_S of a contact
    for a, b in zip(*true_runs(contact)):
        near[np.searchsorted(t, t[a] - FA_MARGIN_S):np.searchsorted(t, t[b - 1] + FA_MARGIN_S,
                                                                     side="right")] = True
        peak = float(force_n[a:b].max())
        if not judged[a] or peak < MIN_PEAK_N:
            continue
        hit = np.flatnonzero(flagged[a:b])
        if not len(hit):
            missed.append({"start_s": float(t[a]), "end_s": float(t[b - 1]), "peak_N": peak})
            continue
        onset = a + int(np.argmax(force_n[a:b] > ONSET_N))
        delays.append(max(0.0, float(t[a + hit[0]] - t[onset])))
        forces.append(float(force_n[a + hit[0]]))
    alarms = [float(t[a]) for a, b in zip(*true_runs(flagged)) if not near[a:b].any()]
    free = judged & ~contact
    window = np.zeros(len(t), dtype=bool)
    for c in changes_s:
        window |= (t >= c) & (t < c + AFTER_CHANGE_S)
    after = [a for a in alarms if any(c <= a < c + AFTER_CHANGE_S for c in changes_s)]
    free_min, after_min = _minutes(t, free), _minutes(t, free & window)
    return {
        "min_peak_N": MIN_PEAK_N, "onset_N": ONSET_N, "episodes": len(delays) + len(missed),
        "found": len(delays), "missed": len(missed), "over_N": FOUND_OVER_N,
        "missed_over_N": sum(m["peak_N"] > FOUND_OVER_N for m in missed),
        "missed_episodes": missed, "delay_s": _stats(delays), "force_at_flag_N": _stats(forces),
        "delay_each_s": delays,
        "false_alarms": {
            "count": len(alarms), "free_min": free_min, "at_s": alarms,
            "per_min": len(alarms) / free_min if free_min > 0 else None,
            "after_change": {"count": len(after), "free_min": after_min,
                             "per_min": len(after) / after_min if after_min > 0 else None}}}


def _c(x: Any, fmt: str = "{:.2f}") -> str:
    return "n/a" if x is None else fmt.format(x)


def pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One policy's ``gate_detector`` over several sessions: episodes and false alarms summed,
    delays pooled, the lowest sample precision and the contact offered to training summed."""
    ds = [m["gate_detector"] for m in rows]
    fa = [d["false_alarms"] for d in ds]
    free, after = sum(f["free_min"] for f in fa), sum(f["after_change"]["free_min"] for f in fa)
    count, count_after = sum(f["count"] for f in fa), sum(f["after_change"]["count"] for f in fa)
    precisions = [(m.get("gate_episodes") or {}).get("precision") for m in rows]
    return {
        "sessions": len(rows), "episodes": sum(d["episodes"] for d in ds),
        "found": sum(d["found"] for d in ds), "missed_over_N": sum(d["missed_over_N"] for d in ds),
        "delay_s": _stats([x for d in ds for x in d.get("delay_each_s", [])]),
        "false_alarms": {"count": count, "free_min": free,
                         "per_min": count / free if free > 0 else None,
                         "after_change": {"count": count_after, "free_min": after,
                                          "per_min": count_after / after if after > 0 else None}},
        "min_precision": min((p for p in precisions if p is not None), default=None),
        "offered_in_contact": sum((m.get("contamination") or {}).get(
            "in_contact_after_calibration", 0) for m in rows)}


def _row(name: str, policy: str, d: dict[str, Any], precision: Any, offered: Any) -> str:
    fa, dl = d["false_alarms"], d["delay_s"]
    return "| " + " | ".join([
        name, policy, f"{d['found']} of {d['episodes']}", str(d["missed_over_N"]),
        f"{_c(dl['median'])} / {_c(dl['p95'])} / {_c(dl['max'])}",
        f"{_c(fa['per_min'])} ({fa['count']})",
        f"{_c(fa['after_change']['per_min'])} ({fa['after_change']['count']})",
        _c(precision, "{:.3f}"), str(offered)]) + " |"


def detector_table(rows: list[dict[str, Any]]) -> str:
    """Markdown: one row per replay's ``gate_detector`` (with its sample precision and the
    contact samples offered to training after the calibration), and per policy over several
    sessions a pooled row (:func:`pooled`; its precision the lowest)."""
    out = ["| session | policy | contacts found | missed > 2 N | delay median / p95 / max [s] "
           "| false alarms / min | after a change / min | sample precision | contact offered "
           "to training |", "|" + "---|" * 9]
    scored = [m for m in rows if m.get("gate_detector") is not None]
    for m in scored:
        out.append(_row(m["session"], m["policy"], m["gate_detector"],
                        (m.get("gate_episodes") or {}).get("precision"),
                        (m.get("contamination") or {}).get("in_contact_after_calibration",
                                                           "n/a")))
    for policy in dict.fromkeys(m["policy"] for m in scored):
        group = [m for m in scored if m["policy"] == policy]
        if len(group) > 1:
            p = pooled(group)
            out.append(_row(f"**all {p['sessions']}**", policy, p, p["min_precision"],
                            p["offered_in_contact"]))
    return "\n".join(out) + "\n"
