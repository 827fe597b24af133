"""How the pipeline reaches the lifelong adaptation: the backend interface and the inline one.

The daemon's backend is a worker process (:mod:`wrenchd.service.runtime.worker`), replay's a
forked worker in sample time (:mod:`wrenchd.service.replay.worker`) or :class:`InlineAdaptation`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from wrenchd.models.adaptation import Adapter, AdaptationConfig, RoundResult
from wrenchd.models.adaptation.host import SETUP_CALLS, AdapterHost
from wrenchd.models.adaptation.config import corr_config_of
from wrenchd.models.estimator.correction import Corr, zero_corr

class AdaptationBackend(Protocol):
    """Where offered samples go and accepted models come from."""

    def offer(self, windows: np.ndarray, step1: np.ndarray, measured: np.ndarray,
              t: np.ndarray | None = None) -> None: ...
    def drift(self, t: float) -> None: ...
    def setup_change(self, t: float, kind: str = "pressure") -> None: ...
    def tick(self, t: float) -> list[RoundResult]: ...
    def reset(self, t: float) -> None: ...
    def close(self) -> None: ...


class InlineAdaptation:
    """The adaptation host run synchronously in the pipeline's (simulated) time: replay."""

    ARM = "inline"

    def __init__(self, config: AdaptationConfig,
                 normalisation: dict[str, np.ndarray] | None = None) -> None:
        self.host = AdapterHost({self.ARM: config}, {self.ARM: normalisation})

    @property
    def adapter(self) -> Adapter:
        return self.host.adapters[self.ARM]

    def offer(self, windows, step1, measured, t=None) -> None:
        self.host.call(self.ARM, "samples", 0.0, (windows, step1, measured, t))

    def drift(self, t: float) -> None:
        self.host.call(self.ARM, "drift", t)

    def setup_change(self, t: float, kind: str = "pressure") -> None:
        self.host.call(self.ARM, SETUP_CALLS[kind], t, t)

    def tick(self, t: float) -> list[RoundResult]:
        result = self.host.call(self.ARM, "tick", t)
        return [] if result is None else [result]

    def reset(self, t: float) -> None:
        self.host.call(self.ARM, "reset", t)

    def close(self) -> None:
        pass


def initial_corr(config: AdaptationConfig) -> Corr:
    """The pipeline's starting ``Corr``: identity normalisation, output exactly zero."""
    return zero_corr(corr_config_of(config))
