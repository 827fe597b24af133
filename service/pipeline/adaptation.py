"""How the pipeline reaches the lifelong adaptation: the backend interface and the inline one.

The daemon's backend is a worker process (:mod:`wrenchd.service.runtime.worker`), replay's a
forked worker in sample time (:mod:`wrenchd.service.replay.worker`) or :class:`InlineAdaptation`.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from wrenchd.models.adaptation.adapter import Adapter, AdaptationConfig, RoundResult
from wrenchd.models.estimator.correction import Corr, CorrConfig, zero_corr

class AdaptationBackend(Protocol):
    """Where offered samples go and accepted models come from."""

    def offer(self, windows: np.ndarray, step1: np.ndarray, measured: np.ndarray,
              t: np.ndarray | None = None) -> None: ...
    def drift(self, t: float) -> None: ...
    def setup_change(self, t: float) -> None: ...
    def tick(self, t: float) -> list[RoundResult]: ...
    def reset(self, t: float) -> None: ...
    def close(self) -> None: ...


class InlineAdaptation:
    """The :class:`Adapter` run synchronously in the pipeline's (simulated) time: replay."""

    def __init__(self, config: AdaptationConfig,
                 normalisation: dict[str, np.ndarray] | None = None) -> None:
        self.config, self.normalisation = config, normalisation
        self.adapter = Adapter(config, normalisation=normalisation)

    def offer(self, windows, step1, measured, t=None) -> None:
        self.adapter.add(windows, step1, measured, t)

    def drift(self, t: float) -> None:
        self.adapter.on_drift(t)

    def setup_change(self, t: float) -> None:
        self.adapter.on_setup_change(t)

    def tick(self, t: float) -> list[RoundResult]:
        result = self.adapter.round(t)
        return [] if result is None else [result]

    def reset(self, t: float) -> None:
        self.adapter = Adapter(self.config, normalisation=self.normalisation)

    def close(self) -> None:
        pass


def initial_corr(config: AdaptationConfig) -> Corr:
    """The pipeline's starting ``Corr``: identity normalisation, output exactly zero."""
    return zero_corr(CorrConfig(window=config.window, hidden_size=config.hidden_size))
