"""Shipped step-1 weights, trained on the simulator (the service's embedded default).

=======  ====================  ==================================================================
name     file                  trained on
=======  ====================  ==================================================================
base     ``weights/sim-base.pt``  ``free-space`` scenario (no seal): the paper's Base
seal     ``weights/sim-seal.pt``  ``free-space-seal`` scenario (cannula seal): the paper's Seal
=======  ====================  ==================================================================

Each file is produced by a seeded, documented command (the config beside it)::

    wrenchd train --config models/estimator/weights/sim-base.toml
    wrenchd train --config models/estimator/weights/sim-seal.toml

The recipes are shortened (tens of epochs, minutes on two CPU cores) compared with the
paper's 1000 epochs; each checkpoint's ``train`` config and ``data`` record what was run.
"""

from __future__ import annotations

from pathlib import Path

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.checkpoint import load_checkpoint
from wrenchd.models.estimator.free_space import FreeSpaceModel

#: Names of the shipped step-1 models.
PRETRAINED: tuple[str, ...] = ("base", "seal")
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"


def pretrained_path(name: str = "base") -> Path:
    """Path of the shipped checkpoint ``name`` (one of :data:`PRETRAINED`).

    Raises:
        ConfigError: unknown name.
    """
    if name not in PRETRAINED:
        raise ConfigError(f"unknown pretrained model {name!r}; choose one of {list(PRETRAINED)}")
    return WEIGHTS_DIR / f"sim-{name}.pt"


def load_pretrained(name: str = "base") -> FreeSpaceModel:
    """The shipped step-1 model ``name`` in eval mode (float32, CPU).

    Raises:
        ConfigError: unknown name, or the file is missing or not a step-1 checkpoint.
    """
    path = pretrained_path(name)
    ckpt = load_checkpoint(path)
    if ckpt.kind != "free_space":
        raise ConfigError(f"{path}: expected a step-1 (free_space) checkpoint, got {ckpt.kind}")
    return ckpt.model
