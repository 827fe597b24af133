"""What the pipeline hands its driver: per-sample estimates, events and counters."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np


class EventKind(StrEnum):
    """What an :class:`Event` tells; a member equals its string (``EventKind.DRIFT == "drift"``),
    the form logs and subscribers carry."""

    ERROR = "error"
    GAP = "gap"
    JUMP = "jump"
    CLOCK_RESET = "clock_reset"
    CALIBRATING = "calibrating"
    CALIBRATED = "calibrated"
    CALIBRATION_CONTAMINATED = "calibration_contaminated"
    MODEL_MISMATCH = "model_mismatch"
    CONTACT_START = "contact_start"
    CONTACT_END = "contact_end"
    GATE_SETUP_CHANGE = "gate_setup_change"
    GATE_SETUP_WITHDRAWN = "gate_setup_withdrawn"
    GATE_RECALIBRATED = "gate_recalibrated"
    DRIFT = "drift"
    SETUP_CHANGE = "setup_change"
    ROUND = "round"
    MODEL = "model"
    ADAPTATION_ERROR = "adaptation_error"
    LOG_ERROR = "log_error"
    LOG_REMOVED = "log_removed"
    ZENOH_LINK = "zenoh_link"


@dataclass(frozen=True)
class Event:
    """Something worth telling subscribers and the log: ``kind`` and JSON-able ``detail``."""

    t: float
    kind: EventKind
    detail: dict[str, Any]

    def __post_init__(self) -> None:
        if not isinstance(self.kind, EventKind):      # a kind read back from a log
            object.__setattr__(self, "kind", EventKind(self.kind))

    def to_json(self) -> dict[str, Any]:
        return {"t": self.t, "kind": self.kind, **self.detail}


@dataclass(frozen=True)
class Estimate:
    """One sample's outputs (arrays (6,) as in :class:`EstimatorOutput`)."""

    index: int
    stamp_ns: int
    t: float
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    wrench: np.ndarray
    predicted_torque: np.ndarray
    external_torque: np.ndarray
    free: bool
    score: float
    model_version: int
    restarted: bool

    def __init__(self, index: int, stamp_ns: int, t: float, position: np.ndarray,
                 velocity: np.ndarray, effort: np.ndarray, wrench: np.ndarray,
                 predicted_torque: np.ndarray, external_torque: np.ndarray, free: bool,
                 score: float, model_version: int, restarted: bool) -> None:
        # One per sample: a dict update instead of the generated frozen __init__'s
        # object.__setattr__ per field (2-3 us less a sample); immutable all the same.
        self.__dict__.update(
            index=index, stamp_ns=stamp_ns, t=t, position=position, velocity=velocity,
            effort=effort, wrench=wrench, predicted_torque=predicted_torque,
            external_torque=external_torque, free=free, score=score,
            model_version=model_version, restarted=restarted)


@dataclass
class Counters:
    received: int = 0
    estimated: int = 0
    errors: int = 0
    gaps: int = 0
    jumps: int = 0            # position jumps that restarted the estimator
    dropped: int = 0          # set by the daemon (ring buffer overflow)
    offered: int = 0          # samples given to the adaptation
    discarded_onsets: int = 0  # free-looking samples dropped because a contact began
    held_back: int = 0         # free samples kept from training: a weak contact's form
    calibration_samples: int = 0   # samples estimated during the calibration
    calibration_contact: int = 0   # of those, the calibration guard called contact
    drifts: int = 0
    setup_changes: int = 0     # announced set-up changes taken
    rounds: int = 0
    swaps: int = 0
    error_kinds: dict[str, int] = field(default_factory=dict)
