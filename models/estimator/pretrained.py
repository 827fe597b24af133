"""Shipped step-1 weights, trained on the simulator (the service's embedded default).

==========  ==========================  ============================================================
name        file                        trained on
==========  ==========================  ============================================================
base        ``weights/sim-base.pt``     ``free-space`` scenario (no seal): the paper's Base
seal        ``weights/sim-seal.pt``     ``free-space-seal`` scenario (cannula seal): the paper's Seal
paper-base  ``weights/paper-base.pt``   an hour of free motion, patient variation: Base to convergence
paper-seal  ``weights/paper-seal.pt``   the same with the cannula seal: Seal to convergence
==========  ==========================  ============================================================

``base`` and ``seal`` are produced by a seeded, documented command (the config beside each)::

    wrenchd train --config models/estimator/weights/sim-base.toml
    wrenchd train --config models/estimator/weights/sim-seal.toml

with shortened recipes (tens of epochs, minutes on two CPU cores). ``paper-base`` and
``paper-seal`` are the paper-scale run's step 1 (the paper's recipe, early-stopped on held-out
sessions of unseen patients, training seed 0), copied from what that run writes::

    wrenchd reproduce --paper --threads 1 --out reports/paper-scale
    cp reports/paper-scale/weights/Base-seed0.pt models/estimator/weights/paper-base.pt
    cp reports/paper-scale/weights/Seal-seed0.pt models/estimator/weights/paper-seal.pt

Each checkpoint's ``train`` config, ``data`` and ``validation`` record what was run and how it
scored (``converged``: early stopping ended it, not the epoch ceiling).
"""

from __future__ import annotations

from pathlib import Path

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.checkpoint import load_checkpoint
from wrenchd.models.estimator.free_space import FreeSpaceModel

#: The shipped step-1 models by name, and their files under :data:`WEIGHTS_DIR`.
FILES: dict[str, str] = {"base": "sim-base.pt", "seal": "sim-seal.pt",
                         "paper-base": "paper-base.pt", "paper-seal": "paper-seal.pt"}
#: Names of the shipped step-1 models.
PRETRAINED: tuple[str, ...] = tuple(FILES)
WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"


def pretrained_path(name: str = "base") -> Path:
    """Path of the shipped checkpoint ``name`` (one of :data:`PRETRAINED`).

    Raises:
        ConfigError: unknown name.
    """
    if name not in PRETRAINED:
        raise ConfigError(f"unknown pretrained model {name!r}; choose one of {list(PRETRAINED)}")
    return WEIGHTS_DIR / FILES[name]


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
