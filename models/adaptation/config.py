"""The adaptation's settings and what one fine-tuning round reports."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from wrenchd.models.body_wall_tracker import BodyWallTrackerConfig
from wrenchd.models.estimator.correction import CorrConfig, CorrKernel


class AdaptationConfig(BaseModel):
    """How the correction net follows the set-up."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(default=True, description="fine-tune the correction net online")
    recent_size: int = Field(default=3000, ge=16, description="recent ring [samples]")
    reservoir_size: int = Field(default=6000, ge=0, description="older samples kept [samples]")
    recent_fraction: float = Field(default=0.6, ge=0.0, le=1.0,
                                   description="share of a batch drawn from the recent ring")
    holdout_every: int = Field(default=5, ge=2, description="every k-th sample validates")
    holdout_size: int = Field(default=800, ge=16, description="recent held-out samples")
    min_train_samples: int = Field(default=600, ge=16,
                                   description="samples before the first round")
    round_steps: int = Field(default=40, ge=1, description="Adam steps per round")
    batch_size: int = Field(default=128, ge=1, description="samples per Adam step")
    lr: float = Field(default=2e-3, gt=0.0, description="Adam learning rate")
    weight_decay: float = Field(default=0.01, ge=0.0, description="L2 penalty (paper's Corr)")
    min_improvement: float = Field(default=0.005, ge=0.0, lt=1.0,
                                   description="relative validation gain needed to swap")
    interval_s: float = Field(default=2.0, gt=0.0, description="time between rounds [s]")
    eager_interval_s: float = Field(default=0.5, gt=0.0,
                                    description="time between rounds after a drift [s]")
    eager_s: float = Field(default=30.0, ge=0.0, description="eager period after a drift [s]")
    skip_idle: bool = Field(
        default=False,
        description="outside an eager period, a round that falls due with no sample offered "
                    "since the last round (a contact holding the buffer, an arm at rest) is "
                    "skipped: it would train on what the last one trained on")
    backoff_after: int = Field(
        default=0, ge=0,
        description="outside an eager period, after this many rounds in a row whose candidate "
                    "was refused (the held-out error stopped improving) the interval doubles "
                    "per further refusal, up to backoff_max x interval_s, until one is "
                    "accepted or the set-up changes; 0 = never")
    backoff_max: float = Field(default=4.0, ge=1.0,
                               description="the longest backed-off interval, in interval_s")
    hidden_size: int = Field(default=64, ge=1, description="Corr hidden units (paper: 256)")
    window: int = Field(default=10, ge=1, description="Corr history window (paper: 10)")
    max_cpu_fraction: float = Field(default=0.5, gt=0.0, le=1.0,
                                    description="duty cycle of the daemon's worker process")
    refit_shrink: float = Field(
        default=0.3, ge=0.0,
        description="ridge weight of the output-layer refit on the recent ring, towards the "
                    "current weights, as a multiple of the mean diagonal of the hidden "
                    "features' Gram matrix [-]; 0 = no refit (module docstring)")
    drift_carry_over: bool = Field(
        default=True,
        description="a detected drift also carries the buffer over as an announced pressure "
                    "change does, the change taken at the detection minus drift_lead_s "
                    "(recovery from the data alone: docs/results.md)")
    drift_lead_s: float = Field(default=0.0, ge=0.0,
                                description="how long before its detection a drift is taken "
                                            "to have begun [s]")
    trocar_physics: bool = Field(
        default=True,
        description="step 2 also holds the body wall's physics (a spring-damper about the "
                    "incision), linear in 12 parameters that the rounds fit by least squares "
                    "on the buffer (trocar_fit_s): what carries to poses the net has not seen "
                    "(models/estimator/trocar_physics.py)")
    trocar_fit_s: float = Field(
        default=60.0, ge=0.0,
        description="the body wall's physics is re-fitted in the rounds of this long from the "
                    "first one [s] (the calibration minute) and then held: the net follows "
                    "what changes later; inf: re-fitted in every round")
    trocar_shrink: float = Field(
        default=1e-3, ge=0.0,
        description="ridge weight of that fit towards the current parameters, as a multiple "
                    "of the mean diagonal of its column-scaled Gram matrix [-]")
    seed: int = Field(default=0, description="seed of the batches and of a fresh Corr's weights")
    body_wall: BodyWallTrackerConfig = Field(
        default_factory=BodyWallTrackerConfig,
        description="the body wall's stiffness tracking and the carry-over at an announced "
                    "set-up change")

    @model_validator(mode="after")
    def _reachable(self) -> AdaptationConfig:
        """The first round needs ``min_train_samples`` in the recent ring and the reservoir
        together: more than they hold would never come."""
        held = self.recent_size + self.reservoir_size
        if self.min_train_samples > held:
            raise ValueError(f"min_train_samples ({self.min_train_samples}) exceeds what "
                             f"recent_size + reservoir_size hold ({held}): no round would run")
        return self


def corr_config_of(config: AdaptationConfig) -> CorrConfig:
    """The structure of the correction net that ``config`` adapts."""
    return CorrConfig(window=config.window, hidden_size=config.hidden_size,
                      trocar_physics=config.trocar_physics)


@dataclass
class RoundResult:
    """What one round did; ``accepted`` rounds carry the new version."""

    t: float
    accepted: bool
    version: int
    val_before: float
    val_after: float
    n_train: int
    n_holdout: int
    eager: bool
    state_dict: dict[str, np.ndarray] | None = None
    #: the accepted net's serving kernel, built where the round ran (the adaptation worker),
    #: so the process that serves swaps a reference instead of building a module
    kernel: CorrKernel | None = None
    #: the body wall's stiffness [N/m] per segment between announced set-up changes, as the
    #: tracker estimates it (None: no bin yet); one entry until a change is announced
    body_wall: list[float | None] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        return {"t": self.t, "accepted": self.accepted, "version": self.version,
                "val_before": self.val_before, "val_after": self.val_after,
                "n_train": self.n_train, "n_holdout": self.n_holdout, "eager": self.eager,
                "body_wall_n_per_m": self.body_wall}
