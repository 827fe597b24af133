"""Inputs of the two-step estimator: feature rows, gap segmentation, history windows.

Both steps of Wu, Yilmaz, Kazanzides and Tumerdem, "Estimation of Trocar and Tool Interaction
Forces on the da Vinci Research Kit with Two-Step Deep Learning" (arXiv 2012.01479) read the
positions and velocities of all six joints. One feature row is ``[q1..q6, dq1..dq6]``:
positions [rad, rad, m, rad, rad, rad] then velocities [rad/s, rad/s, m/s, ...].

A stream is cut into segments wherever samples are missing (a gap longer than ``max_gap_s``),
time does not advance or the positions jump (:func:`position_jumps`): recurrent state and
history windows restart at each segment, in the streaming path and in the batch path alike.
"""

from __future__ import annotations

import numpy as np

from wrenchd.models.errors import DataError
from wrenchd.models.series import N_JOINTS

N_FEATURES = 2 * N_JOINTS


def joint_features(position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """Feature rows ``[q, dq]``: (N, 12) from (N, 6) and (N, 6), or (12,) from (6,) and (6,)."""
    q = np.asarray(position, dtype=np.float64)
    dq = np.asarray(velocity, dtype=np.float64)
    if q.shape != dq.shape or q.shape[-1] != N_JOINTS or q.ndim not in (1, 2):
        raise DataError(
            f"positions and velocities must both have shape (6,) or (N, 6), got {q.shape} "
            f"and {dq.shape}")
    return np.concatenate([q, dq], axis=-1)


def position_jumps(t: np.ndarray, q: np.ndarray, dq: np.ndarray,
                   max_jump: np.ndarray) -> np.ndarray:
    """(N - 1,) True where a sample's position is further than ``max_jump`` (6,) [rad; m]
    on some joint from where the velocities carried the previous one (trapezoid rule): a
    splice of two streams, an encoder re-zeroed, a glitch; no arm moves so."""
    dt = np.diff(np.asarray(t, dtype=np.float64))[:, None]
    moved = np.diff(q, axis=0) - 0.5 * (dq[1:] + dq[:-1]) * dt
    return (np.abs(moved) > max_jump).any(axis=1)


def segment_starts(t: np.ndarray, max_gap_s: float, q: np.ndarray | None = None,
                   dq: np.ndarray | None = None,
                   max_jump: tuple[float, ...] | None = None) -> np.ndarray:
    """Indices where a new segment starts: 0, and every sample after a gap or a jump.

    A gap is a time step longer than ``max_gap_s`` [s] or one that does not advance; a jump
    (with positions ``q`` and velocities ``dq``, (N, 6), and ``max_jump``) is
    :func:`position_jumps`'. Returns a sorted int array whose first element is 0 (empty for an
    empty ``t``).

    >>> t = np.arange(6) * 0.005
    >>> q = np.zeros((6, 6)); q[3:, 0] = 0.3                     # a 0.3 rad splice at sample 3
    >>> segment_starts(t, 0.05).tolist(), segment_starts(t, 0.05, q, 0 * q, (0.05,) * 6).tolist()
    ([0], [0, 3])
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    dt = np.diff(t)
    cut = (dt > max_gap_s) | (dt <= 0.0)
    if max_jump is not None and q is not None and dq is not None:
        cut |= position_jumps(t, np.asarray(q, np.float64), np.asarray(dq, np.float64),
                              np.asarray(max_jump, np.float64))
    return np.concatenate([[0], np.flatnonzero(cut) + 1]).astype(np.int64)


def segments(t: np.ndarray, max_gap_s: float, q: np.ndarray | None = None,
             dq: np.ndarray | None = None,
             max_jump: tuple[float, ...] | None = None) -> list[slice]:
    """The segments of a series as slices, in order (see :func:`segment_starts`)."""
    starts = segment_starts(t, max_gap_s, q, dq, max_jump)
    stops = np.append(starts[1:], len(t))
    return [slice(int(a), int(b)) for a, b in zip(starts, stops)]


def history_windows(x: np.ndarray, window: int) -> np.ndarray:
    """The last ``window`` rows at each sample of one segment, oldest first.

    Args:
        x: (T, F) rows of one gap-free segment.
        window: number of rows per window, >= 1.
    Returns:
        (T, window, F). Before ``window`` rows exist, the window is padded at the old end by
        repeating the segment's first row; this is exactly what the streaming
        :class:`wrenchd.models.estimator.correction.HistoryWindow` does.
    """
    x = np.asarray(x)
    if x.ndim != 2:
        raise DataError(f"rows must have shape (T, F), got {x.shape}")
    idx = np.arange(x.shape[0])[:, None] - (window - 1) + np.arange(window)[None, :]
    return x[np.clip(idx, 0, None)]
