"""What the robot's sensors make of the true motion and torque.

* Encoders quantise position; the velocity a controller reports is a finite difference of
  quantised positions at the servo rate, low-pass filtered (first order), as an encoder-based
  estimate would be. Resolution: dVRK PSM, ~4000 counts/rev motor encoders behind gear ratios
  of ~50, i.e. ~3e-5 rad per count on the outer joints; ~2.5e-6 m on insertion (assumption).
* Joint efforts come from motor currents: Gaussian noise per joint (assumed standard
  deviations of the order of the current-sensing noise of the dVRK controllers, below the
  smallest signals seen in the WPI recordings).
* A 6-axis force/torque sensor (for contact ground truth) adds its own noise (ATI Mini40 class:
  ~0.02 N, ~0.0005 N m).
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.signal import lfilter


class SensorConfig(BaseModel):
    """Noise and resolution of the simulated robot's sensors."""

    model_config = ConfigDict(extra="forbid")

    encoder_resolution: tuple[float, ...] = Field(
        default=(3e-5, 3e-5, 2.5e-6, 3e-5, 3e-5, 3e-5),
        description="position quantum per joint [rad; m]")
    velocity_cutoff_hz: float = Field(default=50.0, gt=0.0,
                                      description="low-pass cut-off of the velocity estimate [Hz]")
    effort_noise_std: tuple[float, ...] = Field(
        default=(0.015, 0.015, 0.05, 0.0008, 0.002, 0.002),
        description="effort noise per joint [N m; N]")
    ft_force_noise_std_n: float = Field(default=0.02, ge=0.0, description="F/T sensor force noise [N]")
    ft_torque_noise_std_nm: float = Field(default=0.0005, ge=0.0,
                                          description="F/T sensor torque noise [N m]")


def quantise(q: np.ndarray, resolution) -> np.ndarray:
    """Encoder positions: ``q`` rounded to the nearest count (N, 6)."""
    res = np.asarray(resolution)
    return np.round(q / res) * res


def velocity_estimate(q_measured: np.ndarray, dt_s: float, cutoff_hz: float,
                      initial_velocity: np.ndarray) -> np.ndarray:
    """Backward difference of encoder positions, first-order low-pass (N, 6) [per s].

    The filter starts settled at ``initial_velocity`` so the series has no start-up transient.
    """
    raw = np.empty_like(q_measured)
    raw[1:] = np.diff(q_measured, axis=0) / dt_s
    raw[0] = initial_velocity
    alpha = 1.0 - np.exp(-2 * np.pi * cutoff_hz * dt_s)        # discrete first-order pole
    zi = ((1.0 - alpha) * initial_velocity)[None, :]
    out, _ = lfilter([alpha], [1.0, -(1.0 - alpha)], raw, axis=0, zi=zi)
    return out
