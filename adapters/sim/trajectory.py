"""Smooth random joint trajectories: sums of sinusoids, like the Fourier excitation
trajectories of the WPI identification, but with random incommensurate frequencies so a long
session never repeats and wanders over the whole workspace.

Positions, velocities and accelerations are analytic (no numerical differentiation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wrenchd.models.series import N_JOINTS


@dataclass(frozen=True)
class Workspace:
    """Joint-space box the trajectory fills: ``lower`` and ``upper`` (6,) [rad, m]."""

    lower: tuple[float, ...]
    upper: tuple[float, ...]

    @property
    def center(self) -> np.ndarray:
        return (np.asarray(self.upper) + np.asarray(self.lower)) / 2

    @property
    def half_range(self) -> np.ndarray:
        return (np.asarray(self.upper) - np.asarray(self.lower)) / 2


class FourierTrajectory:
    """``q_j(t) = c_j + h_j * sum_k a_jk sin(2 pi f_jk t + phi_jk) / peak_j``.

    Args:
        workspace: the box to fill.
        rng: random generator (frequencies, amplitudes, phases).
        duration_s: session length; the normalisation ``peak_j`` is the largest excursion over
            it, so every joint reaches its workspace bound once and never leaves the box.
        freq_hz: (low, high) frequency band; amplitudes fall as 1/f so velocities stay modest.
        harmonics: number of sinusoids per joint.
    """

    def __init__(self, workspace: Workspace, rng: np.random.Generator, duration_s: float,
                 freq_hz: tuple[float, float] = (0.03, 0.3), harmonics: int = 6) -> None:
        self.workspace = workspace
        lo, hi = freq_hz
        self.freq = rng.uniform(lo, hi, (N_JOINTS, harmonics))                   # [Hz]
        self.amp = rng.uniform(0.3, 1.0, (N_JOINTS, harmonics)) * (lo / self.freq)
        self.phase = rng.uniform(0, 2 * np.pi, (N_JOINTS, harmonics))
        # Normalise by the excursion reached over the session, scanned every 50 ms; between
        # scan points a joint can move at most max|velocity| * 25 ms further, so adding that
        # bound guarantees the trajectory never leaves the box.
        scan_dt = 0.05
        scan = np.arange(0.0, max(duration_s, 1e-3) + scan_dt, scan_dt)
        peak = np.abs(self._unit(scan)[0]).max(axis=0)
        speed_bound = np.sum(self.amp * 2 * np.pi * self.freq, axis=1)
        self.scale = workspace.half_range / np.maximum(peak + speed_bound * scan_dt / 2, 1e-9)

    def _unit(self, t: np.ndarray):
        w = 2 * np.pi * self.freq                                 # (6, K) [rad/s]
        arg = t[:, None, None] * w + self.phase                   # (N, 6, K)
        s, c = np.sin(arg), np.cos(arg)
        pos = np.einsum("njk,jk->nj", s, self.amp)
        vel = np.einsum("njk,jk->nj", c, self.amp * w)
        acc = -np.einsum("njk,jk->nj", s, self.amp * w * w)
        return pos, vel, acc

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, velocities, accelerations (N, 6) at times ``t`` (N,) [s]."""
        out_q = np.empty((t.shape[0], N_JOINTS))
        out_dq = np.empty_like(out_q)
        out_ddq = np.empty_like(out_q)
        block = 200_000                       # bounds the (N, 6, K) temporaries
        for i in range(0, t.shape[0], block):
            pos, vel, acc = self._unit(t[i:i + block])
            out_q[i:i + block] = self.workspace.center + self.scale * pos
            out_dq[i:i + block] = self.scale * vel
            out_ddq[i:i + block] = self.scale * acc
        return out_q, out_dq, out_ddq
