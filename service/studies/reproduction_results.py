"""What the paper reproduction measured, as typed records: the layout of ``results.json``.

:class:`ReproductionResult` is the whole run; its table cells (:class:`Cell`) are keyed by
configuration name and trocar training length [s] (a float, written ``"229.0"`` in JSON).
Fields that a run does not measure (no output filter, no step-1 training, a report written
before per-trial scores existed) are ``None`` and left out of the JSON, so that reports
committed by earlier runs still load and render
(:mod:`wrenchd.service.studies.reproduction_report`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from wrenchd.models.estimator.training import TrainConfig
from wrenchd.service.studies.reproduction_config import ReproductionConfig


def _absent(value: Any) -> bool:
    return value is None


def optional(**kwargs: Any) -> Any:
    """A field that a run may not measure: None, and then absent from the JSON."""
    return Field(default=None, exclude_if=_absent, **kwargs)


class Record(BaseModel):
    """A part of the results; NaN and infinities stay floats in the JSON."""

    model_config = ConfigDict(extra="forbid", ser_json_inf_nan="constants")


class Interval(Record):
    """Mean and 95 % bootstrap interval per axis, and of the mean force, over seeds and
    trials (:func:`~wrenchd.service.studies.reproduction_summary.cell_stats`)."""

    mean: list[float]
    ci95: list[list[float]]
    force: float
    force_ci95: list[float]
    per_seed_force: list[float]


#: {reference ("truth", "sensor", "truth_unfiltered"): {metric: interval, None where no
#: trial has a sample to score (the contact RMSE of trials without contact)}}
Scores = dict[str, dict[str, Interval | None]]


class Summary(Record):
    """Per-axis truth RMSE over every sample averaged over trials, its ratio to the oracle
    floor, and the mean force RMSE (mean of Fx, Fy, Fz) with its spread over trials."""

    rmse: list[float]
    ratio: list[float]
    force_rmse: float
    force_rmse_std: float
    force_ratio: float


class Cell(Summary):
    """A table cell: the :class:`Summary` of its seeds and trials, the ratio to the raw
    floor, every reference and metric with intervals (``scores``) and, with an output filter,
    the same estimate before the filter."""

    force_ratio_raw_floor: float | None = optional()
    seeds: int | None = optional()
    trials: int | None = optional()
    scores: Scores | None = optional()
    unfiltered_force_rmse: float | None = optional()
    unfiltered_force_ratio_raw_floor: float | None = optional()


class InDomainCell(Cell):
    """A step-1 model on the free motion it was trained for, with the floors of its trials."""

    oracle: Cell
    oracle_filtered: Cell


class Fit(Record):
    """The held-out score and epochs of one trained network."""

    score: float
    epochs_run: int


class FitCell(Fit):
    """The mean score and largest epoch count over the training seeds, and each seed's."""

    per_seed: list[Fit] | None = optional()


class Step1Fit(Record):
    """Base or Seal trained in the run with one training seed."""

    train_seconds: float
    score: float
    epochs_run: int


class Step1Record(Record):
    """Base and Seal trained in the run: per seed, the free-motion data and the recipe."""

    per_seed: list[dict[str, Step1Fit]]
    data_s: dict[str, float]
    held_out_sessions: int
    recipe: TrainConfig


class Pretrained(Record):
    """How the shipped step-1 weights were trained (their checkpoint's record)."""

    train_seconds: float | None
    epochs_run: int | None
    series: int


class RecipeRun(Record):
    """Base+Corr trained with one Corr recipe (the fast one or the paper's), and the
    :class:`Summary` fields of its contact trials."""

    recipe: str
    overrides: dict[str, Any]
    train_seconds: float
    cpu_seconds: float | None = optional()
    epochs_run: int
    rmse: list[float]
    ratio: list[float]
    force_rmse: float
    force_rmse_std: float
    force_ratio: float


class FastVsPaper(Record):
    """The fast Corr recipe beside the paper's on the same data, in the same run."""

    length_s: float
    threads: int
    paper: RecipeRun
    fast: RecipeRun


class Trials(Record):
    no_contact: int
    contact: int
    step1_in_domain: dict[str, int]


class Seeds(Record):
    training: list[int]
    training_sessions: list[int]
    validation_sessions: int
    test_sessions: int


class OutputFilter(Record):
    kind: str
    cutoff_hz: float


class Patients(Record):
    """The patient draw of every session (patient variation only)."""

    training: list[Any]
    no_contact: list[Any]
    contact: list[Any]


class Step1Criterion(Record):
    ratios: dict[str, dict[str, float]]
    within_2x: bool


class BestTwoStep(Record):
    config: str
    ratios: dict[str, float]
    unseen_patients: bool
    within_1_5x: bool
    #: the length it is judged at when that is not the run's longest (a partial run)
    length_s: float | None = optional()


class Criteria(Record):
    """The paper-scale run's targets
    (:func:`~wrenchd.service.studies.reproduction_summary.criteria`)."""

    step1_in_domain: Step1Criterion | None = optional()
    best_two_step: BestTwoStep


class PairedDifference(Record):
    """Troc's contact-trial force RMSE minus a two-step configuration's, trial by trial and
    training seed by training seed (the same test trials), with its 95 % bootstrap interval
    over seeds and trials [N]
    (:func:`~wrenchd.service.studies.reproduction_summary.troc_minus`): below zero, Troc is
    the better."""

    mean: float
    ci95: list[float]


class Progress(Record):
    """How far a run that is still going (or was stopped) has come: the (training seed,
    trocar training length) cells trained and scored so far, of ``planned`` in all. A
    complete run has no progress record."""

    done: list[tuple[int, float]]
    planned: int


class ReproductionResult(Record):
    """Every number of one reproduction run (``results.json``)."""

    config: ReproductionConfig
    axes: list[str]
    recipes: dict[str, TrainConfig]
    pretrained: dict[str, Pretrained]
    torch_threads: int
    patient_variation: bool | None = optional()
    trials: Trials | None = optional()
    seeds: Seeds | None = optional()
    output_filter: OutputFilter | None = None
    oracle: dict[str, Cell]
    oracle_filtered: dict[str, Cell] | None = optional()
    train_seconds: dict[str, dict[float, float]]
    contact: dict[str, dict[float, Cell]]
    no_contact: dict[str, Cell]
    validation: dict[str, dict[float, FitCell]]
    patient_draws_disjoint: bool | None = optional()
    patients: Patients | None = optional()
    fast_vs_paper: FastVsPaper | None = optional()
    step1: Step1Record | None = optional()
    step1_in_domain: dict[str, InDomainCell] | None = optional()
    #: {length [s]: {two-step configuration: Troc minus it}} (absent from older runs)
    troc_minus_two_step: dict[float, dict[str, PairedDifference]] | None = optional()
    criteria: Criteria | None = optional()
    wall_seconds: float | None = optional()
    command: str | None = optional()
    provenance: dict[str, Any] | None = optional()
    progress: Progress | None = optional()

    @property
    def lengths(self) -> list[float]:
        """The trocar training lengths [s] at which every configuration has been scored: all
        of the config's in a complete run, those done so far in a partial one."""
        return [float(L) for L in self.config.lengths_s
                if all(float(L) in by_length for by_length in self.contact.values())]

    @property
    def scored(self) -> bool:
        """Whether the cells carry per-trial scores with intervals (every current run)."""
        base = self.no_contact.get("Base")
        return base is not None and base.scores is not None

    def to_json(self) -> dict[str, Any]:
        """The JSON object of ``results.json`` (keys as ever: lengths as ``"229.0"``)."""
        return self.model_dump(mode="json")

    @classmethod
    def read(cls, path: str | Path) -> ReproductionResult:
        """A ``results.json`` written by ``wrenchd reproduce``, checked against this layout."""
        return cls.model_validate(json.loads(Path(path).read_text()))
