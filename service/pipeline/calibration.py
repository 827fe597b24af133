"""The check that the contact-free calibration at a session's start is contact-free.

The step-1 residual (measured minus step-1 torque) does not change while the correction net
calibrates, and the step-1 model's validation RMSE says how large it is in free motion; a
contact adds ``J^T w`` on top. A :class:`FreeMotionGate` on that residual, seeded from the
RMSE instead of a warm-up that could itself be spent in contact, judges from the first sample
(:class:`~wrenchd.service.pipeline.config.CalibrationGuardConfig`).
"""

from __future__ import annotations

import numpy as np

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.gate import FreeMotionGate, GateDecision
from wrenchd.models.series import N_JOINTS
from wrenchd.service.pipeline.config import CalibrationGuardConfig, PipelineConfig


class CalibrationGuard:
    """A gate on the step-1 residual during the calibration.

    Args:
        gate: the seeded gate.
        config: the guard's settings (``action``: warn or refuse).
    """

    def __init__(self, gate: FreeMotionGate, config: CalibrationGuardConfig) -> None:
        self.gate, self.config = gate, config
        self.refuses = config.action == "refuse"
        self.last_free = True            # the verdict on the last sample judged

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
        gate = FreeMotionGate(config.gate)
        gate.seed(g.scale_factor * np.asarray(scale, dtype=float))
        return cls(gate, g)

    def judge(self, index: int, t: float, residual: np.ndarray, score: float) -> GateDecision:
        """The verdict on one calibration sample from its step-1 residual (6,) [N m; N];
        ``score`` is the main gate's and stays in the decision. With ``action: warn`` every
        sample stays free and trainable (the guard only counts, in :attr:`last_free`)."""
        g = self.gate.update(index, t, residual)
        self.last_free = g.free
        if not self.refuses:
            return GateDecision(True, score, -1, trainable=True)
        trainable = g.free if self.config.borderline_trains else g.trainable
        return GateDecision(g.free, score, g.contact_started, trainable=trainable)
