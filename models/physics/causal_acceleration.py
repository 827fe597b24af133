"""Joint accelerations from past velocities only: a causal estimate for streaming models.

A rigid-body model needs the acceleration, which the dVRK does not measure. The centred
Savitzky-Golay derivative (:func:`wrenchd.models.physics.least_squares.smoothed_acceleration`)
reads 50 ms into the future; a model that runs sample by sample cannot. This estimate is a
finite impulse response filter on the last ``taps`` velocity samples,

    ddq_j[k] = sum_i w_j[i] dq_j[k - i],    i = 0 .. taps - 1,

whose taps are the least-squares (Wiener) fit to the centred derivative on training data: the
best linear causal stand-in for it at the training recordings' sample rate. Joints of one group
share their taps (fitted on all of them): one joint's filter alone learns the spectrum of its
own trajectory and transfers worse to another.

At the start of a segment the history is padded with the segment's first velocity, in the
batch path and in the streaming path alike.

A filter may instead read ``lookahead`` samples past the one it estimates
(``CausalAccelerationConfig.lookahead_s``): ``ddq_j[k] = sum_i w_j[i] dq_j[k + lookahead - i]``.
That one is not causal: a stream would get each estimate ``lookahead`` samples late, so it
estimates whole segments only (:meth:`CausalAcceleration.estimate`, the end padded with the
last velocity) and refuses to stream. ``wrenchd real-data --lookahead-ms`` uses it to measure
what such a latency would buy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.physics.least_squares import smoothed_acceleration
from wrenchd.models.series import N_JOINTS

#: Joints sharing one filter, zero-based: (yaw, pitch), insertion, roll, (wrist pitch, yaw).
ACCELERATION_GROUPS: tuple[tuple[int, ...], ...] = ((0, 1), (2,), (3,), (4, 5))

#: A causal acceleration's state: (B, taps, 6) velocity history, newest first, and (B,)
#: whether each stream has seen a sample since its start.
AccelerationState = tuple[np.ndarray, np.ndarray]


def velocity_history(velocity: np.ndarray, taps: int, lookahead: int = 0) -> np.ndarray:
    """(T, taps, 6) of one segment's (T, 6) velocities: row k holds ``dq[k + lookahead - i]``
    at ``i``, newest first, the segment's first sample standing in before its start (and its
    last after its end)."""
    idx = np.arange(len(velocity))[:, None] + lookahead - np.arange(taps)[None, :]
    return velocity[np.clip(idx, 0, len(velocity) - 1)]


def accel_window(config: CausalAccelerationConfig, dt_s: float) -> int:
    """Samples of the centred target derivative (odd, at least ``order + 2``)."""
    return max(int(round(config.target_window_s / dt_s)) | 1, config.target_order + 2 | 1)


def lookahead_samples(config: CausalAccelerationConfig, dt_s: float) -> int:
    """``config.lookahead_s`` in whole samples of ``dt_s`` seconds (below ``taps``).

    Raises:
        ConfigError: a look-ahead as long as the filter or longer.
    """
    n = int(round(config.lookahead_s / dt_s))
    if n >= config.taps:
        raise ConfigError(f"lookahead_s {config.lookahead_s} s is {n} samples, more than the "
                          f"filter's {config.taps} taps can hold")
    return n


class CausalAccelerationConfig(BaseModel):
    """How the causal acceleration filter is fitted."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    taps: int = Field(default=48, ge=2, description="velocity samples per estimate")
    groups: tuple[tuple[int, ...], ...] = Field(default=ACCELERATION_GROUPS,
                                                description="joints sharing one filter")
    target_window_s: float = Field(default=0.105, gt=0.0,
                                   description="window of the centred target derivative [s]")
    target_order: int = Field(default=3, ge=2, description="its polynomial order")
    lookahead_s: float = Field(default=0.0, ge=0.0,
                               description="how far past the estimated sample the filter reads "
                                           "[s]; above 0 it cannot stream (offline studies)")

    @field_validator("groups")
    @classmethod
    def _partition(cls, value: tuple[tuple[int, ...], ...]) -> tuple[tuple[int, ...], ...]:
        if sorted(j for g in value for j in g) != list(range(N_JOINTS)):
            raise ValueError(f"groups must partition joints 0..5, got {value}")
        return value


@dataclass(frozen=True)
class CausalAcceleration:
    """A fitted filter: ``weights`` (6, taps) [1/s], ``weights[j, i]`` multiplies
    ``dq_j[k + lookahead - i]``.

    ``dt_s`` is the sample period it was fitted at: other rates need another fit.
    ``lookahead`` [samples] above 0 makes a filter for whole segments only.
    """

    weights: np.ndarray
    dt_s: float
    lookahead: int = 0

    def __post_init__(self) -> None:
        w = np.asarray(self.weights, dtype=np.float64)
        if w.ndim != 2 or w.shape[0] != N_JOINTS or w.shape[1] < 2 or not np.isfinite(w).all():
            raise ConfigError(f"weights must be finite (6, taps >= 2), got {w.shape}")
        if not self.dt_s > 0:
            raise ConfigError(f"dt_s must be positive, got {self.dt_s}")
        if not 0 <= self.lookahead < w.shape[1]:
            raise ConfigError(f"lookahead must be 0 to taps - 1, got {self.lookahead}")
        object.__setattr__(self, "weights", w)

    @property
    def taps(self) -> int:
        return int(self.weights.shape[1])

    @classmethod
    def fit(cls, velocities: Sequence[np.ndarray], dt_s: float,
            config: CausalAccelerationConfig | None = None) -> CausalAcceleration:
        """Fit the taps on gap-free (T, 6) velocity segments sampled every ``dt_s`` seconds.

        Segments shorter than the target's window are skipped.
        """
        config = config if config is not None else CausalAccelerationConfig()
        rows: list[tuple[np.ndarray, np.ndarray]] = []
        n_window = accel_window(config, dt_s)
        lookahead = lookahead_samples(config, dt_s)
        for v in velocities:
            v = np.asarray(v, dtype=np.float64)
            if v.ndim != 2 or v.shape[1] != N_JOINTS:
                raise DataError(f"velocities must be (T, 6), got {v.shape}")
            if len(v) < n_window:
                continue
            target = smoothed_acceleration(v, dt_s, config.target_window_s, config.target_order)
            rows.append((velocity_history(v, config.taps, lookahead), target))
        if not rows:
            raise DataError(f"no velocity segment holds the {n_window} samples the fit needs")
        weights = np.zeros((N_JOINTS, config.taps))
        for group in config.groups:
            a = np.concatenate([w[:, :, j] for w, _ in rows for j in group])
            b = np.concatenate([t[:, j] for _, t in rows for j in group])
            weights[list(group)] = np.linalg.lstsq(a, b, rcond=None)[0]
        return cls(weights, float(dt_s), lookahead)

    def estimate(self, velocity: np.ndarray) -> np.ndarray:
        """Accelerations (T, 6) of one gap-free segment of (T, 6) velocities."""
        if self.lookahead == 0:
            return self.run(velocity, self.initial_state(1))[0]
        v = np.asarray(velocity, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != N_JOINTS:
            raise DataError(f"velocity must be (T, 6), got {v.shape}")
        if len(v) == 0:
            return np.zeros((0, N_JOINTS))
        return np.einsum("tij,ji->tj", velocity_history(v, self.taps, self.lookahead),
                         self.weights)

    def _streams(self) -> None:
        if self.lookahead:
            raise ConfigError(f"this acceleration filter reads {self.lookahead} samples ahead: "
                              "it estimates whole segments only and cannot stream")

    def initial_state(self, batch: int = 1) -> AccelerationState:
        """Empty history for ``batch`` streams."""
        return np.zeros((batch, self.taps, N_JOINTS)), np.zeros(batch, dtype=bool)

    def run(self, velocity: np.ndarray, state: AccelerationState
            ) -> tuple[np.ndarray, AccelerationState]:
        """Consecutive samples of one stream: (T, 6) velocities -> (T, 6) accelerations [rad/s^2;
        m/s^2] and the new state (``state``, for one stream, is not modified)."""
        self._streams()
        v = np.asarray(velocity, dtype=np.float64)
        history, started = state
        if v.ndim != 2 or v.shape[1] != N_JOINTS or history.shape[0] != 1:
            raise DataError(f"velocity must be (T, 6) of one stream, got {v.shape} "
                            f"for {history.shape[0]} streams")
        if len(v) == 0:
            return np.zeros((0, N_JOINTS)), state
        past = history[0, ::-1] if started[0] else np.repeat(v[:1], self.taps, axis=0)
        ext = np.concatenate([past, v])                       # oldest first
        newest_first = velocity_history(ext, self.taps)[self.taps:]     # (T, taps, 6)
        acc = np.einsum("tij,ji->tj", newest_first, self.weights)
        return acc, (newest_first[-1][None].copy(), np.ones(1, dtype=bool))

    def step(self, velocity: np.ndarray, state: AccelerationState
             ) -> tuple[np.ndarray, AccelerationState]:
        """One sample of ``batch`` streams: (B, 6) velocities -> (B, 6) accelerations, new
        state (``state`` is not modified)."""
        self._streams()
        v = np.asarray(velocity, dtype=np.float64)
        history, started = state
        if v.ndim != 2 or v.shape[1] != N_JOINTS or v.shape[0] != history.shape[0]:
            raise DataError(f"velocity must be ({history.shape[0]}, 6), got {v.shape}")
        new = np.empty_like(history)
        new[:, 1:] = history[:, :-1]
        new[:, 0] = v
        fresh = ~started
        if fresh.any():                        # first sample of a segment: pad with it
            new[fresh] = v[fresh, None, :]
        return (np.einsum("bij,ji->bj", new, self.weights),
                (new, np.ones_like(started)))
