"""Training of the reproduction's networks, one training seed at a time.

Base and Seal on free motion (:func:`train_step1`, when the run trains step 1), the four
per-length configurations on the trocar set of one length (:func:`train_length`), and the
fast Corr recipe beside the paper's on the same data (:func:`fast_vs_paper`). Troc and Xfer
early-stop on held-out trocar sessions when the run has them, else on the tail of each
training series; Corr trains on the CPU.
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Callable

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict

from wrenchd.models.estimator.checkpoint import (
    load_checkpoint,
    load_training_state,
    save_result,
    save_training_state,
)
from wrenchd.models.estimator.correction import Corr, CorrConfig, Xfer
from wrenchd.models.estimator.correction_training import fit_corr, fit_xfer
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.free_space_training import fit_free_space
from wrenchd.models.estimator.training import TrainConfig, recipe
from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.models.series import JointStates, Session
from wrenchd.service.runtime import stopping
from wrenchd.service.studies.reproduction_cells import fingerprint
from wrenchd.service.studies.reproduction_config import TRAINED, ReproductionConfig
from wrenchd.service.studies.reproduction_results import FastVsPaper, Fit, RecipeRun, Step1Fit
from wrenchd.service.studies.reproduction_scoring import predicted_torques, wrench_rmse
from wrenchd.service.studies.reproduction_summary import summary
from wrenchd.service.studies.training import fit_step1_held_out, fit_xfer_held_out


def seeded_recipe(name: str, overrides: dict[str, Any], seed: int) -> TrainConfig:
    """The named recipe with ``overrides`` and the training seed put in."""
    return recipe(name, **{**overrides, "seed": seed})


class Step1Fits(BaseModel):
    """Base and Seal trained with one training seed, and how each fit went."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    models: dict[str, FreeSpaceModel]
    fits: dict[str, Step1Fit]


def stop_between_epochs(_epoch: int, _score: float) -> None:
    """After each saved epoch: end the training if the command was asked to stop (SIGINT,
    SIGTERM); the checkpoint goes on from the next epoch."""
    stopping.check()


def _checkpoint(folder: Path | None, name: str) -> Path | None:
    """``folder / name`` (the folder made), or None without a folder."""
    if folder is None:
        return None
    folder.mkdir(parents=True, exist_ok=True)
    return folder / name


def train_step1(config: ReproductionConfig, seed: int,
                sets: dict[str, tuple[list[Session], list[Session]]], device: str | None,
                log: Callable[[str], None], checkpoints: Path | None = None,
                weights: Path | None = None,
                finished: Callable[[str, int], list[Path]] | None = None) -> Step1Fits:
    """Base and Seal trained with training seed ``seed`` on their free-motion sets,
    early-stopped on the held-out sessions (resumed from ``checkpoints`` when given).

    ``weights``: a folder to write each trained model to as an estimator checkpoint
    (``{name}-seed{seed}.pt``, its best weights per joint group with the held-out scores and
    whether early stopping ended it), loadable wherever a step-1 checkpoint is.
    ``finished(name, seed)``: estimator checkpoints that may hold this very training, finished
    (a former sitting's ``weights``, the shipped copies): the first one trained on this recipe
    (its seed included) and on as many series and samples is used, not trained again."""
    st = config.step1
    models, fits = {}, {}
    for name, (train, held) in sets.items():
        rec = seeded_recipe(st.recipe, st.overrides, seed)
        found = _finished_step1(finished(name, seed) if finished else [], rec, train, held,
                                fingerprint(config))
        if found is not None:
            path, ck = found
            models[name] = ck.model
            v = ck.validation
            fits[name] = Step1Fit(train_seconds=float(v.get("train_seconds", math.nan)),
                                  score=v["score"], epochs_run=v["epochs_run"])
            log(f"seed {seed} {name}: finished training read from {path} "
                f"({v['epochs_run']} epochs, held-out score {v['score']:.4f}), not trained again")
            target = weights / f"{name}-seed{seed}.pt" if weights is not None else None
            if target is not None and not (target.exists() and target.samefile(path)):
                weights.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(path, target)
            continue
        start = time.perf_counter()
        res = fit_step1_held_out([s.joint_states for s in train],
                                 [s.joint_states for s in held], rec, device=device,
                                 on_epoch=stop_between_epochs,
                                 checkpoint=_checkpoint(checkpoints, f"{name}-seed{seed}.pt"))
        seconds = _trained_seconds(res.validation, time.perf_counter() - start)
        models[name] = res.model
        fits[name] = Step1Fit(train_seconds=round(seconds, 2), score=res.validation["score"],
                              epochs_run=res.validation["epochs_run"])
        log(f"seed {seed} {name}: {res.validation['epochs_run']} epochs in {seconds:.1f} s, "
            f"held-out score {res.validation['score']:.4f}")
        if weights is not None:
            weights.mkdir(parents=True, exist_ok=True)
            # the run's configuration with the weights: a later sitting of another one
            # (another patient draw, the same sizes) does not take them for its own
            res.data = {**(res.data or {}), "reproduction": fingerprint(config)}
            save_result(weights / f"{name}-seed{seed}.pt", res)
            log(f"seed {seed} {name}: weights in {weights / f'{name}-seed{seed}.pt'} "
                f"({'converged' if res.validation.get('converged') else 'not converged'})")
    return Step1Fits(models=models, fits=fits)


def _finished_step1(paths: list[Path], rec: TrainConfig, train: list[Session],
                    held: list[Session], run: str) -> tuple[Path, Any] | None:
    """The first of ``paths`` that holds a step-1 model trained on recipe ``rec`` with as
    many training series, samples and held-out series as ``train`` and ``held``, and, where
    it names the configuration of the run that trained it, by a run of this one (``run``,
    its :func:`~wrenchd.service.studies.reproduction_cells.fingerprint`), loaded."""
    size = {"n_series": len(train), "n_samples": sum(len(s.joint_states) for s in train),
            "held_out_series": len(held)}
    for path in paths:
        if not Path(path).is_file():
            continue
        ck = load_checkpoint(path)
        data = ck.data or {}
        if (ck.kind == "free_space" and ck.train_config == rec
                and all(data.get(k) == v for k, v in size.items())
                and data.get("reproduction", run) == run
                and {"score", "epochs_run"} <= set(ck.validation or {})):
            return Path(path), ck
    return None


def _digest(model: torch.nn.Module) -> str:
    """SHA-256 of a model's weights (names, shapes and bytes of its state)."""
    h = hashlib.sha256()
    for key, value in model.state_dict().items():
        t = value.detach().cpu().contiguous()
        h.update(f"{key}{tuple(t.shape)}{t.dtype}".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def _fit_corr_once(step1: FreeSpaceModel, data: list[JointStates], rec: TrainConfig,
                   path: Path | None):
    """``fit_corr``, or the Corr a former sitting trained on the same recipe, data and step-1
    weights, read from ``path`` (written when it trains here). Corr keeps no per-epoch
    checkpoint (it trains in minutes), but a restarted run would otherwise train every
    length's again; training is seeded, so the file holds the very weights a retraining
    would give. Returns what ``train_length`` reads: ``model`` and ``validation``.

    Raises:
        DataError: ``path`` holds another run's Corr.
    """
    if path is None:
        return fit_corr(step1, data, config=rec)
    fingerprint = {"format": 1, "recipe": rec.model_dump(mode="json"), "step1": _digest(step1),
                   "data": [[len(js.t), float(np.sum(js.position)), float(np.sum(js.effort))]
                            for js in data]}
    saved = load_training_state(path, fingerprint)
    if saved is not None:
        with torch.random.fork_rng(devices=[]):     # its initial weights draw: not the run's
            corr = Corr(CorrConfig(**saved["config"])).to(saved["state"]["in_mean"].dtype)
        corr.load_state_dict(saved["state"])
        return SimpleNamespace(model=corr.eval(), validation=saved["validation"])
    start = time.perf_counter()
    res = fit_corr(step1, data, config=rec)
    validation = json.loads(json.dumps({**res.validation,
                                        "train_seconds": time.perf_counter() - start},
                                       default=float))
    save_training_state(path, {"fingerprint": fingerprint, "state": res.model.state_dict(),
                               "config": res.model.config.model_dump(mode="json"),
                               "validation": validation})
    res.validation["train_seconds"] = validation["train_seconds"]    # as a later sitting reads
    return res


def _trained_seconds(validation: dict, wall: float) -> float:
    """A training's time [s]: a checkpointed network's epochs over every sitting (not the
    seconds a resumed one took to be rebuilt; NaN when a checkpoint too old to say was
    kept), else the wall time it took here."""
    if "train_seconds" not in validation:
        return wall
    kept = validation["train_seconds"]
    return float("nan") if kept is None else float(kept)


class Trained(BaseModel):
    """One trained configuration: its step-1 model, its step 2, the time and the fit."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    step1: FreeSpaceModel
    step2: Corr | Xfer | None
    seconds: float
    fit: Fit


class LengthTraining(BaseModel):
    """The per-length configurations (:data:`TRAINED`) trained with one seed on one set."""

    model_config = ConfigDict(frozen=True)

    seed: int
    length_s: float
    configs: dict[str, Trained]


def train_length(config: ReproductionConfig, seed: int, length_s: float,
                 data: list[JointStates], held: list[JointStates], base: FreeSpaceModel,
                 seal: FreeSpaceModel, device: str | None,
                 checkpoints: Path | None = None) -> LengthTraining:
    """Troc, Base+Corr, Seal+Corr and Seal+Xfer trained on ``data`` (the trocar set of
    ``length_s``) with training seed ``seed``; Troc and Xfer early-stop on ``held`` when
    given, and then resume from ``checkpoints`` when given."""
    rec_troc = seeded_recipe(config.troc_recipe, config.recurrent_overrides, seed)
    rec_xfer = seeded_recipe(config.xfer_recipe, config.recurrent_overrides, seed)
    rec_corr = seeded_recipe(config.corr_recipe, config.corr_overrides, seed)
    out: dict[str, Trained] = {}
    for name in TRAINED:
        start = time.perf_counter()
        step2: Corr | Xfer | None = None
        if name == "Troc":
            res = (fit_step1_held_out(data, held, rec_troc, device=device,
                                      on_epoch=stop_between_epochs, checkpoint=_checkpoint(
                                          checkpoints, f"Troc-{length_s:g}s-seed{seed}.pt"))
                   if held else fit_free_space(data, config=rec_troc, device=device))
            step1 = res.model
        elif name == "Seal+Xfer":
            res = (fit_xfer_held_out(seal, data, held, rec_xfer, device=device,
                                     on_epoch=stop_between_epochs, checkpoint=_checkpoint(
                                         checkpoints, f"Xfer-{length_s:g}s-seed{seed}.pt"))
                   if held else fit_xfer(seal, data, config=rec_xfer, device=device))
            step1, step2 = seal, res.model
        else:
            step1 = base if name == "Base+Corr" else seal
            res = _fit_corr_once(step1, data, rec_corr, _checkpoint(
                checkpoints, f"{name}-{length_s:g}s-seed{seed}.pt"))
            step2 = res.model
        out[name] = Trained(step1=step1, step2=step2,
                            seconds=_trained_seconds(res.validation,
                                                     time.perf_counter() - start),
                            fit=Fit(score=res.validation["score"],
                                    epochs_run=res.validation["epochs_run"]))
    return LengthTraining(seed=seed, length_s=length_s, configs=out)


def fast_vs_paper(config: ReproductionConfig, base: FreeSpaceModel, data: list[JointStates],
                  contact: list[Session], wmap: WrenchMap, oracle_contact: np.ndarray,
                  log: Callable[[str], None]) -> FastVsPaper:
    """Base+Corr trained with the paper's recipe and the fast one on the same data."""
    runs = {}
    for label, name, overrides in (("paper", "corr", config.paper_corr_overrides),
                                   ("fast", config.corr_recipe, config.corr_overrides)):
        rec = recipe(name, **overrides)
        start, cpu = time.perf_counter(), time.process_time()
        res = fit_corr(base, data, config=rec)
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        tc = predicted_torques(base, res.model, contact)
        runs[label] = RecipeRun(recipe=name, overrides=overrides,
                                train_seconds=round(seconds, 2), cpu_seconds=round(cpu, 2),
                                epochs_run=res.validation["epochs_run"],
                                **summary(wrench_rmse(tc, contact, wmap),
                                          oracle_contact).model_dump())
        log(f"Corr recipe {name}: {seconds:.2f} s ({cpu:.2f} s CPU), contact force RMSE "
            f"{runs[label].force_rmse:.3f} N")
    return FastVsPaper(length_s=float(sum(js.t[-1] - js.t[0] + 1.0 / js.rate_hz for js in data)),
                       threads=torch.get_num_threads(), **runs)
