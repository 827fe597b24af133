"""Inputs of the two-step estimator: feature rows, gap segmentation, history windows.

Both steps of Wu, Yilmaz, Kazanzides and Tumerdem, "Estimation of Trocar and Tool Interaction
Forces on the da Vinci Research Kit with Two-Step Deep Learning" (arXiv 2012.01479) read the
positions and velocities of all six joints. One feature row is ``[q1..q6, dq1..dq6]``:
positions [rad, rad, m, rad, rad, rad] then velocities [rad/s, rad/s, m/s, ...].

A stream is cut into segments wherever samples are missing (a gap longer than ``max_gap_s``)
or time does not advance: recurrent state and history windows restart at each segment, in the
streaming path and in the batch path alike.
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


def segment_starts(t: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Indices where a new segment starts: 0, and every sample after a gap.

    A gap is a time step longer than ``max_gap_s`` [s] or one that does not advance.
    Returns a sorted int array whose first element is 0 (empty for an empty ``t``).
    """
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    dt = np.diff(t)
    breaks = np.flatnonzero((dt > max_gap_s) | (dt <= 0.0)) + 1
    return np.concatenate([[0], breaks]).astype(np.int64)


def segments(t: np.ndarray, max_gap_s: float) -> list[slice]:
    """The gap-free segments of a series as slices, in order (see :func:`segment_starts`)."""
    starts = segment_starts(t, max_gap_s)
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
