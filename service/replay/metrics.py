"""Metrics of a replay against the session's ground truth, as JSON and Markdown.

Forces are compared as vectors: the error of a sample is ``|F_est - F_ref|`` [N] (3-axis
norm), torques ``|T_est - T_ref|`` [N m]. References: the simulator's true tip wrench
(``truth``) and its force sensor (``sensor``), where the session has them.

* ``force_rmse_N`` / ``torque_rmse_Nm``: over all samples, contact samples and free ones.
* ``false_force_N``: mean and 95th percentile of the estimated force when the arm is truly
  in free motion (the true wrench is then zero).
* gate ``precision`` / ``recall`` of "contact" against the true ``in_contact``, after the
  pipeline's calibration period (when the gate is not used); ``gate_episodes`` scores the
  same flags on contact episodes whose true force peaks above ``EPISODE_MIN_N`` only,
  leaving out ``EPISODE_MARGIN_S`` around every onset and release (where the force is near
  zero whatever the label says) and the samples of weaker episodes.
* ``contamination``: offered training samples that were truly in contact (all, and those
  offered after the calibration, which trains on every sample by design).
* ``setup_changes`` (free-motion tip force around each set-up change) and ``contacts_found``
  (contact episodes over 2 N found or missed): :mod:`wrenchd.service.replay.events_scored`;
  ``gate_detector`` (episodes found, detection delay, false alarms per minute):
  :mod:`wrenchd.service.replay.detector`.
* drift: for each set-up change the session announces (a step, or a ramp's start), the free-
  motion force error before (30 s) and after it, and the time until the 5 s rolling free-
  motion error is back within 10 % of the pre-change level (None: never).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wrenchd.models.series import Session
from wrenchd.service.replay.loop import ReplayResult
from wrenchd.models.physics.effects.drift import drift_onsets
from wrenchd.service.replay.detector import detector_scores
from wrenchd.service.replay.events_scored import (contact_detection, setup_change_levels,
                                                  true_runs)

PRE_S, ROLL_S, RECOVER_FRACTION = 30.0, 5.0, 0.10
#: ``gate_episodes``: contact episodes count above this peak true force [N]; this long
#: around each onset and release is not scored [s]
EPISODE_MIN_N, EPISODE_MARGIN_S = 1.0, 0.1
#: ``gate_episodes``: the recall of flagging every episode from its first sample over each
#: of these true forces [N]
ONSET_FORCES_N = (0.3, 0.5, 1.0)


def episode_scoring(t: np.ndarray, contact: np.ndarray, force_n: np.ndarray,
                    min_peak_n: float = EPISODE_MIN_N, margin_s: float = EPISODE_MARGIN_S
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Which samples a contact detector is scored on, and their labels.

    Args:
        t: (N,) sample times [s], increasing.
        contact: (N,) true contact flags.
        force_n: (N,) true tip force magnitude [N].

    Returns:
        ``scored`` (N,) bool: free samples and samples of episodes peaking above
        ``min_peak_n``, except within ``margin_s`` of any onset or release; ``label`` (N,)
        bool: in such an episode.
    """
    contact = np.asarray(contact, dtype=bool)
    edges = np.flatnonzero(np.diff(contact.astype(np.int8))) + 1
    starts = np.r_[0, edges]
    stops = np.r_[edges, len(contact)]
    scored = np.ones(len(contact), dtype=bool)
    for a, b in zip(starts, stops):
        if contact[a] and not force_n[a:b].max(initial=0.0) > min_peak_n:
            scored[a:b] = False                              # a weak episode: not scored
    for e in edges:                                          # onsets and releases
        scored[np.abs(t - t[e]) <= margin_s + 1e-9] = False
    return scored, contact & scored


def episode_gate_scores(t: np.ndarray, contact: np.ndarray, force_n: np.ndarray,
                        flagged: np.ndarray, judged: np.ndarray) -> dict[str, Any]:
    """Precision and recall of the (N,) ``flagged`` contact samples on the samples
    :func:`episode_scoring` scores among the (N,) ``judged`` ones (after the calibration),
    and how late contacts are found.

    ``onset``: over the scored episodes judged from their start, the delay from each one's
    start to its first flagged sample [s] and the true force there [N] (median and max;
    ``unfound``: episodes never flagged), and ``missed_before_flag``: the share of the
    labelled samples missed before their episode's first flag (the rest of the misses are
    later in an episode). ``recall_if_flagged_above_N``: the recall of a detector that knew
    the true force and flagged each episode from the first sample over 0.3, 0.5 and 1 N to
    its end: how weak a contact the recall asks to be found at.
    """
    scored, label = episode_scoring(t, contact, force_n)
    scored &= judged
    label &= judged
    said = flagged & scored
    tp = int(np.sum(said & label))
    delays, forces, unfound, before = [], [], 0, 0
    bound = {th: 0 for th in ONSET_FORCES_N}
    for a, b in zip(*true_runs(contact)):
        if not label[a:b].any():
            continue
        for th in ONSET_FORCES_N:
            over = np.flatnonzero(force_n[a:b] > th)
            if len(over):
                bound[th] += int(label[a + over[0]:b].sum())
        hit = np.flatnonzero(flagged[a:b])
        before += int(label[a:a + (hit[0] if len(hit) else b - a)].sum())
        if not judged[a]:
            continue
        if len(hit):
            delays.append(float(t[a + hit[0]] - t[a]))
            forces.append(float(force_n[a + hit[0]]))
        else:
            unfound += 1
    n_label = int(label.sum())

    def summary(x: list[float]) -> dict[str, float | None]:
        return {"median": float(np.median(x)) if x else None,
                "max": float(np.max(x)) if x else None}

    return {"precision": tp / int(said.sum()) if said.any() else None,
            "recall": tp / n_label if n_label else None,
            "scored": int(scored.sum()), "min_peak_N": EPISODE_MIN_N,
            "margin_s": EPISODE_MARGIN_S,
            "onset": {"episodes": len(delays) + unfound, "unfound": unfound,
                      "delay_s": summary(delays), "force_at_flag_N": summary(forces)},
            "missed_before_flag": before / n_label if n_label else None,
            "recall_if_flagged_above_N": {f"{th:g}": (bound[th] / n_label if n_label else None)
                                          for th in ONSET_FORCES_N}}


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(x ** 2))) if x.size else None


def _mean(x: np.ndarray) -> float | None:
    return float(np.mean(x)) if x.size else None


def _errors(r: ReplayResult, ref: np.ndarray, contact: np.ndarray) -> dict[str, Any]:
    ef = np.linalg.norm(r.wrench[:, :3] - ref[:, :3], axis=1)
    et = np.linalg.norm(r.wrench[:, 3:] - ref[:, 3:], axis=1)
    return {"force_rmse_N": {"all": _rms(ef), "contact": _rms(ef[contact]),
                             "free": _rms(ef[~contact])},
            "torque_rmse_Nm": {"all": _rms(et), "contact": _rms(et[contact]),
                               "free": _rms(et[~contact])}}


def free_error_series(r: ReplayResult, session: Session, bin_s: float = 1.0,
                      start_s: float | None = None, rms: bool = False) -> dict[str, np.ndarray]:
    """Per ``bin_s`` bin from ``start_s`` (default: the first sample) to the last sample:
    ``t`` the bins' start times [s], ``free`` and ``contact`` the mean (``rms``: root mean
    square) force error [N] of the free-motion and contact samples in it (NaN where it has
    none), ``free_n`` how many free-motion samples it has. Without truth, ``free`` is the mean
    estimated force [N] over every sample and ``contact`` is NaN.

    Raises:
        ValueError: ``bin_s`` is not > 0.
    """
    if not bin_s > 0:
        raise ValueError(f"the bin must be longer than 0 s, got {bin_s:g}")
    truth = session.truth
    t = r.t
    if start_s is not None:
        start = float(start_s)
    else:
        start = float(t[0]) if len(t) else 0.0
    nb = max(int(np.ceil((float(t[-1]) - start) / bin_s)), 1) \
        if len(t) and t[-1] >= start else 0
    inside = t >= start
    idx = np.minimum(np.floor((t - start) / bin_s).astype(np.int64), nb - 1)
    edges = start + bin_s * np.arange(nb)

    def per_bin(values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        mask = mask & inside
        cnt = np.bincount(idx[mask], minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            if rms:
                return np.sqrt(np.bincount(idx[mask], values[mask] ** 2, nb) / cnt), cnt
            return np.bincount(idx[mask], values[mask], nb) / cnt, cnt

    if truth is None:
        free, n = per_bin(np.linalg.norm(r.wrench[:, :3], axis=1), np.ones(len(t), bool))
        return {"t": edges, "free": free, "contact": np.full(nb, np.nan), "free_n": n}
    contact = truth.in_contact[r.sample]
    ef = force_error_n(r, truth)
    free, n = per_bin(ef, ~contact)
    return {"t": edges, "free": free, "contact": per_bin(ef, contact)[0], "free_n": n}


def force_error_n(r: ReplayResult, truth) -> np.ndarray:
    """(N,) size of the force error [N] of each replayed sample against the truth."""
    return np.linalg.norm(r.wrench[:, :3] - truth.external_wrench[r.sample, :3], axis=1)


def _recovery(t: np.ndarray, ef: np.ndarray, free: np.ndarray, onset: float
              ) -> dict[str, Any]:
    pre = free & (t >= onset - PRE_S) & (t < onset)
    post = free & (t >= onset)
    level = _mean(ef[pre])
    out = {"onset_s": onset, "free_force_error_before_N": level,
           "free_force_error_after_N": _mean(ef[post]), "recovery_s": None}
    if level is None or not post.any():
        return out
    tp, ep = t[post], ef[post]
    csum = np.r_[0.0, np.cumsum(ep)]
    lo = np.searchsorted(tp, tp - ROLL_S, side="left")           # rolling window start
    rolling = (csum[1:] - csum[lo]) / (np.arange(1, len(tp) + 1) - lo)
    ok = (tp - onset >= ROLL_S) & (rolling <= (1 + RECOVER_FRACTION) * level)
    if ok.any():
        out["recovery_s"] = float(tp[np.argmax(ok)] - onset)
    return out


def replay_metrics(r: ReplayResult, session: Session) -> dict[str, Any]:
    """Every metric the session allows (see the module docstring), JSON-able."""
    calib = float(r.config.get("calibration_s", 0.0) or 0.0)
    t0 = float(r.t[0]) if len(r.t) else 0.0
    versions = np.flatnonzero(np.r_[True, np.diff(r.model_version) != 0])
    c = r.status["counters"]
    after = r.t >= t0 + calib
    m: dict[str, Any] = {
        "policy": r.policy, "source": r.meta.get("source"),
        "samples": int(len(r.t)), "samples_in": r.samples_in,
        "duration_s": float(r.t[-1] - r.t[0]) if len(r.t) else 0.0,
        "wall_s": r.wall_s, "samples_per_s": len(r.t) / r.wall_s if r.wall_s > 0 else None,
        "counters": c,
        "model_versions": [[float(r.t[i]), int(r.model_version[i])] for i in versions],
        "final_model_version": int(r.model_version[-1]) if len(r.t) else 0,
        # None while no sample came after the calibration (a session shorter than it)
        "gate_contact_fraction": float(np.mean(~r.free[after])) if after.any() else None,
        "events": {k: sum(1 for e in r.events if e.kind == k)
                   for k in sorted({e.kind for e in r.events})},
    }
    m["setup_changes"] = setup_change_levels(r.t, r.wrench, r.sample, session)
    truth = session.truth
    if truth is None:
        m["estimated_force_mean_N"] = _mean(np.linalg.norm(r.wrench[:, :3], axis=1))
        return m
    contact = truth.in_contact[r.sample]
    m["truth"] = _errors(r, truth.external_wrench[r.sample], contact)
    if truth.sensor_wrench is not None:
        m["sensor"] = _errors(r, truth.sensor_wrench[r.sample], contact)
    fmag = np.linalg.norm(r.wrench[:, :3], axis=1)
    m["false_force_N"] = {"mean": _mean(fmag[~contact]),
                          "p95": float(np.percentile(fmag[~contact], 95))
                          if (~contact).any() else None}
    after = r.t >= t0 + calib
    est_contact, true_contact = ~r.free[after], contact[after]
    tp = int(np.sum(est_contact & true_contact))
    m["gate"] = {"precision": tp / int(est_contact.sum()) if est_contact.any() else None,
                 "recall": tp / int(true_contact.sum()) if true_contact.any() else None,
                 "after_s": t0 + calib}
    true_force = np.linalg.norm(truth.external_wrench[r.sample, :3], axis=1)
    m["gate_episodes"] = episode_gate_scores(r.t, contact, true_force, ~r.free, after)
    ef = force_error_n(r, truth)
    if len(r.offered_t):
        pos = np.clip(np.searchsorted(session.joint_states.t, r.offered_t), 0,
                      len(truth) - 1)
        bad_mask = truth.in_contact[pos]
        bad = int(bad_mask.sum())
        m["contamination"] = {"offered": int(len(r.offered_t)), "in_contact": bad,
                              "fraction": bad / len(r.offered_t),
                              # the calibration minute trains on every sample by design
                              "in_contact_after_calibration": int(
                                  bad_mask[r.offered_t >= t0 + calib].sum()),
                              "episodes_after_calibration": offered_contact_episodes(
                                  r, truth, pos[bad_mask & (r.offered_t >= t0 + calib)],
                                  contact, ef)}
    else:
        m["contamination"] = {"offered": 0, "in_contact": 0, "fraction": None,
                              "in_contact_after_calibration": 0,
                              "episodes_after_calibration": []}
    m["contacts_found"] = contact_detection(r.t, ~r.free, true_force, contact, t0 + calib)
    m["gate_detector"] = detector_scores(r.t, contact, true_force, ~r.free, after,
                                         [at for _, at, _ in drift_onsets(session)])
    m["drifts"] = [{"id": name, "end_s": end, **_recovery(r.t, ef, ~contact, start)}
                   for name, start, end in drift_onsets(session)]
    return m


#: ``offered_contact_episodes``: the free-motion force error is taken over this long before
#: an episode's start [s].
BEFORE_EPISODE_S = 10.0


def offered_contact_episodes(r: ReplayResult, truth, offered: np.ndarray,
                             contact: np.ndarray, ef: np.ndarray) -> list[dict[str, Any]]:
    """The true contact episodes that samples offered to training fell in: for each, its start
    [s], the samples offered, its peak true tip force [N] and the free-motion tip force error
    RMS over the :data:`BEFORE_EPISODE_S` before it [N] (how far the estimate strayed when
    nothing touched: a contact much weaker than that cannot be told from free motion).

    ``offered``: session sample indices of the offered samples in contact; ``contact``: the
    truth's contact flag per replayed sample; ``ef``: the force error per replayed sample
    (:func:`force_error_n`)."""
    if not len(offered):
        return []
    starts, ends = true_runs(truth.in_contact)
    run = np.searchsorted(starts, offered, side="right") - 1    # the run each one is in
    out = []
    for k, n in zip(*np.unique(run, return_counts=True)):
        start, end = starts[k], ends[k]
        # the replayed sample at (or first after) the episode's start; replay keeps order
        t_start = float(r.t[min(int(np.searchsorted(r.sample, start)), len(r.t) - 1)])
        before = (r.t >= t_start - BEFORE_EPISODE_S) & (r.t < t_start) & ~contact
        peak = np.linalg.norm(truth.external_wrench[start:end, :3], axis=1).max()
        out.append({"start_s": round(t_start, 3), "offered": int(n), "peak_N": float(peak),
                    "free_error_before_N": (float(np.sqrt(np.mean(ef[before] ** 2)))
                                            if before.any() else None)})
    return out


def _f(x: Any, digits: int = 3) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return str(x)


def _onset_line(g: dict[str, Any]) -> str:
    o = g["onset"]
    bound = ", ".join(f"{k} N {_f(v)}" for k, v in g["recall_if_flagged_above_N"].items())
    return (f"- contacts found {_f(o['delay_s']['median'])} s after they start (median; max "
            f"{_f(o['delay_s']['max'])} s), at {_f(o['force_at_flag_N']['median'])} N (median); "
            f"{o['unfound']} of {o['episodes']} never; misses before the first flag: "
            f"{_f(g['missed_before_flag'])} of the contact samples; recall if flagged from the "
            f"first sample over {bound}")


def metrics_markdown(m: dict[str, Any]) -> str:
    """A short Markdown report of :func:`replay_metrics`."""
    lines = [f"# Replay: policy `{m['policy']}` on `{m['source']}`", "",
             f"{m['samples']} samples ({m['duration_s']:.1f} s) in {m['wall_s']:.1f} s wall "
             f"({_f(m['samples_per_s'])} samples/s); final model version "
             f"{m['final_model_version']} ({len(m['model_versions']) - 1} changes).", ""]
    if "truth" in m:
        lines += ["| reference | force RMSE all [N] | contact [N] | free [N] | "
                  "torque RMSE all [N m] |", "|---|---|---|---|---|"]
        for ref in ("truth", "sensor"):
            if ref in m:
                e = m[ref]
                lines.append(f"| {ref} | {_f(e['force_rmse_N']['all'])} | "
                             f"{_f(e['force_rmse_N']['contact'])} | "
                             f"{_f(e['force_rmse_N']['free'])} | "
                             f"{_f(e['torque_rmse_Nm']['all'])} |")
        g, c = m["gate"], m["contamination"]
        lines += ["", f"- false force in free motion: mean {_f(m['false_force_N']['mean'])} N, "
                  f"p95 {_f(m['false_force_N']['p95'])} N",
                  f"- gate (after {g['after_s']:.0f} s): precision {_f(g['precision'])}, "
                  f"recall {_f(g['recall'])}; on episodes above "
                  f"{m['gate_episodes']['min_peak_N']:g} N, {m['gate_episodes']['margin_s']:g} s "
                  f"around onsets and releases left out: precision "
                  f"{_f(m['gate_episodes']['precision'])}, recall "
                  f"{_f(m['gate_episodes']['recall'])}",
                  _onset_line(m["gate_episodes"]),
                  f"- training contamination: {c['in_contact']} of {c['offered']} offered "
                  f"samples were in contact ({_f(c['fraction'])}), "
                  f"{c['in_contact_after_calibration']} of them after the calibration"]
        for d in m["drifts"]:
            lines.append(f"- drift `{d['id']}` at {d['onset_s']:.0f} s: free-motion force error "
                         f"{_f(d['free_force_error_before_N'])} N before, "
                         f"{_f(d['free_force_error_after_N'])} N after; recovery "
                         f"{_f(d['recovery_s'])} s")
        cf = m["contacts_found"]
        lines.append(f"- contact episodes peaking over {cf['over_N']:g} N after the calibration: "
                     f"{cf['found']} of {cf['episodes']} found")
    else:
        lines.append(f"- no ground truth; mean estimated force "
                     f"{_f(m.get('estimated_force_mean_N'))} N")
    for c in m.get("setup_changes", []):
        lines.append(f"- set-up change `{c['id']}` at {c['at_s']:.1f} s: free-motion tip force "
                     f"RMS {_f(c['before_N'])} N over the 30 s before, {_f(c['after_N'])} N "
                     f"from 60 s after (ratio {_f(c['ratio'])})")
    lines += ["", f"Events: {m['events']}", ""]
    return "\n".join(lines)


def recovery_levels(r: ReplayResult, session: Session, change_s: float,
                    settle_s: float = 60.0, window_s: float = 40.0) -> tuple[float, float]:
    """The insufflation-recovery measure after a set-up change at ``change_s`` [s]: the free-motion
    force RMSE [N] over the ``window_s`` before the change (``pre``), and over the
    ``window_s`` that start once ``settle_s`` of free motion (truth labels) has passed after
    it (``post``). Needs the session's truth; raises ``ValueError`` when the session ends
    before the second window can start."""
    truth = session.truth
    if truth is None:
        raise ValueError("recovery levels need a session with its truth (a simulated one)")
    t = r.t
    err = force_error_n(r, truth)
    free = ~truth.in_contact[r.sample]
    rate_hz = 1.0 / float(np.median(np.diff(session.joint_states.t)))
    pre = free & (t >= change_s - window_s) & (t < change_s)
    after = np.flatnonzero(free & (t >= change_s))
    k = int(round(settle_s * rate_hz))
    if k >= len(after):
        raise ValueError(f"the session ends before {settle_s:g} s of free motion after "
                         f"{change_s:g} s")
    start = t[after[k]]
    post = free & (t >= start) & (t < start + window_s)
    return float(np.sqrt(np.mean(err[pre] ** 2))), float(np.sqrt(np.mean(err[post] ** 2)))
