"""Training recipes, results and data preparation shared by the two-step estimator's fits.

The fits themselves: step 1 (free space, ``Troc``) in
:mod:`~wrenchd.models.estimator.free_space_training`, ``Xfer`` and ``Corr`` in
:mod:`~wrenchd.models.estimator.correction_training`.

Recipes follow Wu, Yilmaz, Kazanzides, Tumerdem (arXiv 2012.01479): Adam at a learning rate
of 1e-3; the step-1 networks 1000 epochs with the rate halved every 125 epochs; the
correction network 400 epochs with L2 weight decay 0.01 (Adam's coupled ``weight_decay``,
i.e. an L2 penalty, not AdamW). The ``Xfer`` recipe reuses the step-1 schedule (an assumption).

The validation split is the last ``val_fraction`` of every series (contiguous in time). All
randomness (initial weights, dropout, lane order) comes from ``seed``. Train on motion without
contact: the target is the measured effort.

The paper's variants, as (function, recipe, data):

=======  ===============================  ==========================================
Base     ``fit_free_space``, free-space   free motion, no trocar
Troc     ``fit_free_space``, ``"troc"``   trocar motion only (step-1 structure)
Corr     ``fit_corr`` on Base, ``"corr"``  trocar motion, a few minutes
Xfer     ``fit_xfer`` on Base, ``"xfer"``  trocar motion, a few minutes
=======  ===============================  ==========================================
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.features import segments
from wrenchd.models.series import JointStates

Segment = tuple[np.ndarray, np.ndarray]          # (T, 12) features, (T, 6) measured torques


class TrainConfig(BaseModel):
    """Optimisation of one network."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    epochs: int = Field(default=1000, ge=1, description="maximum number of epochs")
    lr: float = Field(default=1e-3, gt=0.0, description="Adam learning rate")
    lr_halving_epochs: int | None = Field(default=125, ge=1,
                                          description="halve the rate every N epochs; None: never")
    batch_size: int = Field(default=16, ge=1, description="lanes (recurrent) or samples (Corr)")
    window: int = Field(default=100, ge=2, description="truncated-BPTT window [samples]")
    lane_windows: int = Field(default=8, ge=1, description="windows per lane (state carried)")
    weight_decay: float = Field(default=0.0, ge=0.0, description="L2 penalty (Adam weight_decay)")
    grad_clip: float | None = Field(default=1.0, gt=0.0, description="max gradient norm per group")
    patience: int | None = Field(default=100, ge=1, description="early-stopping patience [epochs]")
    val_fraction: float = Field(default=0.2, gt=0.0, lt=1.0, description="validation tail share")
    max_gap_s: float = Field(default=0.05, gt=0.0, description="gap that splits a series [s]")
    seed: int = Field(default=0, description="seed of every random choice")
    sample_stride: int = Field(default=1, ge=1,
                               description="Corr: epoch k uses every n-th sample from offset "
                                           "k mod n (200 Hz neighbours are near duplicates)")


#: Named recipes. ``troc`` is the step-1 structure trained directly on trocar data.
RECIPES: dict[str, TrainConfig] = {
    "free-space": TrainConfig(epochs=1000, lr_halving_epochs=125),
    "troc": TrainConfig(epochs=1000, lr_halving_epochs=125),
    "xfer": TrainConfig(epochs=1000, lr_halving_epochs=125),
    "corr": TrainConfig(epochs=400, lr_halving_epochs=None, weight_decay=0.01, batch_size=256),
    # A Corr in seconds on a CPU, for adaptation: large batches, a ten times higher rate
    # halved every 5 epochs, 16 epochs over a quarter of the samples each (the offset
    # rotates, so 4 passes over the data in all), no early stop. Compared with the paper's
    # recipe in docs/results.md.
    "corr-fast": TrainConfig(epochs=16, lr=1e-2, lr_halving_epochs=5, weight_decay=0.01,
                             batch_size=1024, sample_stride=4, patience=None),
}


def recipe(name: str, **overrides: Any) -> TrainConfig:
    """The named recipe with fields overridden (e.g. ``recipe("corr", epochs=20)``)."""
    try:
        base = RECIPES[name]
    except KeyError:
        raise ConfigError(f"unknown recipe {name!r}; choose one of {sorted(RECIPES)}") from None
    return TrainConfig(**{**base.model_dump(), **overrides})       # validates the overrides


@dataclass
class TrainResult:
    """A trained model with what a checkpoint records about it."""

    kind: str                                   # "free_space", "xfer" or "corr"
    model: torch.nn.Module
    train_config: TrainConfig
    data: dict[str, Any]
    validation: dict[str, Any]
    history: list[float] = field(default_factory=list)   # validation score per epoch


def split_series(series: Sequence[JointStates], val_fraction: float, max_gap_s: float
                 ) -> tuple[list[Segment], list[Segment]]:
    """Training and validation segments: the last ``val_fraction`` of each series validates."""
    train, val = [], []
    for s in series:
        x = np.concatenate([s.position, s.velocity], axis=1)
        cut = len(s) - int(round(len(s) * val_fraction))
        for part, out in ((slice(0, cut), train), (slice(cut, len(s)), val)):
            t = s.t[part]
            for seg in segments(t, max_gap_s):
                if seg.stop - seg.start >= 2:
                    out.append((x[part][seg], s.effort[part][seg]))
    if not train or not val:
        raise DataError("not enough samples for a training and a validation split")
    return train, val


def describe_data(series: Sequence[JointStates], data: dict[str, Any] | None,
                  config: TrainConfig) -> dict[str, Any]:
    """The data description a checkpoint stores: the caller's labels plus counts."""
    return {**(data or {}), "n_series": len(series), "n_samples": int(sum(len(s) for s in series)),
            "duration_s": float(sum(s.t[-1] - s.t[0] for s in series if len(s) > 1)),
            "rate_hz": [s.rate_hz for s in series], "val_fraction": config.val_fraction}


def rmse_report(pred: np.ndarray, target: np.ndarray, baseline_mean: np.ndarray,
                 scale: np.ndarray) -> dict[str, Any]:
    rmse = np.sqrt(np.mean((pred - target) ** 2, axis=0))
    base = np.sqrt(np.mean((target - baseline_mean) ** 2, axis=0))
    return {"rmse": rmse.tolist(), "baseline_rmse": base.tolist(),
            "score": float(np.mean(rmse / scale))}


def training_device(device: str | torch.device | None = None) -> torch.device:
    """The device to train on: ``device`` if given, else CUDA when present, else the CPU."""
    if device is not None:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")
