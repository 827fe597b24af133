"""Per-event measures of a replay: the tip force around each set-up change, each strong contact
found or missed.

* :func:`setup_change_levels`: for each set-up change the session records
  (:func:`~wrenchd.models.physics.effects.drift.drift_onsets`: a simulated drift's start, a
  change of recording in a ``concat:`` session), the RMS of the published tip force (the force
  part of the wrench, N) over the free-motion samples (truth: not in contact; every sample of a
  session without truth) of the ``BEFORE_S`` before the change (``before_N``) and of the
  ``AFTER_WINDOW_S`` that start ``SETTLE_S`` after it (``after_N``), and ``ratio`` =
  after / before. In free motion the true tip force is zero, so these are errors: a ratio near
  1 means the pipeline is back to its pre-change accuracy a minute after the change. The
  ``SEAM_SKIP_S`` after each seam of a ``concat:`` session (``metadata["seams_s"]``, where
  one recording ends and the next begins and the joints jump, which a real arm never does)
  are left out of both windows: the estimate's transient there is an artefact of the join.
* :func:`contact_detection`: of the true contact episodes that start after the pipeline's
  calibration and whose true force peaks over ``FOUND_OVER_N``, how many the gate flagged
  (any sample of the episode called contact) and when the missed ones were.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wrenchd.models.physics.effects.drift import drift_onsets
from wrenchd.models.series import Session

#: Window before a set-up change, delay from the change to the window after it, and that
#: window's length [s].
BEFORE_S, SETTLE_S, AFTER_WINDOW_S = 30.0, 60.0, 30.0
#: Time after a seam of recordings left out of the windows [s] (the causal acceleration's
#: window and the jump's transient are well inside it).
SEAM_SKIP_S = 1.0
#: Contact episodes peaking over this true force [N] count in :func:`contact_detection`.
FOUND_OVER_N = 2.0


def _rms(x: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(x ** 2))) if x.size else None


def after_seam(t: np.ndarray, session: Session) -> np.ndarray:
    """(N,) True where a sample time ``t`` [s] lies within ``SEAM_SKIP_S`` after a seam of
    recordings (``session.metadata["seams_s"]``, ascending)."""
    t = np.asarray(t, dtype=np.float64)
    seams = np.asarray((session.metadata or {}).get("seams_s", ()), dtype=np.float64)
    if not seams.size:
        return np.zeros(len(t), dtype=bool)
    i = np.searchsorted(seams, t, side="right") - 1
    return (i >= 0) & (t - seams[np.clip(i, 0, None)] < SEAM_SKIP_S)


def true_runs(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (exclusive) indices of the runs of True in the (N,) ``flags``."""
    edges = np.flatnonzero(np.diff(np.r_[False, np.asarray(flags, dtype=bool), False]
                                   .astype(np.int8)))
    return edges[::2], edges[1::2]


def setup_change_levels(t: np.ndarray, wrench: np.ndarray, sample: np.ndarray,
                        session: Session) -> list[dict[str, Any]]:
    """The free-motion tip force around each set-up change (see the module docstring).

    Args:
        t: (N,) times of the replayed samples [s].
        wrench: (N, 6) the published wrenches [N, N m].
        sample: (N,) each row's index in the session.

    Returns:
        one dict per change, oldest first: ``id``, ``at_s``, ``before_N``, ``after_N``,
        ``ratio`` (None where a window has no free-motion sample or ``before_N`` is 0) and the
        samples each window held.
    """
    force = np.linalg.norm(np.asarray(wrench)[:, :3], axis=1)
    truth = session.truth
    free = (~truth.in_contact[sample] if truth is not None
            else np.ones(len(t), dtype=bool))
    free = free & ~after_seam(t, session)
    out = []
    for name, at, _ in drift_onsets(session):
        before = free & (t >= at - BEFORE_S) & (t < at)
        start = at + SETTLE_S
        after = free & (t >= start) & (t < start + AFTER_WINDOW_S)
        b, a = _rms(force[before]), _rms(force[after])
        out.append({"id": name, "at_s": float(at), "before_N": b, "after_N": a,
                    "ratio": a / b if a is not None and b else None,
                    "before_samples": int(before.sum()), "after_samples": int(after.sum()),
                    "after_window_s": [start, start + AFTER_WINDOW_S]})
    return out


def contact_detection(t: np.ndarray, flagged: np.ndarray, true_force_n: np.ndarray,
                      contact: np.ndarray, judged_from_s: float,
                      over_n: float = FOUND_OVER_N) -> dict[str, Any]:
    """Which strong contact episodes the gate found (see the module docstring).

    Args:
        t: (N,) sample times [s].
        flagged: (N,) the gate called the sample contact.
        true_force_n: (N,) true tip force magnitude [N].
        contact: (N,) truly in contact.
        judged_from_s: episodes starting before this time [s] (the calibration) are left out.
    """
    contact = np.asarray(contact, dtype=bool)
    edges = np.flatnonzero(np.diff(np.r_[False, contact, False].astype(np.int8)))
    found, missed = 0, []
    for a, b in zip(edges[::2], edges[1::2]):
        if t[a] < judged_from_s or not true_force_n[a:b].max() > over_n:
            continue
        if np.asarray(flagged[a:b]).any():
            found += 1
        else:
            missed.append({"start_s": float(t[a]), "end_s": float(t[b - 1]),
                           "peak_N": float(true_force_n[a:b].max())})
    return {"over_N": over_n, "episodes": found + len(missed), "found": found,
            "missed": len(missed), "missed_episodes": missed}
