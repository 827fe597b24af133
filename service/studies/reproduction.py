"""The paper's three tables regenerated on the simulator (Wu, Yilmaz, Kazanzides, Tumerdem).

Configurations, as in the paper:

==========  =====================================================================
Troc        the step-1 structure trained directly on trocar data (per length)
Base        step 1 trained on free motion without a seal (shipped ``base`` weights)
Seal        step 1 trained on free motion through the seal (shipped ``seal`` weights)
Base+Corr   Base + a correction net trained on trocar data (per length)
Seal+Corr   Seal + a correction net trained on trocar data (per length)
Seal+Xfer   Seal's LSTMs frozen + new layers trained on trocar data (per length)
==========  =====================================================================

Data: the trocar training set of length ``L`` is ``L / segment_s`` simulated ``trocar``
sessions of ``segment_s`` seconds (seeds ``seed + k``; the sets are nested, a longer set
holds the shorter ones). Tests: ``no_contact_trials`` fresh ``trocar`` sessions, and
``contact_trials`` fresh ``trocar-contact`` sessions, all with seeds no training set uses.
RMSEs compare the estimated tip wrench with the simulator's true tip wrench (zero without
contact) over every sample of a trial, per axis, averaged over trials.

Oracle floor: the estimate made with the simulator's own noise-free internal torque
(``truth.internal_torque``), so that what is left is the effort noise mapped through the
damped ``J^-T``. Every RMSE is also given as a ratio to this floor.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.correction import Corr, Xfer
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.correction_training import fit_corr, fit_xfer, predict_segments
from wrenchd.models.estimator.free_space_training import fit_free_space
from wrenchd.models.estimator.training import recipe
from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.models.series import Session

CONFIGS = ("Troc", "Base", "Seal", "Base+Corr", "Seal+Corr", "Seal+Xfer")
TRAINED = ("Troc", "Base+Corr", "Seal+Corr", "Seal+Xfer")
AXES = ("Fx", "Fy", "Fz", "tau_x", "tau_y", "tau_z")


class ReproductionConfig(BaseModel):
    """Sizes of the reproduction: lengths, trials, shortened recipes."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lengths_s: tuple[float, ...] = Field(default=(229.0, 474.0, 874.0, 1013.0),
                                         description="trocar training lengths [s] (the paper's)")
    segment_s: float = Field(default=30.0, gt=0, description="length of one training session [s]")
    no_contact_trials: int = Field(default=8, ge=1, description="no-contact test sessions")
    no_contact_trial_s: float = Field(default=30.0, gt=0, description="their length [s]")
    contact_trials: int = Field(default=3, ge=1, description="contact test sessions")
    contact_trial_s: float = Field(default=45.0, gt=0, description="their length [s]")
    recurrent_overrides: dict[str, Any] = Field(
        default={"epochs": 6, "lr": 3e-3, "lr_halving_epochs": 2, "window": 50,
                 "lane_windows": 4, "batch_size": 16, "patience": None},
        description="recipe fields replaced for Troc and Xfer (shortened)")
    corr_recipe: str = Field(default="corr-fast", description="Corr recipe of the tables")
    corr_overrides: dict[str, Any] = Field(default={}, description="its fields replaced")
    paper_corr_overrides: dict[str, Any] = Field(
        default={}, description="fields of the paper's Corr recipe replaced (side by side run)")
    seed: int = Field(default=1000, description="first seed of the training sessions")
    test_seed: int = Field(default=50000, description="first seed of the test sessions")


QUICK = ReproductionConfig(
    lengths_s=(20.0, 40.0), segment_s=10.0, no_contact_trials=2, no_contact_trial_s=10.0,
    contact_trials=1, contact_trial_s=20.0,
    recurrent_overrides={"epochs": 1, "window": 20, "lane_windows": 2, "batch_size": 8,
                         "patience": None},
    corr_overrides={"epochs": 3}, paper_corr_overrides={"epochs": 3})


def training_set(config: ReproductionConfig, length_s: float) -> list:
    """Joint states of the nested trocar training set of ``length_s`` seconds."""
    n = math.ceil(length_s / config.segment_s - 1e-9)
    out = []
    for k in range(n):
        duration = min(config.segment_s, length_s - k * config.segment_s)
        out.append(run_scenario("trocar", duration, config.seed + k).joint_states)
    return out


def test_sets(config: ReproductionConfig) -> tuple[list[Session], list[Session]]:
    """(no-contact trials, contact trials), seeds disjoint from every training set."""
    s0 = config.test_seed
    free = [run_scenario("trocar", config.no_contact_trial_s, s0 + k)
            for k in range(config.no_contact_trials)]
    contact = [run_scenario("trocar-contact", config.contact_trial_s, s0 + 1000 + k)
               for k in range(config.contact_trials)]
    return free, contact


# -- predicted torques of each configuration ----------------------------------------------
def _features(sessions: list[Session]) -> list[np.ndarray]:
    return [np.concatenate([s.joint_states.position, s.joint_states.velocity], 1)
            for s in sessions]


def predicted_torques(step1: FreeSpaceModel, step2: Corr | Xfer | None,
                      sessions: list[Session]) -> list[np.ndarray]:
    """(T, 6) predicted internal torques of each session (every session starts fresh)."""
    xs = _features(sessions)
    if isinstance(step2, Xfer):
        return predict_segments(step2, xs)
    tau1 = predict_segments(step1, xs)
    if isinstance(step2, Corr):
        return [step2.correct_sequence(x, t) for x, t in zip(xs, tau1)]
    return tau1


def wrench_rmse(predicted: list[np.ndarray], sessions: list[Session], wrench_map: WrenchMap
                ) -> np.ndarray:
    """(trials, 6) RMSE of the estimated tip wrench against the true one [N, N m]."""
    out = []
    for tau, s in zip(predicted, sessions):
        js = s.joint_states
        w = wrench_map.wrench_batch(js.position, js.effort - tau)
        out.append(np.sqrt(np.mean((w - s.truth.external_wrench) ** 2, axis=0)))
    return np.array(out)


def oracle_torques(sessions: list[Session]) -> list[np.ndarray]:
    """The simulator's noise-free internal torque: the best any predictor can do."""
    return [s.truth.internal_torque for s in sessions]


def _summary(rmse: np.ndarray, oracle: np.ndarray) -> dict[str, Any]:
    mean = rmse.mean(0)
    force = rmse[:, :3].mean(1)                    # mean force RMSE per trial [N]
    return {"rmse": mean.tolist(), "ratio": (mean / oracle.mean(0)).tolist(),
            "force_rmse": float(force.mean()), "force_rmse_std": float(force.std()),
            "force_ratio": float(force.mean() / oracle[:, :3].mean())}


# -- the run --------------------------------------------------------------------------------
def run_reproduction(config: ReproductionConfig, base: FreeSpaceModel, seal: FreeSpaceModel,
                     pretrained_info: dict[str, Any] | None = None,
                     log: Callable[[str], None] = print) -> dict[str, Any]:
    """Train the per-length configurations, evaluate all six, return the results dict."""
    wmap = WrenchMap()
    free, contact = test_sets(config)
    oracle_free = wrench_rmse(oracle_torques(free), free, wmap)
    oracle_contact = wrench_rmse(oracle_torques(contact), contact, wmap)
    rec_troc = recipe("troc", **config.recurrent_overrides)
    rec_xfer = recipe("xfer", **config.recurrent_overrides)
    rec_corr = recipe(config.corr_recipe, **config.corr_overrides)
    results: dict[str, Any] = {
        "config": config.model_dump(mode="json"), "axes": list(AXES),
        "recipes": {"troc": rec_troc.model_dump(), "xfer": rec_xfer.model_dump(),
                    "corr": rec_corr.model_dump()},
        "pretrained": pretrained_info or {}, "torch_threads": torch.get_num_threads(),
        "oracle": {"no_contact": _summary(oracle_free, oracle_free),
                   "contact": _summary(oracle_contact, oracle_contact)},
        "train_seconds": {c: {} for c in TRAINED}, "contact": {c: {} for c in CONFIGS},
        "no_contact": {}, "validation": {c: {} for c in TRAINED},
    }
    for name, model in (("Base", base), ("Seal", seal)):
        tf, tc = predicted_torques(model, None, free), predicted_torques(model, None, contact)
        results["no_contact"][name] = _summary(wrench_rmse(tf, free, wmap), oracle_free)
        summary = _summary(wrench_rmse(tc, contact, wmap), oracle_contact)
        for length in config.lengths_s:
            results["contact"][name][str(length)] = summary
    for length in config.lengths_s:
        data = training_set(config, length)
        key = str(length)
        trained: dict[str, tuple[FreeSpaceModel, Corr | Xfer | None]] = {}
        for name in TRAINED:
            start = time.perf_counter()
            if name == "Troc":
                res = fit_free_space(data, config=rec_troc)
                trained[name] = (res.model, None)
            elif name == "Seal+Xfer":
                res = fit_xfer(seal, data, config=rec_xfer)
                trained[name] = (seal, res.model)
            else:
                step1 = base if name == "Base+Corr" else seal
                res = fit_corr(step1, data, config=rec_corr)
                trained[name] = (step1, res.model)
            seconds = time.perf_counter() - start
            results["train_seconds"][name][key] = round(seconds, 2)
            results["validation"][name][key] = {"score": res.validation["score"],
                                                "epochs_run": res.validation["epochs_run"]}
            step1, step2 = trained[name]
            tc = predicted_torques(step1, step2, contact)
            results["contact"][name][key] = _summary(wrench_rmse(tc, contact, wmap),
                                                     oracle_contact)
            log(f"L={length:g} s {name}: trained in {seconds:.1f} s, contact force RMSE "
                f"{results['contact'][name][key]['force_rmse']:.3f} N")
        if length == config.lengths_s[-1]:            # no-contact table: the longest set
            for name, (step1, step2) in trained.items():
                tf = predicted_torques(step1, step2, free)
                results["no_contact"][name] = _summary(wrench_rmse(tf, free, wmap), oracle_free)
        if length == config.lengths_s[0]:
            results["fast_vs_paper"] = fast_vs_paper(config, base, data, contact, wmap,
                                                     oracle_contact, log)
    return results


def fast_vs_paper(config: ReproductionConfig, base: FreeSpaceModel, data: list,
                  contact: list[Session], wmap: WrenchMap, oracle_contact: np.ndarray,
                  log: Callable[[str], None]) -> dict[str, Any]:
    """Base+Corr trained with the paper's recipe and the fast one on the same data."""
    out = {"length_s": float(sum(js.t[-1] - js.t[0] + 1.0 / js.rate_hz for js in data)),
           "threads": torch.get_num_threads()}
    for label, name, overrides in (("paper", "corr", config.paper_corr_overrides),
                                   ("fast", config.corr_recipe, config.corr_overrides)):
        rec = recipe(name, **overrides)
        start, cpu = time.perf_counter(), time.process_time()
        res = fit_corr(base, data, config=rec)
        seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
        tc = predicted_torques(base, res.model, contact)
        out[label] = {"recipe": name, "overrides": overrides, "train_seconds": round(seconds, 2),
                      "cpu_seconds": round(cpu, 2),
                      "epochs_run": res.validation["epochs_run"],
                      **_summary(wrench_rmse(tc, contact, wmap), oracle_contact)}
        log(f"Corr recipe {name}: {seconds:.2f} s ({cpu:.2f} s CPU), contact force RMSE "
            f"{out[label]['force_rmse']:.3f} N")
    return out
