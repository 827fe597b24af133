"""Where a pipeline's step-1 model comes from: a shipped model by name or a checkpoint file."""

from __future__ import annotations

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.free_space import FreeSpaceModel


def load_free_space(spec: str) -> FreeSpaceModel:
    """A shipped step-1 model by name (``base``, ``seal``) or a step-1 checkpoint file."""
    from wrenchd.models.estimator.checkpoint import load_checkpoint
    from wrenchd.models.estimator.pretrained import PRETRAINED, load_pretrained

    if spec in PRETRAINED:
        return load_pretrained(spec)
    ckpt = load_checkpoint(spec)
    if ckpt.kind != "free_space":
        raise ConfigError(f"{spec}: the arm model must be a step-1 checkpoint, got {ckpt.kind}")
    return ckpt.model
