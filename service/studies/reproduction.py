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

The paper-scale run (:data:`PAPER`, ``wrenchd reproduce --paper``) adds, each switched by a
field of :class:`ReproductionConfig`:

* patient variation: every session (training, held-out validation, test) draws its own seal,
  body wall, incision and pressure (:mod:`wrenchd.adapters.sim.patients`); the session seeds of
  the roles are disjoint, so test patients are unseen, and the run checks that no test draw
  equals a training draw (``patient_draws_disjoint``);
* the handle's torsional stiffness (``handle_nm_per_rad``);
* step 1 (Base, Seal) trained here per training seed on ``step1.duration_s`` of free motion,
  early-stopped on held-out sessions (:func:`~wrenchd.service.studies.training.
  fit_step1_held_out`), and tested in domain on fresh free-motion sessions of unseen patients;
* Troc and Xfer early-stopped on held-out trocar sessions (``validation_sessions``);
* several training seeds per cell; every table cell is the mean over seeds and trials with a
  95 % interval (:func:`mean_interval`);
* RMSE over every sample, RMSE over contact samples only and the peak error, each against the
  simulator's true tip wrench and against the force sensor's noisy channel;
* an output filter (``output_filter_hz``: a causal second-order Butterworth low-pass on every
  wrench estimate) and beside the raw oracle floor the oracle through the same filter.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.adapters.sim.patients import REALISTIC_HANDLE_NM_PER_RAD, PatientRanges
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.correction import Corr, Xfer
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.correction_training import fit_corr, fit_xfer, predict_segments
from wrenchd.models.estimator.free_space_training import fit_free_space
from wrenchd.models.estimator.training import recipe
from wrenchd.models.estimator.wrench import WrenchMap
from wrenchd.models.series import Session
from wrenchd.service.studies.training import fit_step1_held_out, fit_xfer_held_out

CONFIGS = ("Troc", "Base", "Seal", "Base+Corr", "Seal+Corr", "Seal+Xfer")
TRAINED = ("Troc", "Base+Corr", "Seal+Corr", "Seal+Xfer")
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


class ReproductionConfig(BaseModel):
    """Sizes of the reproduction: lengths, trials, recipes, seeds, patients, scoring."""

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
    sensor_on_no_contact=True, output_filter_hz=10.0, step1=Step1Training(),
    step1_test_trials=20)

#: The paper-scale run's pipeline at toy sizes (seconds), for the tests.
PAPER_QUICK = PAPER.model_copy(update=dict(
    lengths_s=(20.0, 40.0), segment_s=10.0, no_contact_trials=3, no_contact_trial_s=8.0,
    contact_trials=2, contact_trial_s=20.0, training_seeds=(0, 1), validation_sessions=1,
    recurrent_overrides={"epochs": 1, "window": 20, "lane_windows": 2, "batch_size": 8},
    corr_recipe="corr-fast", corr_overrides={"epochs": 2},
    step1=Step1Training(duration_s=20.0, session_s=10.0, val_sessions=1,
                        overrides={"epochs": 2, "window": 20, "lane_windows": 2,
                                   "batch_size": 8}),
    step1_test_trials=2, step1_test_s=8.0))


def _patients(config: ReproductionConfig) -> PatientRanges | None:
    return config.patient_ranges if config.patient_variation else None


def _session(config: ReproductionConfig, scenario: str, duration_s: float, seed: int,
             sensor: bool | None = None) -> Session:
    return run_scenario(scenario, duration_s, seed, patients=_patients(config),
                        handle_nm_per_rad=config.handle_nm_per_rad, force_sensor=sensor)


def training_set(config: ReproductionConfig, length_s: float) -> list:
    """Sessions of the nested trocar training set of ``length_s`` seconds."""
    n = math.ceil(length_s / config.segment_s - 1e-9)
    out = []
    for k in range(n):
        duration = min(config.segment_s, length_s - k * config.segment_s)
        out.append(_session(config, "trocar", duration, config.seed + k))
    return out


def validation_set(config: ReproductionConfig) -> list[Session]:
    """Held-out trocar sessions that early-stop Troc and Xfer (their own seeds)."""
    return [_session(config, "trocar", config.segment_s, config.validation_seed + k)
            for k in range(config.validation_sessions)]


def test_sets(config: ReproductionConfig) -> tuple[list[Session], list[Session]]:
    """(no-contact trials, contact trials), seeds disjoint from every training set."""
    s0 = config.test_seed
    sensor = True if config.sensor_on_no_contact else None
    free = [_session(config, "trocar", config.no_contact_trial_s, s0 + k, sensor)
            for k in range(config.no_contact_trials)]
    if config.no_contact_trials > 1000:
        raise ValueError("more than 1000 no-contact trials would reuse the contact seeds")
    contact = [_session(config, "trocar-contact", config.contact_trial_s, s0 + 1000 + k)
               for k in range(config.contact_trials)]
    return free, contact


def step1_sets(config: ReproductionConfig, scenario: str, offset: int
               ) -> tuple[list[Session], list[Session]]:
    """Free-motion training and held-out sessions of one step-1 model (``offset`` apart)."""
    st = config.step1
    n = math.ceil(st.duration_s / st.session_s - 1e-9)
    first = st.seed + offset
    train = [_session(config, scenario, min(st.session_s, st.duration_s - k * st.session_s),
                      first + k) for k in range(n)]
    held = [_session(config, scenario, st.session_s, first + 5000 + k)
            for k in range(st.val_sessions)]
    return train, held


def step1_test_sets(config: ReproductionConfig) -> dict[str, list[Session]]:
    """In-domain step-1 tests: free motion for Base, free motion through the seal for Seal."""
    s0 = config.step1_test_seed
    return {name: [_session(config, scenario, config.step1_test_s, s0 + 1000 * i + k, True)
                   for k in range(config.step1_test_trials)]
            for i, (name, scenario) in enumerate((("Base", "free-space"),
                                                  ("Seal", "free-space-seal")))}


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


# -- scoring: every trial, every reference, every metric -----------------------------------
METRICS = ("rmse", "contact_rmse", "peak")


def lowpass(wrench: np.ndarray, rate_hz: float, cutoff_hz: float | None) -> np.ndarray:
    """Causal second-order Butterworth low-pass of (T, 6) samples at ``rate_hz`` [Hz], started
    settled at the first sample; ``cutoff_hz`` None returns the input."""
    if cutoff_hz is None:
        return wrench
    from scipy.signal import butter, lfilter, lfilter_zi

    b, a = butter(2, cutoff_hz / (rate_hz / 2.0))
    zi = lfilter_zi(b, a)[:, None] * wrench[:1]
    return lfilter(b, a, wrench, axis=0, zi=zi)[0]


def trial_errors(estimate: np.ndarray, reference: np.ndarray, in_contact: np.ndarray
                 ) -> dict[str, np.ndarray]:
    """Per-axis errors of one trial (each (6,), [N, N m]).

    ``rmse`` over every sample; ``contact_rmse`` over the samples in contact (NaN without
    contact); ``peak``: the largest absolute error over every sample.
    """
    err = estimate - reference
    contact = (np.sqrt(np.mean(err[in_contact] ** 2, axis=0)) if in_contact.any()
               else np.full(err.shape[1], np.nan))
    return {"rmse": np.sqrt(np.mean(err ** 2, axis=0)), "contact_rmse": contact,
            "peak": np.abs(err).max(axis=0)}


def mean_interval(values: np.ndarray, level: float = 0.95, n_boot: int = 2000,
                  seed: int = 0) -> tuple[float, float, float]:
    """Mean of a (seeds, trials) table and its percentile-bootstrap interval.

    Each resample draws seeds with replacement and, independently, trials with replacement
    (the same trials for every seed: every seed is tested on the same sessions), and takes
    the mean of the selected block; with one seed only the trials are resampled.
    """
    v = np.atleast_2d(np.asarray(values, dtype=np.float64))
    s_n, t_n = v.shape
    rng = np.random.default_rng(seed)
    si = rng.integers(0, s_n, (n_boot, s_n)) if s_n > 1 else np.zeros((n_boot, 1), int)
    ti = rng.integers(0, t_n, (n_boot, t_n))
    per_seed = v[si[:, :, None], ti[:, None, :]]              # (n_boot, S, T)
    means = per_seed.mean(axis=(1, 2))
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(v.mean()), float(lo), float(hi)


class Scorer:
    """Scores wrench estimates of one trial set against the truth and the sensor channel.

    The map from external torque to wrench of every trial is computed once
    (``WrenchMap.gains``); the output filter (``cutoff_hz``) is applied to every estimate.
    """

    def __init__(self, sessions: list[Session], wrench_map: WrenchMap,
                 cutoff_hz: float | None) -> None:
        self.sessions, self.cutoff_hz = sessions, cutoff_hz
        self.gains = [wrench_map.gains(s.joint_states.position) for s in sessions]
        self.references = {"truth": [s.truth.external_wrench for s in sessions]}
        if all(s.truth.sensor_wrench is not None for s in sessions):
            self.references["sensor"] = [s.truth.sensor_wrench for s in sessions]

    def wrenches(self, torques: list[np.ndarray], filtered: bool = True) -> list[np.ndarray]:
        """Estimated tip wrenches from predicted internal torques (filtered if asked)."""
        out = []
        for g, tau, s in zip(self.gains, torques, self.sessions):
            w = np.einsum("nij,nj->ni", g, s.joint_states.effort - tau)
            out.append(lowpass(w, s.joint_states.rate_hz, self.cutoff_hz) if filtered else w)
        return out

    def score(self, torques: list[np.ndarray], filtered: bool = True
              ) -> dict[str, dict[str, np.ndarray]]:
        """{reference: {metric: (trials, 6)}}.

        With an output filter, ``truth_unfiltered`` scores the same estimates before the
        filter against the truth (the like-for-like comparison with the raw floor).
        """
        raw = self.wrenches(torques, filtered=False)
        est = ([lowpass(w, s.joint_states.rate_hz, self.cutoff_hz)
                for w, s in zip(raw, self.sessions)] if filtered else raw)
        refs = [(ref, values, est) for ref, values in self.references.items()]
        if filtered and self.cutoff_hz is not None:
            refs.append(("truth_unfiltered", self.references["truth"], raw))
        out = {}
        for ref, values, estimates in refs:
            rows = [trial_errors(e, r, s.truth.in_contact)
                    for e, r, s in zip(estimates, values, self.sessions)]
            out[ref] = {m: np.array([r[m] for r in rows]) for m in METRICS}
        return out

    def floors(self) -> dict[str, dict[str, dict[str, np.ndarray]]]:
        """The oracle (noise-free internal torque) raw and through the output filter."""
        oracle = oracle_torques(self.sessions)
        return {"raw": self.score(oracle, filtered=False),
                "filtered": self.score(oracle, filtered=True)}


def _cell_stats(values: np.ndarray) -> dict[str, Any] | None:
    """Mean and interval per axis and of the mean force of (seeds, trials, 6) values."""
    if np.isnan(values).any():
        keep = ~np.isnan(values).any(axis=(0, 2))
        values = values[:, keep]
        if values.shape[1] == 0:
            return None
    axes = [mean_interval(values[..., k]) for k in range(values.shape[-1])]
    force = mean_interval(values[..., :3].mean(-1))
    return {"mean": [a[0] for a in axes], "ci95": [[a[1], a[2]] for a in axes],
            "force": force[0], "force_ci95": [force[1], force[2]],
            "per_seed_force": values[..., :3].mean(-1).mean(-1).tolist()}


def summarise(per_seed: list[dict[str, dict[str, np.ndarray]]],
              floors: dict[str, dict[str, dict[str, np.ndarray]]], filtered: bool
              ) -> dict[str, Any]:
    """A table cell from its per-seed scores ({reference: {metric: (trials, 6)}} per seed).

    The legacy keys (``rmse``, ``ratio``, ``force_rmse``, ``force_rmse_std``,
    ``force_ratio``) are the truth RMSE over every sample, the ratios against the floor of
    the same filtering; ``scores`` holds every reference and metric with intervals and
    ``force_ratio_raw_floor`` the ratio against the raw oracle.
    """
    rmse = np.stack([p["truth"]["rmse"] for p in per_seed])            # (S, T, 6)
    floor = floors["filtered" if filtered else "raw"]["truth"]["rmse"]
    raw = floors["raw"]["truth"]["rmse"]
    mean = rmse.mean(axis=(0, 1))
    force = rmse[..., :3].mean(-1)                                     # (S, T)
    out: dict[str, Any] = {
        "rmse": mean.tolist(), "ratio": (mean / floor.mean(0)).tolist(),
        "force_rmse": float(force.mean()), "force_rmse_std": float(force.std()),
        "force_ratio": float(force.mean() / floor[:, :3].mean()),
        "force_ratio_raw_floor": float(force.mean() / raw[:, :3].mean()),
        "seeds": len(per_seed), "trials": int(rmse.shape[1]), "scores": {}}
    if "truth_unfiltered" in per_seed[0]:
        unf = np.stack([p["truth_unfiltered"]["rmse"] for p in per_seed])[..., :3].mean()
        out["unfiltered_force_rmse"] = float(unf)
        out["unfiltered_force_ratio_raw_floor"] = float(unf / raw[:, :3].mean())
    for ref in per_seed[0]:
        out["scores"][ref] = {m: _cell_stats(np.stack([p[ref][m] for p in per_seed]))
                              for m in METRICS}
    return out


def floor_summary(floor: dict[str, dict[str, np.ndarray]]) -> dict[str, Any]:
    """A floor in the layout of :func:`summarise` (one "seed": the oracle is deterministic)."""
    return summarise([floor], {"raw": floor, "filtered": floor}, filtered=False)


# -- the run --------------------------------------------------------------------------------
def _draw(session: Session) -> Any:
    return session.metadata.get("patient", {}).get("draw")


def _disjoint(train: list[Session], test: list[Session]) -> bool:
    """No test session's patient equals a training session's (patient variation only)."""
    seen = [_draw(s) for s in train]
    return all(_draw(t) not in seen for t in test)


def _recipe(name: str, overrides: dict[str, Any], seed: int):
    return recipe(name, **{**overrides, "seed": seed})


def train_step1(config: ReproductionConfig, seed: int, sets: dict[str, tuple[list, list]],
                device: str | None, log: Callable[[str], None]
                ) -> tuple[dict[str, FreeSpaceModel], dict[str, Any]]:
    """Base and Seal trained with training seed ``seed`` on their free-motion sets,
    early-stopped on the held-out sessions."""
    st = config.step1
    models, info = {}, {}
    for name, (train, held) in sets.items():
        rec = _recipe(st.recipe, st.overrides, seed)
        start = time.perf_counter()
        res = fit_step1_held_out([s.joint_states for s in train],
                                 [s.joint_states for s in held], rec, device=device)
        seconds = time.perf_counter() - start
        models[name] = res.model
        info[name] = {"train_seconds": round(seconds, 2), "score": res.validation["score"],
                      "epochs_run": res.validation["epochs_run"]}
        log(f"seed {seed} {name}: {res.validation['epochs_run']} epochs in {seconds:.1f} s, "
            f"held-out score {res.validation['score']:.4f}")
    return models, info


def run_reproduction(config: ReproductionConfig, base: FreeSpaceModel | None = None,
                     seal: FreeSpaceModel | None = None,
                     pretrained_info: dict[str, Any] | None = None,
                     log: Callable[[str], None] = print,
                     device: str | None = "cpu") -> dict[str, Any]:
    """Train the per-length configurations, evaluate all six, return the results dict.

    ``base``, ``seal``: the step-1 models when ``config.step1`` is None (else trained here,
    per training seed). ``device``: where the recurrent networks train (None: CUDA when
    present); Corr trains on the CPU.
    """
    if config.step1 is None and (base is None or seal is None):
        raise ValueError("without config.step1 the step-1 models base and seal are needed")
    wmap = WrenchMap()
    cut = config.output_filter_hz
    filtered = cut is not None
    free, contact = test_sets(config)
    scorers = {"no_contact": Scorer(free, wmap, cut), "contact": Scorer(contact, wmap, cut)}
    floors = {k: sc.floors() for k, sc in scorers.items()}
    val_sessions = validation_set(config)
    step1_data = ({"Base": step1_sets(config, "free-space", 0),
                   "Seal": step1_sets(config, "free-space-seal", 10000)}
                  if config.step1 is not None else {})
    step1_tests = step1_test_sets(config) if config.step1_test_trials else {}
    step1_scorers = {k: Scorer(v, wmap, cut) for k, v in step1_tests.items()}
    data_by_length = {str(L): training_set(config, L) for L in config.lengths_s}
    longest = data_by_length[str(config.lengths_s[-1])]

    train_pool = [s for d in data_by_length.values() for s in d] + val_sessions + [
        s for tr, held in step1_data.values() for s in tr + held]
    test_pool = free + contact + [s for v in step1_tests.values() for s in v]
    results: dict[str, Any] = {
        "config": config.model_dump(mode="json"), "axes": list(AXES),
        "recipes": {"troc": _recipe(config.troc_recipe, config.recurrent_overrides,
                                    config.training_seeds[0]).model_dump(),
                    "xfer": _recipe(config.xfer_recipe, config.recurrent_overrides,
                                    config.training_seeds[0]).model_dump(),
                    "corr": _recipe(config.corr_recipe, config.corr_overrides,
                                    config.training_seeds[0]).model_dump()},
        "pretrained": pretrained_info or {}, "torch_threads": torch.get_num_threads(),
        "patient_variation": config.patient_variation,
        "trials": {"no_contact": len(free), "contact": len(contact),
                   "step1_in_domain": {k: len(v) for k, v in step1_tests.items()}},
        "seeds": {"training": list(config.training_seeds),
                  "training_sessions": [config.seed, config.seed
                                        + len(data_by_length[str(config.lengths_s[-1])]) - 1],
                  "validation_sessions": config.validation_sessions,
                  "test_sessions": config.test_seed},
        "output_filter": ({"kind": "causal 2nd-order Butterworth low-pass", "cutoff_hz": cut}
                          if filtered else None),
        "oracle": {k: floor_summary(f["raw"]) for k, f in floors.items()},
        "oracle_filtered": {k: floor_summary(f["filtered"]) for k, f in floors.items()},
        "train_seconds": {c: {} for c in TRAINED}, "contact": {c: {} for c in CONFIGS},
        "no_contact": {}, "validation": {c: {} for c in TRAINED},
    }
    if config.patient_variation:
        results["patient_draws_disjoint"] = _disjoint(train_pool, test_pool)
        results["patients"] = {"training": [_draw(s) for s in longest],
                               "no_contact": [_draw(s) for s in free],
                               "contact": [_draw(s) for s in contact]}
    # scores[table][name][length] = list over seeds of {reference: {metric: (T, 6)}}
    scores: dict[str, dict[str, dict[str, list]]] = {
        t: {c: {} for c in CONFIGS} for t in ("contact", "no_contact")}
    step1_scores: dict[str, list] = {k: [] for k in step1_tests}
    seconds: dict[str, dict[str, list[float]]] = {c: {} for c in TRAINED}
    validation: dict[str, dict[str, list]] = {c: {} for c in TRAINED}
    step1_info: list[dict[str, Any]] = []
    held_js = [s.joint_states for s in val_sessions]
    for seed in config.training_seeds:
        if config.step1 is not None:
            models, info = train_step1(config, seed, step1_data, device, log)
            base, seal = models["Base"], models["Seal"]
            step1_info.append(info)
        for name, model in (("Base", base), ("Seal", seal)):
            for table, sessions in (("no_contact", free), ("contact", contact)):
                tau = predicted_torques(model, None, sessions)
                sc = scorers[table].score(tau)
                for length in ([config.lengths_s[-1]] if table == "no_contact"
                               else config.lengths_s):
                    scores[table][name].setdefault(str(length), []).append(sc)
            if name in step1_scorers:
                step1_scores[name].append(step1_scorers[name].score(
                    predicted_torques(model, None, step1_tests[name])))
        rec_troc = _recipe(config.troc_recipe, config.recurrent_overrides, seed)
        rec_xfer = _recipe(config.xfer_recipe, config.recurrent_overrides, seed)
        rec_corr = _recipe(config.corr_recipe, config.corr_overrides, seed)
        for length in config.lengths_s:
            data = [s.joint_states for s in data_by_length[str(length)]]
            key = str(length)
            trained: dict[str, tuple[FreeSpaceModel, Corr | Xfer | None]] = {}
            for name in TRAINED:
                start = time.perf_counter()
                if name == "Troc":
                    res = (fit_step1_held_out(data, held_js, rec_troc, device=device) if held_js
                           else fit_free_space(data, config=rec_troc, device=device))
                    trained[name] = (res.model, None)
                elif name == "Seal+Xfer":
                    res = (fit_xfer_held_out(seal, data, held_js, rec_xfer,
                                             device=device) if held_js
                           else fit_xfer(seal, data, config=rec_xfer, device=device))
                    trained[name] = (seal, res.model)
                else:
                    step1 = base if name == "Base+Corr" else seal
                    res = fit_corr(step1, data, config=rec_corr)
                    trained[name] = (step1, res.model)
                took = time.perf_counter() - start
                seconds[name].setdefault(key, []).append(took)
                validation[name].setdefault(key, []).append(
                    {"score": res.validation["score"], "epochs_run": res.validation["epochs_run"]})
                step1, step2 = trained[name]
                sc = scorers["contact"].score(predicted_torques(step1, step2, contact))
                scores["contact"][name].setdefault(key, []).append(sc)
                log(f"seed {seed} L={length:g} s {name}: trained in {took:.1f} s "
                    f"({res.validation['epochs_run']} epochs), contact force RMSE "
                    f"{sc['truth']['rmse'][:, :3].mean():.3f} N")
            if length == config.lengths_s[-1]:        # no-contact table: the longest set
                for name, (step1, step2) in trained.items():
                    sc = scorers["no_contact"].score(predicted_torques(step1, step2, free))
                    scores["no_contact"][name].setdefault(key, []).append(sc)
            if (length == config.lengths_s[0] and config.fast_vs_paper
                    and seed == config.training_seeds[0]):
                results["fast_vs_paper"] = fast_vs_paper(
                    config, base, data, contact, wmap,
                    wrench_rmse(oracle_torques(contact), contact, wmap), log)
    last = str(config.lengths_s[-1])
    for table in ("contact", "no_contact"):
        for name in CONFIGS:
            for key, per_seed in scores[table][name].items():
                cell = summarise(per_seed, floors[table], filtered)
                if table == "contact":
                    results["contact"][name][key] = cell
                elif key == last:
                    results["no_contact"][name] = cell
    for name in TRAINED:
        for key, values in seconds[name].items():
            results["train_seconds"][name][key] = round(float(np.mean(values)), 2)
            v = validation[name][key]
            results["validation"][name][key] = {
                "score": float(np.mean([x["score"] for x in v])),
                "epochs_run": int(max(x["epochs_run"] for x in v)), "per_seed": v}
    if step1_info:
        results["step1"] = {
            "per_seed": step1_info,
            "data_s": {k: float(sum(s.joint_states.t[-1] + 1 / s.joint_states.rate_hz
                                    for s in tr)) for k, (tr, _) in step1_data.items()},
            "held_out_sessions": config.step1.val_sessions,
            "recipe": _recipe(config.step1.recipe, config.step1.overrides,
                              config.training_seeds[0]).model_dump()}
    if step1_tests:
        results["step1_in_domain"] = {}
        for name, sc in step1_scores.items():
            f = step1_scorers[name].floors()
            results["step1_in_domain"][name] = {
                **summarise(sc, f, filtered), "oracle": floor_summary(f["raw"]),
                "oracle_filtered": floor_summary(f["filtered"])}
    results["criteria"] = criteria(results)
    return results


def like_for_like(cell: dict[str, Any]) -> dict[str, float]:
    """A cell's force RMSE over the floor of the same filtering: ``raw`` (the estimate
    before any output filter over the raw oracle) and, with a filter, ``filtered`` (the
    filtered estimate over the filtered oracle)."""
    if "unfiltered_force_ratio_raw_floor" in cell:
        return {"raw": cell["unfiltered_force_ratio_raw_floor"], "filtered": cell["force_ratio"]}
    return {"raw": cell["force_ratio_raw_floor"]}


def criteria(results: dict[str, Any]) -> dict[str, Any]:
    """The paper-scale run's targets, measured like for like (:func:`like_for_like`): the
    in-domain step-1 false force within 2x the oracle floor; the best two-step configuration
    (contact force RMSE at the longest length, unseen patients under patient variation)
    within 1.5x the raw oracle floor. The verdicts read the ``raw`` pairing."""
    out: dict[str, Any] = {}
    s1 = results.get("step1_in_domain")
    if s1:
        ratios = {k: like_for_like(v) for k, v in s1.items()}
        out["step1_in_domain"] = {"ratios": ratios, "within_2x": bool(
            max(r["raw"] for r in ratios.values()) <= 2.0)}
    last = str(float(results["config"]["lengths_s"][-1]))
    two_step = {k: like_for_like(results["contact"][k][last])
                for k in ("Base+Corr", "Seal+Corr", "Seal+Xfer")}
    best = min(two_step, key=lambda k: two_step[k]["raw"])
    out["best_two_step"] = {"config": best, "ratios": two_step[best],
                            "unseen_patients": bool(results.get("patient_variation")),
                            "within_1_5x": bool(two_step[best]["raw"] <= 1.5)}
    return out


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
