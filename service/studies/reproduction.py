"""The paper's three tables regenerated on the simulator (Wu, Yilmaz, Kazanzides, Tumerdem).

The paper (arXiv 2012.01479) compares six ways to train the two-step estimator on trocar data;
this study runs the same comparison where the true tip wrench is known, to check its claims:
training time, no-contact RMSE per axis and contact RMSE against training length (s of data).

==========  =====================================================================
Troc        the step-1 structure trained directly on trocar data (per length)
Base        step 1 trained on free motion without a seal (shipped ``base`` weights)
Seal        step 1 trained on free motion through the seal (shipped ``seal`` weights)
Base+Corr   Base + a correction net trained on trocar data (per length)
Seal+Corr   Seal + a correction net trained on trocar data (per length)
Seal+Xfer   Seal's LSTMs frozen + new layers trained on trocar data (per length)
==========  =====================================================================

RMSEs [N, N m] compare the estimate with the simulator's true tip wrench and are also given
as a ratio to an oracle floor (:func:`run_reproduction` says how the data and the floor are
made). :data:`PAPER` (``wrenchd reproduce --paper``) adds patient variation, step 1 trained
here, several seeds with 95 % intervals and an output filter (``docs/estimator-and-training.md``,
"The paper-scale run"). The run is four steps, each its own module returning typed records:
the sessions (:mod:`~wrenchd.service.studies.reproduction_sets`), the training
(:mod:`~wrenchd.service.studies.reproduction_training`), the scoring
(:mod:`~wrenchd.service.studies.reproduction_scoring`) and the table cells
(:mod:`~wrenchd.service.studies.reproduction_summary`).
"""

from __future__ import annotations

from pathlib import Path

from typing import Callable

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.service.studies.reproduction_cells import Cell, cell_path, load_cell, save_cell
from wrenchd.service.studies.reproduction_config import (
    AXES,
    CONFIGS,
    PAPER,
    PAPER_QUICK,
    QUICK,
    TRAINED,
    TWO_STEP,
    ReproductionConfig,
    Step1Training,
)
from wrenchd.service.studies.reproduction_results import (
    FastVsPaper,
    Fit,
    FitCell,
    InDomainCell,
    OutputFilter,
    Pretrained,
    Progress,
    ReproductionResult,
    Seeds,
    Step1Fit,
    Step1Record,
    Trials,
)
from wrenchd.service.studies.reproduction_scoring import (
    ModelScores,
    Scorers,
    TrialScores,
    oracle_torques,
    score_models,
    wrench_rmse,
)
from wrenchd.service.studies.reproduction_sets import ReproductionSets, build_sets
from wrenchd.service.studies.reproduction_summary import (
    criteria,
    floor_summary,
    like_for_like,
    summarise,
    troc_minus,
)
from wrenchd.service.studies.reproduction_training import (
    LengthTraining,
    fast_vs_paper,
    seeded_recipe,
    train_length,
    train_step1,
)

__all__ = ["AXES", "CONFIGS", "PAPER", "PAPER_QUICK", "QUICK", "TRAINED", "ReproductionConfig",
           "ReproductionResult", "Step1Training", "run_reproduction"]


class Collected(BaseModel):
    """Per-seed scores, times and fits of every cell, gathered over the training seeds."""

    model_config = ConfigDict(arbitrary_types_allowed=True)

    contact: dict[str, dict[float, list[TrialScores]]] = Field(
        default_factory=lambda: {c: {} for c in CONFIGS})
    no_contact: dict[str, list[TrialScores]] = Field(
        default_factory=lambda: {c: [] for c in CONFIGS})
    step1_in_domain: dict[str, list[TrialScores]] = Field(default_factory=dict)
    seconds: dict[str, dict[float, list[float]]] = Field(
        default_factory=lambda: {c: {} for c in TRAINED})
    fits: dict[str, dict[float, list[Fit]]] = Field(
        default_factory=lambda: {c: {} for c in TRAINED})
    step1: list[dict[str, Step1Fit]] = Field(default_factory=list)
    fast_vs_paper: FastVsPaper | None = None

    def add_step1(self, scores: ModelScores, lengths: tuple[float, ...]) -> None:
        """Base and Seal of one seed: one score per contact length, the in-domain trials."""
        for name, sc in scores.contact.items():
            for length in lengths:
                self.contact[name].setdefault(length, []).append(sc)
        for name, sc in scores.no_contact.items():
            self.no_contact[name].append(sc)
        for name, sc in scores.step1_in_domain.items():
            self.step1_in_domain.setdefault(name, []).append(sc)

    def add_cell(self, cell: Cell) -> None:
        """The per-length configurations of one seed and length, trained here or read back."""
        length = cell.length_s
        for name, seconds in cell.seconds.items():
            self.seconds[name].setdefault(length, []).append(seconds)
            self.fits[name].setdefault(length, []).append(cell.fits[name])
            self.contact[name].setdefault(length, []).append(cell.scores.contact[name])
        for name, sc in cell.scores.no_contact.items():
            self.no_contact[name].append(sc)


def as_cell(training: LengthTraining, scores: ModelScores) -> Cell:
    """A length's training and its scores, as :mod:`.reproduction_cells` keeps them."""
    return Cell(seed=training.seed, length_s=training.length_s,
                seconds={k: t.seconds for k, t in training.configs.items()},
                fits={k: t.fit for k, t in training.configs.items()}, scores=scores)


def run_reproduction(config: ReproductionConfig, base: FreeSpaceModel | None = None,
                     seal: FreeSpaceModel | None = None,
                     pretrained_info: dict[str, Pretrained] | None = None,
                     log: Callable[[str], None] = print,
                     device: str | None = "cpu",
                     checkpoints: Path | None = None,
                     weights: Path | None = None,
                     progress: Callable[[ReproductionResult], None] | None = None,
                     cells: Path | None = None,
                     finished: Callable[[str, int], list[Path]] | None = None
                     ) -> ReproductionResult:
    """Train the per-length configurations, evaluate all six, return the results.

    ``checkpoints``: a folder where every recurrent network's training (Base, Seal, Troc,
    Xfer, per seed and length) is saved after each epoch and resumed from: the same command
    started again after a stop goes on where it stopped. ``weights``: a folder where the
    step-1 models trained here (Base, Seal, per seed) are written as estimator checkpoints.
    ``progress``: called after every (training seed, length) cell with the result so far
    (its :class:`~wrenchd.service.studies.reproduction_results.Progress` says what is done;
    the tables hold the lengths every configuration has reached): a run of days shows its
    figures as they come, and a stopped one keeps them. ``cells``: a folder where each
    finished cell's scores are written and read back instead of training it again
    (:mod:`~wrenchd.service.studies.reproduction_cells`: small files that go into version
    control, so that a run goes on from a fresh clone, where ``checkpoints`` are gone).
    ``finished``: finished step-1 trainings to use instead of training them
    (:func:`~wrenchd.service.studies.reproduction_training.train_step1`).

    Data: the trocar training set of length ``L`` is ``L / segment_s`` simulated ``trocar``
    sessions of ``segment_s`` seconds (seeds ``seed + k``; the sets are nested, a longer set
    holds the shorter ones). Tests: ``no_contact_trials`` fresh ``trocar`` sessions, and
    ``contact_trials`` fresh ``trocar-contact`` sessions, all with seeds no training set uses.
    RMSEs compare the estimated tip wrench with the simulator's true tip wrench (zero without
    contact) over every sample of a trial, per axis, averaged over trials.

    Oracle floor: the estimate made with the simulator's own noise-free internal torque
    (``truth.internal_torque``), so that what is left is the effort noise mapped through the
    damped ``J^-T``. Every RMSE is also given as a ratio to this floor.

    The paper-scale run (:data:`PAPER`) adds, each switched by a field of
    :class:`~wrenchd.service.studies.reproduction_config.ReproductionConfig`:

    * patient variation: every session (training, held-out validation, test) draws its own
      seal, body wall, incision and pressure (:mod:`wrenchd.adapters.sim.patients`); the
      session seeds of the roles are disjoint, so test patients are unseen, and the run checks
      that no test draw equals a training draw (``patient_draws_disjoint``);
    * the handle's torsional stiffness (``handle_nm_per_rad``);
    * step 1 (Base, Seal) trained here per training seed on ``step1.duration_s`` of free
      motion, early-stopped on held-out sessions (:func:`~wrenchd.service.studies.training.
      fit_step1_held_out`), and tested in domain on fresh free-motion sessions of unseen
      patients;
    * Troc and Xfer early-stopped on held-out trocar sessions (``validation_sessions``);
    * several training seeds per cell; every table cell is the mean over seeds and trials with
      a 95 % interval (:func:`~wrenchd.service.studies.reproduction_scoring.mean_interval`);
    * RMSE over every sample, RMSE over contact samples only and the peak error, each against
      the simulator's true tip wrench and against the force sensor's noisy channel;
    * an output filter (``output_filter_hz``: a causal second-order Butterworth low-pass on
      every wrench estimate) and beside the raw oracle floor the oracle through the same
      filter.

    ``base``, ``seal``: the step-1 models when ``config.step1`` is None (else trained here,
    per training seed). ``device``: where the recurrent networks train (None: CUDA when
    present); Corr trains on the CPU.
    """
    if config.step1 is None and (base is None or seal is None):
        raise ValueError("without config.step1 the step-1 models base and seal are needed")
    wmap = WrenchMap()
    sets = build_sets(config)
    scorers = Scorers.build(sets, wmap, config.output_filter_hz)
    held = [s.joint_states for s in sets.validation]
    collected = Collected()
    step1_tables = ("no_contact", "contact", "step1_in_domain")
    once = config.step1 is not None and config.step1.one_seed
    done: list[tuple[int, float]] = []
    planned = len(config.training_seeds) * len(config.lengths_s)
    for seed in config.training_seeds:
        # step 1 trained per seed, or once (the first seed's, served under every seed): then
        # scored once too, so that its intervals do not count one network as several
        first = seed == config.training_seeds[0]
        if config.step1 is not None and (first or not once):
            fits = train_step1(config, seed, sets.step1, device, log, checkpoints, weights,
                               finished)
            base, seal = fits.models["Base"], fits.models["Seal"]
            collected.step1.append(fits.fits)
        if first or not once:
            step1_scores = score_models(scorers, {"Base": (base, None), "Seal": (seal, None)},
                                        step1_tables)
            collected.add_step1(step1_scores, config.lengths_s)
            log_in_domain(scorers, step1_scores, config.output_filter_hz is not None, seed, log)
        for length in config.lengths_s:
            cell = load_cell(cells, config, seed, length) if cells is not None else None
            if cell is not None:
                log(f"seed {seed} L={length:g} s: read from "
                    f"{cell_path(cells, seed, length)}, not trained again")
            else:
                data = [s.joint_states for s in sets.training[length]]
                training = train_length(config, seed, length, data, held, base, seal, device,
                                        checkpoints)
                longest = length == config.lengths_s[-1]    # no-contact table: the longest
                scores = score_models(
                    scorers, {k: (t.step1, t.step2) for k, t in training.configs.items()},
                    ("contact", "no_contact") if longest else ("contact",))
                for name, trained in training.configs.items():
                    log(f"seed {seed} L={length:g} s {name}: trained in "
                        f"{trained.seconds:.1f} s ({trained.fit.epochs_run} epochs), contact "
                        f"force RMSE {scores.contact[name]['truth']['rmse'][:, :3].mean():.3f} N")
                cell = as_cell(training, scores)
                if cells is not None:
                    save_cell(cells, config, cell)
                if (length == config.lengths_s[0] and config.fast_vs_paper
                        and seed == config.training_seeds[0]):
                    collected.fast_vs_paper = fast_vs_paper(
                        config, base, data, sets.contact, wmap,
                        wrench_rmse(oracle_torques(sets.contact), sets.contact, wmap), log)
            collected.add_cell(cell)
            done.append((seed, float(length)))
            if progress is not None and len(done) < planned:
                progress(summarise_run(config, sets, scorers, collected, pretrained_info,
                                       Progress(done=list(done), planned=planned)))
    return summarise_run(config, sets, scorers, collected, pretrained_info)


def log_in_domain(scorers: Scorers, scores: ModelScores, filtered: bool, seed: int,
                  log: Callable[[str], None]) -> None:
    """Log each step-1 model's in-domain false force and its ratio to the raw oracle floor as
    soon as it is scored (the run's first target), hours before the run's report."""
    for name, per_trial in scores.step1_in_domain.items():
        cell = summarise([per_trial], scorers.step1_in_domain[name].floors(), filtered)
        force = (cell.unfiltered_force_rmse if cell.unfiltered_force_rmse is not None
                 else cell.force_rmse)
        log(f"seed {seed} {name} in domain: free-motion force RMSE {force:.3f} N over "
            f"{cell.trials} trials, {like_for_like(cell)['raw']:.2f}x the raw oracle floor")


def summarise_run(config: ReproductionConfig, sets: ReproductionSets, scorers: Scorers,
                  collected: Collected, pretrained_info: dict[str, Pretrained] | None,
                  progress: Progress | None = None) -> ReproductionResult:
    """The run's result from what the training seeds collected (``progress``: how far a
    partial run has come; its configurations not scored yet are left out)."""
    cut = config.output_filter_hz
    filtered = cut is not None
    floors = scorers.floors()
    first = config.training_seeds[0]
    in_domain = {}
    for name, per_seed in collected.step1_in_domain.items():
        f = scorers.step1_in_domain[name].floors()
        in_domain[name] = InDomainCell(**summarise(per_seed, f, filtered).model_dump(),
                                       oracle=floor_summary(f["raw"]),
                                       oracle_filtered=floor_summary(f["filtered"]))
    step1 = None
    if collected.step1:
        step1 = Step1Record(
            per_seed=collected.step1,
            data_s={k: float(sum(s.joint_states.t[-1] + 1 / s.joint_states.rate_hz
                                 for s in tr)) for k, (tr, _) in sets.step1.items()},
            held_out_sessions=config.step1.val_sessions,
            recipe=seeded_recipe(config.step1.recipe, config.step1.overrides, first))
    result = ReproductionResult(
        config=config, axes=list(AXES),
        recipes={"troc": seeded_recipe(config.troc_recipe, config.recurrent_overrides, first),
                 "xfer": seeded_recipe(config.xfer_recipe, config.recurrent_overrides, first),
                 "corr": seeded_recipe(config.corr_recipe, config.corr_overrides, first)},
        pretrained=pretrained_info or {},
        torch_threads=torch.get_num_threads(), patient_variation=config.patient_variation,
        trials=Trials(no_contact=len(sets.no_contact), contact=len(sets.contact),
                      step1_in_domain={k: len(v) for k, v in sets.step1_tests.items()}),
        seeds=Seeds(training=list(config.training_seeds),
                    training_sessions=[config.seed, config.seed + len(sets.longest) - 1],
                    validation_sessions=config.validation_sessions,
                    test_sessions=config.test_seed),
        output_filter=(OutputFilter(kind="causal 2nd-order Butterworth low-pass", cutoff_hz=cut)
                       if filtered else None),
        oracle={k: floor_summary(f["raw"]) for k, f in floors.items()},
        oracle_filtered={k: floor_summary(f["filtered"]) for k, f in floors.items()},
        train_seconds={name: {L: round(float(np.mean(v)), 2) for L, v in by_length.items()}
                       for name, by_length in collected.seconds.items()},
        contact={name: {L: summarise(per_seed, floors["contact"], filtered)
                        for L, per_seed in by_length.items()}
                 for name, by_length in collected.contact.items()},
        no_contact={name: summarise(per_seed, floors["no_contact"], filtered)
                    for name, per_seed in collected.no_contact.items() if per_seed},
        validation={name: {L: FitCell(score=float(np.mean([x.score for x in v])),
                                      epochs_run=int(max(x.epochs_run for x in v)), per_seed=v)
                           for L, v in by_length.items()}
                    for name, by_length in collected.fits.items()},
        patient_draws_disjoint=sets.draws_disjoint() if config.patient_variation else None,
        patients=sets.patients() if config.patient_variation else None,
        fast_vs_paper=collected.fast_vs_paper, step1=step1,
        step1_in_domain=in_domain or None, progress=progress,
        troc_minus_two_step={
            L: {name: troc_minus(per_seed, collected.contact[name][L])
                for name in TWO_STEP if L in collected.contact.get(name, {})}
            for L, per_seed in collected.contact.get("Troc", {}).items()} or None)
    return result.model_copy(update={"criteria": criteria(result)})
