"""The per-sample pipeline that the daemon and replay both drive.

validate -> estimate -> wrench -> gate -> offer to the adaptation -> swap models; see
:class:`~wrenchd.service.pipeline.arm.ArmPipeline`.
"""

from wrenchd.service.pipeline.adaptation import AdaptationBackend, InlineAdaptation, initial_corr
from wrenchd.service.pipeline.arm import ArmPipeline
from wrenchd.service.pipeline.config import (POLICIES, CalibrationGuardConfig, PipelineConfig,
                                             PolicyConfig, ValidationConfig)
from wrenchd.service.pipeline.records import Counters, Estimate, Event, EventKind
from wrenchd.service.pipeline.validation import SampleValidator, accepted_indices

__all__ = ["POLICIES", "AdaptationBackend", "ArmPipeline", "CalibrationGuardConfig", "Counters",
           "Estimate", "Event", "EventKind", "InlineAdaptation", "PipelineConfig", "PolicyConfig",
           "SampleValidator", "ValidationConfig", "accepted_indices", "initial_corr"]
