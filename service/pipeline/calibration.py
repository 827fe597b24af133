"""The check that the contact-free calibration at a session's start is contact-free.

The step-1 residual (measured minus step-1 torque) does not change while the correction net
calibrates, and the step-1 model's held-out (validation) RMSE says how large it is in free
motion; a contact adds ``J^T w`` on top. A :class:`FreeMotionGate` on that residual, seeded from
the RMSE instead of a warm-up that could itself be spent in contact, judges from the first
sample (:class:`~wrenchd.service.pipeline.config.CalibrationGuardConfig`).

Robust statistics over the window (at most one sample per 5 ms of it) follow: each second
from 2 s into the window on, the
residual's robust level per joint (1.4826 x the median absolute residual: a normal RMS
that the contacts, as long as they fill less than half of the window, hardly move) sets the
guard's scale to ``robust_factor`` x that level, never below the seeded scale and never above
``max_growth`` x it. The model's **fit ratio** of a joint is the residual's lower-quartile
level (the |residual| that three samples in four exceed, as a normal RMS) over its held-out
RMSE (floored by the gate's ``min_std``), judged from 5 s into the window on: a misfit is
in nearly every sample, a contact in some (the median would take a contact that fills more
than half of the window's first seconds for a misfit; the lower quartile needs three
quarters). Above ``mismatch_ratio`` on a joint, the step-1 model does not explain this arm
there (a wrong checkpoint, a set-up it never saw). The guard says so (:attr:`CalibrationGuard.mismatch`) and that joint's scale
follows the window's level without the bound, instead of the guard calling nearly every
sample contact; the other joints, bounded as before, still see the contacts.
"""

from __future__ import annotations

import numpy as np

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.gate import FreeMotionGate, GateDecision
from wrenchd.models.series import N_JOINTS
from wrenchd.service.pipeline.config import CalibrationGuardConfig, PipelineConfig

#: the window's robust level is first used this long after the calibration's start, then
#: recomputed this often [s]
ROBUST_AFTER_S, ROBUST_EVERY_S = 2.0, 1.0
#: the fit ratio is first judged this long after the calibration's start [s]
MISMATCH_AFTER_S = 5.0
#: the window keeps at most one sample per this much time [s] (with a tolerance for jitter):
#: every sample at the 200 Hz of a dVRK recording, one in five at 1 kHz. The robust level's
#: quantiles over a minute of 1 kHz samples cost several milliseconds once a second, a stall
#: every arm's estimates wait through; neighbouring samples add next to nothing to them.
WINDOW_EVERY_S = 0.005
_WINDOW_TOLERANCE_S = 0.0005
#: median |x| of a zero-mean normal is 0.6745 sigma, its lower quartile 0.3186 sigma
MAD_TO_RMS, Q25_TO_RMS = 1.4826, 1.0 / 0.31864


class CalibrationGuard:
    """A gate on the step-1 residual during the calibration.

    Args:
        gate: the gate (seeded by :meth:`start`).
        config: the guard's settings (``action``: warn or refuse).
        heldout: (6,) free-motion RMS of the step-1 residual [N m; N on insertion]: the
            step-1 checkpoint's validation RMSE, or ``config.residual_scale``.
    """

    def __init__(self, gate: FreeMotionGate, config: CalibrationGuardConfig,
                 heldout: np.ndarray) -> None:
        self.gate, self.config = gate, config
        self.refuses = config.action == "refuse"
        # the fit ratio's unit: the held-out RMSE, floored as the gate floors its scale
        self.heldout = np.maximum(np.asarray(heldout, dtype=float),
                                  np.asarray(gate.config.min_std, dtype=float))
        self.seed_scale = config.scale_factor * np.asarray(heldout, dtype=float)
        self.start()

    @classmethod
    def build(cls, config: PipelineConfig, free_space: FreeSpaceModel) -> CalibrationGuard | None:
        """The pipeline's guard, or None (off, no calibration, no known residual scale).

        Raises:
            ConfigError: a residual scale without one value per joint.
        """
        g = config.calibration_guard
        scale = g.residual_scale
        if scale is None:
            scale = getattr(free_space, "validation_rmse", None)
        if not g.enabled or scale is None or config.calibration_s <= 0:
            return None
        if len(scale) != N_JOINTS:
            raise ConfigError(f"calibration_guard.residual_scale needs {N_JOINTS} values, "
                              f"got {len(scale)}")
        return cls(FreeMotionGate(config.gate), g, np.asarray(scale, dtype=float))

    def start(self) -> None:
        """A new calibration: the seeded scale, an empty window, no verdict on the fit."""
        self.gate.seed(self.seed_scale)
        self.last_free = True            # the verdict on the last sample judged
        self.ratios: np.ndarray | None = None     # (6,) fit ratio per joint, once judged
        self.mismatch = False
        self._window = np.empty((1024, N_JOINTS))
        self._n = 0
        self._kept_t = -np.inf
        self._t0: float | None = None
        self._next_t = 0.0

    @property
    def ratio(self) -> float | None:
        """The largest per-joint fit ratio (None before it is judged)."""
        return None if self.ratios is None else float(self.ratios.max())

    def _remember(self, t: float, residual: np.ndarray) -> None:
        if t - self._kept_t >= WINDOW_EVERY_S - _WINDOW_TOLERANCE_S:
            self._kept_t = t
            if self._n == len(self._window):
                self._window = np.concatenate([self._window, np.empty_like(self._window)])
            self._window[self._n] = np.abs(residual)
            self._n += 1
        if self._t0 is None:
            self._t0 = t
            self._next_t = t + ROBUST_AFTER_S
        elif t >= self._next_t:
            self._next_t = t + ROBUST_EVERY_S
            self._follow_level(t - self._t0)

    def _follow_level(self, elapsed_s: float) -> None:
        """Set the gate's scale from the window's robust level; judge the fit."""
        q25, median = np.quantile(self._window[:self._n], (0.25, 0.5), axis=0)
        level = MAD_TO_RMS * median
        if elapsed_s >= MISMATCH_AFTER_S:
            self.ratios = Q25_TO_RMS * q25 / self.heldout
            self.mismatch = bool(self.ratios.max() > self.config.mismatch_ratio)
        scale = np.maximum(self.config.robust_factor * level, self.seed_scale)
        bounded = np.minimum(scale, self.gate.config.max_growth * self.seed_scale)
        if self.ratios is not None:         # a joint the model does not fit: its own level
            bounded = np.where(self.ratios > self.config.mismatch_ratio, scale, bounded)
        self.gate.rescale(bounded)

    def judge(self, index: int, t: float, residual: np.ndarray) -> GateDecision:
        """The verdict on one sample from its step-1 residual (6,) [N m; N], with the guard's
        peak score. With ``action: warn`` every sample stays free and trainable (the guard
        only counts, in :attr:`last_free`)."""
        self._remember(t, residual)
        g = self.gate.update(index, t, residual)
        # a contact the gate has released (published free, the contact's until it ends) is
        # contact to the guard: its verdicts are about training
        free = g.free and g.contact_started < 0
        self.last_free = free
        if not self.refuses:
            return GateDecision(True, g.score, -1, trainable=True)
        trainable = free if self.config.borderline_trains else g.trainable
        return GateDecision(free, g.score, g.contact_started, trainable=trainable)
