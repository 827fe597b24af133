"""Joint accelerations from measured velocities by a smoothing derivative.

Encoder-based velocities are noisy; a plain finite difference amplifies that noise by
``1 / dt``. A Savitzky-Golay derivative fits a cubic to a centred window of velocity samples
and differentiates it: zero phase (no lag, unlike a causal low-pass) and flat response up
to roughly ``rate / window`` (~10 Hz for 21 samples at 200 Hz), well above the PSM's
excitation band (< 1 Hz, WPI trajectories and wrenchd's simulated ones alike).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import savgol_filter

from wrenchd.models.errors import DataError

#: Default window [s]; 0.105 s is 21 samples at 200 Hz.
DEFAULT_WINDOW_S = 0.105


def smoothed_acceleration(t: np.ndarray, dq: np.ndarray, window_s: float = DEFAULT_WINDOW_S,
                          polyorder: int = 3) -> np.ndarray:
    """Acceleration (N, 6) [rad/s^2; m/s^2] from velocity ``dq`` (N, 6) sampled at ``t`` (N,) [s].

    Raises:
        DataError: fewer samples than one window, or shapes disagree.
    """
    t, dq = np.asarray(t, float), np.asarray(dq, float)
    if dq.ndim != 2 or t.shape != (dq.shape[0],):
        raise DataError(f"t (N,) and dq (N, 6) expected, got {t.shape} and {dq.shape}")
    dt = float(np.median(np.diff(t)))
    window = int(round(window_s / dt)) | 1                     # odd number of samples
    window = max(window, polyorder + 2 + (polyorder % 2 == 0))
    if dq.shape[0] < window:
        raise DataError(f"need at least {window} samples for the derivative, got {dq.shape[0]}")
    return savgol_filter(dq, window, polyorder, deriv=1, delta=dt, axis=0, mode="interp")


#: Window of the position derivative [s]; 0.055 s is 11 samples at 200 Hz.
POSITION_WINDOW_S = 0.055
#: The recorded velocity counts as an estimate of dq/dt when they differ by less than this
#: fraction of the velocity's RMS.
CONSISTENT = 0.1


def zero_phase_velocity(t: np.ndarray, q: np.ndarray, dq: np.ndarray,
                        window_s: float = POSITION_WINDOW_S) -> tuple[np.ndarray, np.ndarray]:
    """Velocity (N, 6) for friction and dynamics, and which joints (6,) took it from positions.

    A robot's recorded velocity is usually a filtered difference of encoder counts, which
    lags (the simulated PSM's first-order 50 Hz filter: ~3.7 ms, enough to misplace every
    friction reversal by a sample). A quadratic Savitzky-Golay derivative of the positions is
    zero-phase. Per joint it replaces the recorded velocity when the two agree to
    ``CONSISTENT`` of the velocity RMS; otherwise the recorded velocity is kept (the WPI
    recordings' wrist velocities are not the derivative of their wrist positions).
    """
    t, q, dq = (np.asarray(a, float) for a in (t, q, dq))
    dt = float(np.median(np.diff(t)))
    window = max(int(round(window_s / dt)) | 1, 5)
    if q.shape[0] < window:
        return dq.copy(), np.zeros(q.shape[1], bool)
    v = savgol_filter(q, window, 2, deriv=1, delta=dt, axis=0, mode="interp")
    scale = np.sqrt(np.mean(dq**2, axis=0)) + 1e-12
    use = np.sqrt(np.mean((v - dq) ** 2, axis=0)) < CONSISTENT * scale
    return np.where(use[None, :], v, dq), use
