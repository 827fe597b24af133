"""Lifelong adaptation of the correction net: the deterministic adapter, its sample buffer, and
the host that applies a pipeline's calls to every arm's adapter on the caller's clock."""

from wrenchd.models.adaptation.adapter import Adapter, normalisation_of
from wrenchd.models.adaptation.config import AdaptationConfig, RoundResult
from wrenchd.models.adaptation.host import AdapterHost

__all__ = ["AdaptationConfig", "Adapter", "AdapterHost", "RoundResult", "normalisation_of"]
