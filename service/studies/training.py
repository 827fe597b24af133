"""Training one network of the two-step estimator from a config file (``wrenchd train``).

The config (TOML or JSON) is a :class:`TrainCommandConfig`; its format, with an example, is
in :mod:`wrenchd.service.cli.train`. Relative paths (data, output, base checkpoint) are taken
from the working directory. The checkpoint carries the config, the format version, a
description of the data, the validation score (the last ``val_fraction`` of every series, see
:mod:`wrenchd.models.estimator.training`) and the provenance of the run
(:mod:`wrenchd.service.provenance`).

Early stopping on held-out sessions: with a ``validation`` list, the step-1 networks (``base``,
``troc``) and ``xfer`` train on every sample of ``data`` and score each epoch on the
``validation`` sessions instead (:func:`fit_step1_held_out`, :func:`fit_xfer_held_out`); the
recipe's ``epochs`` is the ceiling, its ``patience`` the early stop, and the weights of each
joint group's best validation epoch are kept.
"""

from __future__ import annotations

import json
import os
import time
import tomllib
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from wrenchd.models.errors import ConfigError
from wrenchd.service.provenance import PROVENANCE_KEY, RunMeter, provenance

#: Default recipe of each configuration.
DEFAULT_RECIPES = {"base": "free-space", "troc": "troc", "corr": "corr", "xfer": "xfer"}


class SimulatedData(BaseModel):
    """A simulator scenario run as training data."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    scenario: str = Field(description="scenario name (see `wrenchd simulate --help`)")
    duration_s: float = Field(gt=0.0, description="simulated length [s]")
    seed: int = Field(default=0, description="seed of the simulated session")
    patient_variation: bool = Field(
        default=False, description="draw this session's patient (seal, body wall, incision, "
                                   "pressure) from the default ranges; false: the fixed patient")


class FileData(BaseModel):
    """A recorded session: MCAP, or CSV in the WPI or the paper's layout."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    path: str = Field(description="an .mcap or .csv file")
    rate_hz: float | None = Field(default=None, gt=0.0, description="sample rate of a WPI CSV "
                                  "[Hz]; None: inferred from its velocity columns")


class TrainCommandConfig(BaseModel):
    """What ``wrenchd train`` trains, on what, and where it writes the checkpoint."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    configuration: Literal["base", "troc", "corr", "xfer"] = Field(
        description="base/troc: step-1 networks; corr/xfer: step 2 on a base checkpoint")
    data: list[SimulatedData | FileData] = Field(min_length=1, description="training series")
    validation: list[SimulatedData | FileData] = Field(
        default_factory=list, description="held-out sessions for early stopping (base, troc, "
                                          "xfer); empty: the last val_fraction of every series")
    recipe: str | None = Field(default=None, description="recipe name; default per configuration")
    overrides: dict[str, Any] = Field(default_factory=dict,
                                      description="recipe fields replaced (e.g. epochs)")
    seed: int = Field(default=0, description="seed of the training (overrides the recipe's)")
    base_checkpoint: str | None = Field(
        default=None, description="corr/xfer: step-1 checkpoint path or pretrained:<name>")
    output: str = Field(description="checkpoint file to write (.pt)")
    description: str = Field(default="", description="free text stored with the checkpoint")

    @model_validator(mode="after")
    def _base_for_step2(self):
        if self.configuration in ("corr", "xfer") and not self.base_checkpoint:
            raise ValueError(f"configuration {self.configuration!r} needs base_checkpoint")
        if self.configuration in ("base", "troc") and self.base_checkpoint:
            raise ValueError(f"configuration {self.configuration!r} takes no base_checkpoint")
        if self.configuration == "corr" and self.validation:
            raise ValueError("configuration 'corr' validates on the tail of its series; "
                             "held-out validation sessions are for base, troc and xfer")
        return self

    @property
    def recipe_name(self) -> str:
        return self.recipe or DEFAULT_RECIPES[self.configuration]


def read_train_config(path: str | os.PathLike) -> TrainCommandConfig:
    """Parse a TOML (``.toml``) or JSON config file.

    Raises:
        ConfigError: unreadable, not TOML/JSON, or invalid (the message names the field).
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ConfigError(f"{p}: cannot read the training config: {exc}") from exc
    try:
        raw = tomllib.loads(text) if p.suffix.lower() == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{p}: not valid {'TOML' if p.suffix == '.toml' else 'JSON'}: "
                          f"{exc}") from exc
    try:
        return TrainCommandConfig(**raw)
    except (ValidationError, TypeError) as exc:
        raise ConfigError(f"{p}: invalid training config: {exc}") from exc


def load_series(spec: SimulatedData | FileData):
    """The joint states of one data entry, and its description for the checkpoint."""
    if isinstance(spec, SimulatedData):
        from wrenchd.adapters.sim.scenarios import run_scenario

        from wrenchd.adapters.sim.patients import PatientRanges

        session = run_scenario(spec.scenario, spec.duration_s, spec.seed,
                               patients=PatientRanges() if spec.patient_variation else None)
        info = {"source": "simulator", **spec.model_dump(exclude={"patient_variation"})}
        if spec.patient_variation:                     # the fixed patient's record as it was
            info.update(patient_variation=True, patient=session.metadata["patient"]["draw"])
        return session.joint_states, info
    path = Path(spec.path)
    if path.suffix.lower() == ".mcap":
        from wrenchd.adapters.mcap_session_reader import read_session

        return read_session(path).joint_states, {"source": "mcap", "path": spec.path}
    if path.suffix.lower() == ".csv":
        from wrenchd.adapters.csv_psm import read_psm_csv

        return (read_psm_csv(path, rate_hz=spec.rate_hz),
                {"source": "csv", "path": spec.path, "rate_hz": spec.rate_hz})
    raise ConfigError(f"{spec.path}: data files must be .mcap or .csv")


def whole_segments(series, max_gap_s: float) -> list[tuple[Any, Any]]:
    """Every gap-free segment of ``series`` as (features (T, 12), measured torques (T, 6))."""
    import numpy as np

    from wrenchd.models.estimator.features import segments

    out = []
    for s in series:
        x = np.concatenate([s.position, s.velocity], axis=1)
        for seg in segments(s.t, max_gap_s):
            if seg.stop - seg.start >= 2:
                out.append((x[seg], s.effort[seg]))
    return out


def _held_out(series, validation, config):
    from wrenchd.models.errors import DataError

    train = whole_segments(series, config.max_gap_s)
    val = whole_segments(validation, config.max_gap_s)
    if not train or not val:
        raise DataError("need training and held-out validation samples")
    return train, val


def fit_step1_held_out(series, validation, config, model_config=None,
                       data: dict[str, Any] | None = None, on_epoch=None, device="cpu",
                       checkpoint=None):
    """A step-1 network (``Base``, ``Seal`` or ``Troc``) trained on every sample of
    ``series`` and early-stopped on the held-out ``validation`` sessions.

    Args:
        series, validation: JointStates of free motion (no contact).
        config: the recipe (``epochs``: the ceiling; ``patience``: the early stop).
        checkpoint: a file to save the training to after every epoch and resume it from
            (:func:`~wrenchd.models.estimator.free_space_training.train_recurrent`).
    Returns:
        a ``TrainResult`` of kind ``free_space``; its validation scores the held-out sessions.
    """
    import numpy as np
    import torch

    from wrenchd.models.estimator.free_space import FreeSpaceModel
    from wrenchd.models.estimator.free_space_training import train_recurrent
    from wrenchd.models.estimator.training import TrainResult, describe_data

    train, val = _held_out(series, validation, config)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = FreeSpaceModel(model_config)
        model.set_input_normalisation(np.concatenate([x for x, _ in train]))
        model.set_output_normalisation(np.concatenate([y for _, y in train]))
        report, history = train_recurrent(model, train, val, config, on_epoch, device,
                                          checkpoint)
    described = {**describe_data(series, data, config), "val_fraction": None,
                 "held_out_series": len(validation)}
    return TrainResult("free_space", model, config, described, report, history)


def fit_xfer_held_out(base, series, validation, config, xfer_config=None,
                      data: dict[str, Any] | None = None, on_epoch=None, device="cpu",
                      checkpoint=None):
    """``Xfer``'s new layers on the frozen ``base`` trained on every sample of ``series``,
    early-stopped on the held-out ``validation`` sessions (trocar motion, no contact);
    ``checkpoint`` as in :func:`fit_step1_held_out`."""
    import numpy as np
    import torch

    from wrenchd.models.estimator.correction import Xfer
    from wrenchd.models.estimator.free_space_training import train_recurrent
    from wrenchd.models.estimator.training import TrainResult, describe_data

    train, val = _held_out(series, validation, config)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = Xfer(xfer_config, base=base)
        model.set_output_normalisation(np.concatenate([y for _, y in train]))
        report, history = train_recurrent(model, train, val, config, on_epoch, device,
                                          checkpoint)
    described = {**describe_data(series, data, config), "val_fraction": None,
                 "held_out_series": len(validation)}
    return TrainResult("xfer", model, config, described, report, history)


def load_base(reference: str):
    """A step-1 model from a checkpoint path or ``pretrained:<name>``."""
    from wrenchd.models.estimator.checkpoint import load_checkpoint
    from wrenchd.models.estimator.pretrained import load_pretrained

    if reference.startswith("pretrained:"):
        return load_pretrained(reference.removeprefix("pretrained:"))
    ckpt = load_checkpoint(reference)
    if ckpt.kind != "free_space":
        raise ConfigError(f"{reference}: base checkpoint must be a step-1 (free_space) model, "
                          f"got {ckpt.kind}")
    return ckpt.model


def train(config: TrainCommandConfig, output: str | None = None, device: str | None = None,
          progress: bool = True) -> dict[str, Any]:
    """Train as ``config`` says and write the checkpoint (its data carries the provenance of
    the run). Returns a summary."""
    meter = RunMeter()
    import torch
    from tqdm import tqdm

    from wrenchd.models.estimator.checkpoint import save_result
    from wrenchd.models.estimator.correction_training import fit_corr, fit_xfer
    from wrenchd.models.estimator.free_space_training import fit_free_space
    from wrenchd.models.estimator.training import recipe, training_device

    train_config = recipe(config.recipe_name, **{**config.overrides, "seed": config.seed})
    dev = training_device(device)
    series, described = [], []
    for spec in tqdm(config.data, desc="data", unit="series", disable=not progress):
        js, info = load_series(spec)
        series.append(js)
        described.append(info)
    held_out, held_described = [], []
    for spec in config.validation:
        js, info = load_series(spec)
        held_out.append(js)
        held_described.append(info)
    data = {"configuration": config.configuration, "recipe": config.recipe_name,
            "series": described, "description": config.description,
            "validation_series": held_described,
            "base_checkpoint": config.base_checkpoint, "device": str(dev)}
    bar = tqdm(total=train_config.epochs, desc=f"train {config.configuration}", unit="epoch",
               disable=not progress)

    def on_epoch(epoch: int, score: float) -> None:
        bar.update(1)
        bar.set_postfix(val=f"{score:.4f}")

    start = time.perf_counter()
    try:
        if config.configuration in ("base", "troc") and held_out:
            result = fit_step1_held_out(series, held_out, train_config, data=data,
                                        on_epoch=on_epoch, device=dev)
        elif config.configuration in ("base", "troc"):
            result = fit_free_space(series, config=train_config, data=data, on_epoch=on_epoch,
                                    device=dev)
        elif config.configuration == "xfer" and held_out:
            result = fit_xfer_held_out(load_base(config.base_checkpoint), series, held_out,
                                       train_config, data=data, on_epoch=on_epoch, device=dev)
        elif config.configuration == "xfer":
            result = fit_xfer(load_base(config.base_checkpoint), series, config=train_config,
                              data=data, on_epoch=on_epoch, device=dev)
        else:
            result = fit_corr(load_base(config.base_checkpoint), series, config=train_config,
                              data=data, on_epoch=on_epoch)
    finally:
        bar.close()
    seconds = time.perf_counter() - start
    result.data["train_seconds"] = round(seconds, 2)
    result.data["torch"] = torch.__version__
    result.data[PROVENANCE_KEY] = provenance(run=meter)
    out = Path(output or config.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_result(out, result)
    return {"output": str(out), "kind": result.kind, "train_seconds": round(seconds, 2),
            "epochs_run": result.validation.get("epochs_run"),
            "validation_score": result.validation.get("score"),
            "validation_rmse": result.validation.get("rmse")}
