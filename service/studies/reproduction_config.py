"""Sizes of the paper reproduction: :class:`ReproductionConfig` and its named runs.

``QUICK`` (seconds, the test suite), the default (the committed report's shortened run),
:data:`PAPER` (the paper-scale run) and :data:`PAPER_QUICK` (its pipeline at toy sizes).
Every field is checked when the configuration is built, so a bad size is named before any
session is simulated; :mod:`wrenchd.service.studies.reproduction` says what the run does.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from wrenchd.adapters.sim.patients import REALISTIC_HANDLE_NM_PER_RAD, PatientRanges
from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.training import recipe

CONFIGS = ("Troc", "Base", "Seal", "Base+Corr", "Seal+Corr", "Seal+Xfer")
TRAINED = ("Troc", "Base+Corr", "Seal+Corr", "Seal+Xfer")
TWO_STEP = ("Base+Corr", "Seal+Corr", "Seal+Xfer")
AXES = ("Fx", "Fy", "Fz", "tau_x", "tau_y", "tau_z")


class Step1Training(BaseModel):
    """Base and Seal trained in the run: free motion, early stopping on held-out sessions."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    duration_s: float = Field(default=3600.0, gt=0,
                              description="free-motion training data per model [s] (paper: ~1 h)")
    session_s: float = Field(default=120.0, gt=0, description="length of one session [s]")
    val_sessions: int = Field(default=5, ge=1, description="held-out sessions (early stopping)")
    recipe: str = Field(default="free-space", description="recipe (the paper's: 1000 epochs)")
    overrides: dict[str, Any] = Field(default={}, description="recipe fields replaced")
    seed: int = Field(default=100000, description="first session seed (Seal: + 10000)")
    one_seed: bool = Field(
        default=False,
        description="train Base and Seal once, with the first training seed, and serve them "
                    "under every seed (step 1 costs most of the run); their rows then have "
                    "intervals over trials only")

    @model_validator(mode="after")
    def _recipe(self) -> Step1Training:
        _check_recipe("recipe", self.recipe, self.overrides)
        return self


def _check_recipe(field: str, name: str, overrides: dict[str, Any]) -> None:
    """A recipe name and its replaced fields, refused here rather than at the first fit."""
    try:
        recipe(name, **overrides)
    except ConfigError as exc:
        raise ValueError(f"{field}: {exc}") from None
    except ValidationError as exc:
        bad = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']} (got {e['input']!r})"
                        for e in exc.errors())
        raise ValueError(f"{field} {name!r}: {bad}") from None


class ReproductionConfig(BaseModel):
    """Sizes of the reproduction: lengths, trials, recipes, seeds, patients, scoring."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    lengths_s: tuple[float, ...] = Field(default=(229.0, 474.0, 874.0, 1013.0), min_length=1,
                                         description="trocar training lengths [s] (the paper's), "
                                                     "increasing")
    segment_s: float = Field(default=30.0, gt=0, description="length of one training session [s]")
    no_contact_trials: int = Field(default=8, ge=1, le=1000,
                                   description="no-contact test sessions (more would reuse the "
                                               "contact trials' seeds)")
    no_contact_trial_s: float = Field(default=30.0, gt=0, description="their length [s]")
    contact_trials: int = Field(default=3, ge=1, description="contact test sessions")
    contact_trial_s: float = Field(default=45.0, gt=0, description="their length [s]")
    recurrent_overrides: dict[str, Any] = Field(
        default={"epochs": 6, "lr": 3e-3, "lr_halving_epochs": 2, "window": 50,
                 "lane_windows": 4, "batch_size": 16, "patience": None},
        description="recipe fields replaced for Troc and Xfer (shortened)")
    troc_recipe: str = Field(default="troc", description="Troc recipe")
    xfer_recipe: str = Field(default="xfer", description="Xfer recipe")
    corr_recipe: str = Field(default="corr-fast", description="Corr recipe of the tables")
    corr_overrides: dict[str, Any] = Field(default={}, description="its fields replaced")
    paper_corr_overrides: dict[str, Any] = Field(
        default={}, description="fields of the paper's Corr recipe replaced (side by side run)")
    fast_vs_paper: bool = Field(default=True, description="run the paper's Corr recipe beside "
                                                          "the fast one at the shortest length")
    seed: int = Field(default=1000, description="first seed of the training sessions")
    test_seed: int = Field(default=50000, description="first seed of the test sessions")
    training_seeds: tuple[int, ...] = Field(default=(0,), min_length=1,
                                            description="seeds of every trained network, one "
                                                        "run of each cell per seed")
    validation_sessions: int = Field(default=0, ge=0,
                                     description="held-out trocar sessions that early-stop Troc "
                                                 "and Xfer; 0: the tail of each training series")
    validation_seed: int = Field(default=70000, description="first seed of those sessions")
    patient_variation: bool = Field(default=False,
                                    description="draw a patient per session; false: one fixed "
                                                "patient everywhere")
    patient_ranges: PatientRanges = Field(default_factory=PatientRanges,
                                          description="the ranges of the draws")
    handle_nm_per_rad: float | None = Field(default=None, gt=0,
                                            description="handle torsional stiffness [N m/rad]; "
                                                        "None: the contact effect's default")
    sensor_on_no_contact: bool = Field(default=False,
                                       description="record the force sensor in no-contact trials")
    output_filter_hz: float | None = Field(default=None, gt=0,
                                           description="cut-off of the causal 2nd-order "
                                                       "Butterworth on every wrench estimate "
                                                       "[Hz]; None: raw estimates")
    step1: Step1Training | None = Field(default=None,
                                        description="train Base and Seal here; None: the "
                                                    "shipped weights")
    step1_test_trials: int = Field(default=0, ge=0,
                                   description="in-domain step-1 test sessions (free motion)")
    step1_test_s: float = Field(default=30.0, gt=0, description="their length [s]")
    step1_test_seed: int = Field(default=120000, description="first seed of those sessions")


    @model_validator(mode="after")
    def _relations(self) -> ReproductionConfig:
        lengths = self.lengths_s
        if any(L <= 0 for L in lengths) or any(b <= a for a, b in zip(lengths, lengths[1:])):
            raise ValueError(f"lengths_s must be positive and increasing (the training sets are "
                             f"nested, the longest last), got {lengths}")
        for field, name, overrides in (
                ("troc_recipe", self.troc_recipe, self.recurrent_overrides),
                ("xfer_recipe", self.xfer_recipe, self.recurrent_overrides),
                ("corr_recipe", self.corr_recipe, self.corr_overrides),
                ("paper_corr_overrides", "corr", self.paper_corr_overrides)):
            _check_recipe(field, name, overrides)
        return self


QUICK = ReproductionConfig(
    lengths_s=(20.0, 40.0), segment_s=10.0, no_contact_trials=2, no_contact_trial_s=10.0,
    contact_trials=1, contact_trial_s=20.0,
    recurrent_overrides={"epochs": 1, "window": 20, "lane_windows": 2, "batch_size": 8,
                         "patience": None},
    corr_overrides={"epochs": 3}, paper_corr_overrides={"epochs": 3})

#: The paper-scale run: the paper's lengths and trial counts (92 no-contact, 12 contact
#: trials), three training seeds, patient variation, the realistic handle, step 1 on an hour
#: of free motion per model and every recurrent network to convergence (the paper's recipes:
#: 1000 epochs as the ceiling, early stopping on held-out sessions), the paper's Corr recipe.
PAPER = ReproductionConfig(
    no_contact_trials=92, contact_trials=12, recurrent_overrides={}, corr_recipe="corr",
    fast_vs_paper=False, training_seeds=(0, 1, 2), validation_sessions=4,
    patient_variation=True, handle_nm_per_rad=REALISTIC_HANDLE_NM_PER_RAD,
    sensor_on_no_contact=True, output_filter_hz=10.0, step1=Step1Training(one_seed=True),
    step1_test_trials=20)

#: The paper-scale run's pipeline at toy sizes (seconds), for the tests.
PAPER_QUICK = PAPER.model_copy(update=dict(
    lengths_s=(20.0, 40.0), segment_s=10.0, no_contact_trials=3, no_contact_trial_s=8.0,
    contact_trials=2, contact_trial_s=20.0, training_seeds=(0, 1), validation_sessions=1,
    recurrent_overrides={"epochs": 1, "window": 20, "lane_windows": 2, "batch_size": 8},
    corr_recipe="corr-fast", corr_overrides={"epochs": 2},
    step1=Step1Training(duration_s=20.0, session_s=10.0, val_sessions=1, one_seed=True,
                        overrides={"epochs": 2, "window": 20, "lane_windows": 2,
                                   "batch_size": 8}),
    step1_test_trials=2, step1_test_s=8.0))
