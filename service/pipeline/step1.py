"""Where a pipeline's step-1 model comes from, and what it is.

A model spec is one of:

* a shipped model by name (``base``, ``seal``): LSTMs trained on the simulator;
* a step-1 checkpoint file (``wrenchd train``);
* a model bundle directory (``wrenchd fit``): a hybrid step 1 fitted to a robot's own
  recordings (:mod:`wrenchd.adapters.bundle`, :mod:`wrenchd.models.estimator.hybrid`).

:class:`Step1` carries the model with its origin (``simulator``, ``robot`` or ``unknown``) and
a digest of what was loaded, for the daemon's status and log.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wrenchd.models.errors import ConfigError

#: A bundle's step-1 kind (its ``weights_config["kind"]``).
HYBRID_KIND = "hybrid"


@dataclass(frozen=True)
class Step1:
    """A loaded step-1 model and where it came from.

    Attributes:
        model: a :class:`~wrenchd.models.estimator.free_space.FreeSpaceModel` or a
            :class:`~wrenchd.models.estimator.hybrid.HybridStep1`.
        spec: what was asked for (a name or a path).
        kind: ``"lstm"`` or ``"hybrid"``.
        origin: ``"simulator"``, ``"robot"`` or ``"unknown"``.
        digest: sha256 of the weights file, or the bundle's digest.
    """

    model: Any
    spec: str
    kind: str
    origin: str
    digest: str

    def to_json(self) -> dict[str, str]:
        return {"spec": self.spec, "kind": self.kind, "origin": self.origin,
                "digest": self.digest}


def load_bundle_step1(path: str | os.PathLike[str]):
    """The hybrid step 1 of the bundle at ``path``, and the bundle. The model's
    ``validation_rmse`` is the bundle's held-out RMSE per joint (the calibration guard's
    scale of a free-motion residual).

    Raises:
        ConfigError: not a bundle, a damaged one, or one holding no hybrid step 1.
    """
    from wrenchd.adapters.bundle import read_bundle
    from wrenchd.models.estimator.hybrid import HybridStep1

    bundle = read_bundle(path)
    cfg = dict(bundle.weights_config or {})
    if bundle.weights is None or cfg.pop("kind", None) != HYBRID_KIND:
        raise ConfigError(f"{path}: the bundle holds no hybrid step-1 model")
    arrays = {k: v.numpy() for k, v in bundle.weights.items()}
    model = HybridStep1.from_parts(arrays, {**cfg, "physics": bundle.physics})
    if model.acceleration.lookahead:
        raise ConfigError(f"{path}: the bundle's step 1 reads {model.acceleration.lookahead} "
                          "samples ahead (an offline study's model) and cannot serve")
    held_out = (bundle.report or {}).get("held_out", {}).get("hybrid_rmse")
    if held_out is not None:
        model.validation_rmse = tuple(float(v) for v in held_out)
    return model, bundle


def load_step1(spec: str) -> Step1:
    """The step-1 model named by ``spec`` (see the module docstring).

    Raises:
        ConfigError: an unknown name, a file that is not a step-1 model, a damaged bundle.
    """
    from wrenchd.adapters.bundle import MANIFEST, file_sha256
    from wrenchd.models.estimator.checkpoint import load_checkpoint
    from wrenchd.models.estimator.pretrained import PRETRAINED, load_pretrained, pretrained_path

    if spec in PRETRAINED:
        return Step1(load_pretrained(spec), spec, "lstm", "simulator",
                     file_sha256(pretrained_path(spec)))
    path = Path(spec)
    if path.is_dir():
        if not (path / MANIFEST).is_file():
            raise ConfigError(f"{spec} is a directory but not a model bundle (no {MANIFEST})")
        model, bundle = load_bundle_step1(path)
        return Step1(model, spec, HYBRID_KIND, bundle.origin, bundle.digest)
    ckpt = load_checkpoint(spec)
    if ckpt.kind != "free_space":
        raise ConfigError(f"{spec}: the arm model must be a step-1 checkpoint, got {ckpt.kind}")
    origin = str(ckpt.data.get("origin", "unknown"))
    return Step1(ckpt.model, spec, "lstm", origin, file_sha256(path))


def load_free_space(spec: str):
    """The model of :func:`load_step1` alone."""
    return load_step1(spec).model
