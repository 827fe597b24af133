"""What the paper-scale run's gap to the oracle floor is made of: the patient.

The paper-scale run (:mod:`wrenchd.service.studies.reproduction`) trains every step 2 on the
trocar data of some patients and scores it on the contact trials of others, unseen. Its best
configuration stays several times above the raw oracle floor. This study asks how much of
that is the patient: for each contact trial it simulates fresh free motion of **that trial's
patient** (the same seal, body wall, incision and pressure, other motion: no sample of the
trial itself) and scores, on the trial,

* ``own Corr (L s)``: a correction net trained from scratch on ``L`` seconds of the
  patient's free motion, with the run's Corr recipe, on the run's Seal (the paper's own
  protocol: step 2 trained on the set-up it serves);
* ``wrenchd online (L s)``: the daemon's pipeline, gated, adapting from a zero correction on
  the same ``L`` seconds and then on the trial's free motion as it goes (replay in simulated
  time, :func:`wrenchd.service.replay.loop.replay`): what the served, causal estimate does.
  Its step 2 holds the body wall as physics (:mod:`wrenchd.models.estimator.trocar_physics`),
  whose form is the simulator's own body wall: on the simulator that part fits exactly, so
  ``wrenchd online, net only`` replays it without (``adaptation.trocar_physics`` off);

beside the run's own figures for the trials (``Seal`` alone, and the configurations trained
on other patients, read from the run's cells for one training seed) and the raw oracle floor.
Every figure is the report's: the force RMSE (the mean over Fx, Fy, Fz of each axis's RMSE
against the true tip force, every sample of a trial, through the run's causal output filter),
with a 95 % percentile-bootstrap interval over trials.

The same question for step 1 in its own domain (:func:`step1_by_patient`): Base and Seal on
the run's in-domain trials (unseen patients), on the same motion with the patients they were
trained on, and with the fixed default patient, before the filter, against the raw floor
(the report's in-domain target).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.adapters.sim.scenarios import run_scenario, session_patient
from wrenchd.models.estimator.correction_training import fit_corr
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.models.recorded import Part, concatenate
from wrenchd.models.series import Session
from wrenchd.service.studies.reproduction_cells import load_cell
from wrenchd.service.studies.reproduction_config import ReproductionConfig
from wrenchd.service.studies.reproduction_scoring import (Scorer, lowpass, mean_interval,
                                                           predicted_torques, trial_errors)
from wrenchd.service.studies.reproduction_sets import (contact_trial, step1_test_sets,
                                                        step1_training_seed)
from wrenchd.service.studies.reproduction_training import seeded_recipe

#: the run's configurations read from its cells, in the report's order
GENERAL = ("Troc", "Base+Corr", "Seal+Corr", "Seal+Xfer")
#: the first seed of the patients' fresh free motion (no role of the run uses it)
FREE_SEED = 700_000
#: the replayed pipelines: row name and the pipeline settings changed from the defaults
ONLINE = (("wrenchd online", {}),
          ("wrenchd online, net only", {"adaptation": {"trocar_physics": False}}))


class PatientGapConfig(BaseModel):
    """Sizes of the study; the trials, recipes and output filter are the run's."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lengths_s: tuple[float, ...] = Field(default=(30.0, 60.0, 120.0, 300.0),
                                         description="the patient's free motion [s], nested")
    trials: int | None = Field(default=None, ge=1,
                               description="the run's first contact trials (None: all)")
    seed: int = Field(default=0, ge=0, description="training seed (the own Corr's and the "
                                                   "run's cells read beside it)")
    general_length_s: float = Field(default=1013.0, gt=0,
                                    description="the run's trocar training length whose cells "
                                                "are shown beside")
    online: bool = Field(default=True, description="also replay the daemon's gated pipeline")
    step1_trials: int | None = Field(default=None, ge=0,
                                     description="the run's first in-domain step-1 trials "
                                                 "(None: all; 0: none)")
    corr_overrides: dict[str, Any] | None = Field(
        default=None, description="the Corr recipe's fields replaced (None: the run's)")


def patient_free_motion(run: ReproductionConfig, trial: Session, trial_index: int,
                        length_s: float) -> list[Session]:
    """``length_s`` seconds of new ``trocar`` free motion of ``trial``'s patient, in sessions
    of the run's ``segment_s`` (seeds of their own: a longer set holds the shorter ones)."""
    draw = trial.metadata["patient"]["draw"]
    n = int(np.ceil(length_s / run.segment_s - 1e-9))
    return [run_scenario("trocar", min(run.segment_s, length_s - k * run.segment_s),
                         FREE_SEED + 1000 * trial_index + k, patient=draw,
                         handle_nm_per_rad=run.handle_nm_per_rad) for k in range(n)]


def force_rmse(scores: dict[str, dict[str, np.ndarray]], metric: str = "rmse") -> np.ndarray:
    """(trials,) the report's force figure: the mean over Fx, Fy, Fz of the truth errors."""
    return scores["truth"][metric][:, :3].mean(axis=1)


def _online(run: ReproductionConfig, seal: FreeSpaceModel, free: list[Session],
            trial: Session, overrides: dict[str, Any]) -> tuple[float, float, int]:
    """The gated pipeline (its settings with ``overrides``) replayed over ``free`` then
    ``trial``: the trial's force RMSE and contact force RMSE (through the run's output filter)
    and the serving net's version at the trial's first sample."""
    from wrenchd.service.pipeline.config import PipelineConfig
    from wrenchd.service.replay.loop import replay
    from wrenchd.service.replay.policies import get_policy, merge_nested

    session = concatenate([Part(f"free{k}", s) for k, s in enumerate(free)]
                          + [Part("trial", trial)])
    n = len(trial.joint_states)
    base = PipelineConfig.model_validate(merge_nested(PipelineConfig().model_dump(), overrides))
    result = replay(session, seal, get_policy("gated").configure(base), policy="gated")
    rows = result.sample >= len(session.joint_states) - n      # the trial's samples
    if rows.sum() != n:
        raise RuntimeError(f"the replay estimated {rows.sum()} of the trial's {n} samples")
    w = lowpass(result.wrench[rows], trial.joint_states.rate_hz, run.output_filter_hz)
    errors = trial_errors(w, trial.truth.external_wrench, trial.truth.in_contact)
    return (float(errors["rmse"][:3].mean()), float(errors["contact_rmse"][:3].mean()),
            int(result.model_version[rows][0]))


def step1_by_patient(run: ReproductionConfig, models: dict[str, FreeSpaceModel],
                     trials: int | None = None) -> dict[str, dict[str, Any]]:
    """Each step-1 model of ``models`` (``Base``, ``Seal``) on the run's in-domain trials of
    unseen patients, on the same trials' motion with the patients of its own training
    sessions (trial k with the patient of training session k), and with the fixed default
    patient: per row the per-trial force RMSE before the filter [N], its mean with an
    interval and its ratio to the raw floor of those trials."""
    tests = step1_test_sets(run)
    out: dict[str, dict[str, Any]] = {}
    wrench_map = WrenchMap()
    for name, model in models.items():
        unseen = tests[name][:trials] if trials is not None else tests[name]
        seen, fixed = [], []
        for k, trial in enumerate(unseen):
            meta = trial.metadata["scenario"]
            draw = session_patient(step1_training_seed(run, name, k), run.patient_ranges)
            args = (meta["name"], meta["duration_s"], meta["seed"])
            kw = {"force_sensor": True, "handle_nm_per_rad": meta["handle_nm_per_rad"]}
            seen.append(run_scenario(*args, patient=draw, **kw))
            fixed.append(run_scenario(*args, **kw))
        for label, sessions in (("unseen patients", unseen),
                                ("its training patients, the same motion", seen),
                                ("the fixed default patient, the same motion", fixed)):
            scorer = Scorer(sessions, wrench_map, None)
            rmse = force_rmse(scorer.score(predicted_torques(model, None, sessions),
                                           filtered=False))
            floor = force_rmse(scorer.floors()["raw"])
            mean, lo, hi = mean_interval(rmse)
            out[f"{name}: {label}"] = {"rmse": [float(v) for v in rmse],
                                       "force_rmse": [mean, lo, hi],
                                       "raw_floor": float(floor.mean()),
                                       "ratio_raw_floor": mean / float(floor.mean())}
    return out


def run_patient_gap(run: ReproductionConfig, cells: Path, seal: FreeSpaceModel,
                    config: PatientGapConfig | None = None,
                    log: Callable[[str], None] = print,
                    base: FreeSpaceModel | None = None) -> dict[str, Any]:
    """The study (see the module docstring) on ``run``'s contact trials, its cells under
    ``cells`` and its Seal: per row, the per-trial force RMSE and contact force RMSE [N],
    their means with intervals, ratios to the raw floor, and what each own Corr trained;
    with ``base`` (the run's Base) and ``step1_trials`` not 0, also ``step1``
    (:func:`step1_by_patient` of Base and Seal)."""
    config = config if config is not None else PatientGapConfig()
    n = min(config.trials or run.contact_trials, run.contact_trials)
    trials = [contact_trial(run, k) for k in range(n)]
    wrench_map = WrenchMap()
    scorer = Scorer(trials, wrench_map, run.output_filter_hz)
    rows: dict[str, dict[str, list[float]]] = {}

    def put(name: str, rmse, contact) -> None:
        rows[name] = {"rmse": [float(v) for v in rmse], "contact_rmse": [float(v) for v in contact]}

    floor = scorer.floors()["raw"]
    put("oracle (raw)", force_rmse(floor), force_rmse(floor, "contact_rmse"))
    seal_scores = scorer.score(predicted_torques(seal, None, trials))
    put("Seal", force_rmse(seal_scores), force_rmse(seal_scores, "contact_rmse"))
    cell = load_cell(cells, run, config.seed, config.general_length_s)
    contact = cell.scores.contact if cell is not None else {}
    general = [name for name in GENERAL if name in contact]
    for name in general:
        truth = contact[name]["truth"]
        put(f"{name} (other patients)", truth["rmse"][:n, :3].mean(1),
            truth["contact_rmse"][:n, :3].mean(1))
    rec = seeded_recipe(run.corr_recipe, config.corr_overrides if config.corr_overrides
                        is not None else run.corr_overrides, config.seed)
    fits: dict[str, list[dict[str, Any]]] = {}
    for length in config.lengths_s:
        own = f"own Corr ({length:g} s)"
        rows[own] = {"rmse": [], "contact_rmse": []}
        online = [(f"{name} ({length:g} s)", overrides) for name, overrides in ONLINE
                  if config.online]
        for name, _ in online:
            rows[name] = {"rmse": [], "contact_rmse": [], "version_at_trial": []}
        fits[own] = []
        for k, trial in enumerate(trials):
            free = patient_free_motion(run, trial, k, length)
            with torch.random.fork_rng(devices=[]):
                res = fit_corr(seal, [s.joint_states for s in free], config=rec)
            s = Scorer([trial], wrench_map, run.output_filter_hz).score(
                predicted_torques(seal, res.model, [trial]))
            rows[own]["rmse"].append(float(force_rmse(s)[0]))
            rows[own]["contact_rmse"].append(float(force_rmse(s, "contact_rmse")[0]))
            fits[own].append({"epochs_run": int(res.validation["epochs_run"]),
                              "score": float(res.validation["score"])})
            line = f"trial {k} {own}: {rows[own]['rmse'][-1]:.3f} N"
            for name, overrides in online:
                r, c, version = _online(run, seal, free, trial, overrides)
                rows[name]["rmse"].append(r)
                rows[name]["contact_rmse"].append(c)
                rows[name]["version_at_trial"].append(version)
                line += f", {name} {r:.3f} N (v{version} at the trial)"
            log(line)
    floor_mean = float(np.mean(rows["oracle (raw)"]["rmse"]))
    summary = {}
    for name, row in rows.items():
        mean, lo, hi = mean_interval(np.array(row["rmse"]))
        cm, clo, chi = mean_interval(np.array(row["contact_rmse"]))
        summary[name] = {"force_rmse": [mean, lo, hi], "contact_force_rmse": [cm, clo, chi],
                         "ratio_raw_floor": mean / floor_mean}
    step1 = None
    if base is not None and config.step1_trials != 0:
        step1 = step1_by_patient(run, {"Base": base, "Seal": seal}, config.step1_trials)
    return {"config": config.model_dump(mode="json"), "trials": n, "step1": step1,
            "trial_seeds": [t.metadata["scenario"]["seed"] for t in trials],
            "free_seed": FREE_SEED, "corr_recipe": rec.model_dump(mode="json"),
            "general_from": {"cells": str(cells), "seed": config.seed,
                             "length_s": config.general_length_s, "rows": general},
            "per_trial": rows, "summary": summary, "fits": fits}


def markdown(results: dict[str, Any], command: str) -> str:
    """The study's report: the summary table and what it reads against."""
    c = results["config"]
    lines = [
        "# The gap to the floor on unseen patients: how much is the patient",
        "",
        f"Command: `{command}`",
        "",
        f"The paper-scale run's {results['trials']} contact trials (unseen patients). For each "
        "trial, fresh free motion of that trial's own patient (the same seal, body wall, "
        "incision and pressure; other motion, no sample of the trial) trains a correction "
        "net from scratch with the run's Corr recipe on the run's Seal (`own Corr`), and the "
        "daemon's gated pipeline replays the same free motion and then the trial, adapting as "
        "it goes from a zero correction (`wrenchd online`: the served, causal estimate). Its "
        "step 2 holds the body wall as physics, whose form is the simulator's own body wall, "
        "so on the simulator that part fits exactly: `net only` replays it without. Rows "
        "marked `other patients` are the run's own cells "
        f"(training seed {c['seed']}, {c['general_length_s']:g} s of trocar data from other "
        "patients).",
        "",
        "Force RMSE: the mean over Fx, Fy, Fz of each axis's RMSE against the true tip force, "
        "every sample of a trial, through the run's causal 10 Hz output filter (the report's "
        "figure); contact force RMSE: over the contact samples only. Mean over trials [95 % "
        "interval, bootstrap over trials].",
        "",
        "| row | force RMSE [N] | / raw floor | contact force RMSE [N] |",
        "| --- | --- | --- | --- |",
    ]
    for name, s in results["summary"].items():
        m, lo, hi = s["force_rmse"]
        cm, clo, chi = s["contact_force_rmse"]
        lines.append(f"| {name} | {m:.3f} [{lo:.3f}, {hi:.3f}] | {s['ratio_raw_floor']:.2f} | "
                     f"{cm:.3f} [{clo:.3f}, {chi:.3f}] |")
    if results.get("step1"):
        lines += ["", "## Step 1 in its own domain", "",
                  "Base on `free-space`, Seal on `free-space-seal`: the run's in-domain trials "
                  "(unseen patients), the same trials' motion with the patients the model was "
                  "trained on, and with the fixed default patient. Force RMSE before the "
                  "filter against the raw floor of those trials (the report's in-domain target "
                  "is 2x).", "",
                  "| model: patients | force RMSE [N] | / raw floor |", "| --- | --- | --- |"]
        for name, row in results["step1"].items():
            m, lo, hi = row["force_rmse"]
            lines.append(f"| {name} | {m:.3f} [{lo:.3f}, {hi:.3f}] | "
                         f"{row['ratio_raw_floor']:.2f} |")
    lines += ["", "Per trial, force RMSE [N]:", "",
              "| row | " + " | ".join(str(k) for k in range(results["trials"])) + " |",
              "| --- |" + " --- |" * results["trials"]]
    for name, row in results["per_trial"].items():
        lines.append(f"| {name} | " + " | ".join(f"{v:.3f}" for v in row["rmse"]) + " |")
    return "\n".join(lines) + "\n"
