"""The reproduction's sessions: nested trocar training sets, held-out and test sessions.

The trocar training set of length ``L`` is ``L / segment_s`` simulated ``trocar`` sessions
(seeds ``seed + k``; a longer set holds the shorter ones). Every role has its own seeds, so
no test session is a training session, and under patient variation no test patient is a
training patient (:meth:`ReproductionSets.draws_disjoint`).
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ConfigDict

from wrenchd.adapters.sim.patients import PatientRanges
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.series import Session
from wrenchd.service.studies.reproduction_config import ReproductionConfig
from wrenchd.service.studies.reproduction_results import Patients


def _patients(config: ReproductionConfig) -> PatientRanges | None:
    return config.patient_ranges if config.patient_variation else None


def _session(config: ReproductionConfig, scenario: str, duration_s: float, seed: int,
             sensor: bool | None = None) -> Session:
    return run_scenario(scenario, duration_s, seed, patients=_patients(config),
                        handle_nm_per_rad=config.handle_nm_per_rad, force_sensor=sensor)


def training_set(config: ReproductionConfig, length_s: float) -> list[Session]:
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


def contact_trial(config: ReproductionConfig, k: int) -> Session:
    """Contact trial ``k`` (seed ``test_seed + 1000 + k``: after the no-contact ones)."""
    return _session(config, "trocar-contact", config.contact_trial_s,
                    config.test_seed + 1000 + k)


def test_sets(config: ReproductionConfig) -> tuple[list[Session], list[Session]]:
    """(no-contact trials, contact trials), seeds disjoint from every training set (the
    contact trials start 1000 seeds after the no-contact ones)."""
    s0 = config.test_seed
    sensor = True if config.sensor_on_no_contact else None
    free = [_session(config, "trocar", config.no_contact_trial_s, s0 + k, sensor)
            for k in range(config.no_contact_trials)]
    contact = [contact_trial(config, k) for k in range(config.contact_trials)]
    return free, contact


#: each step-1 model's free-motion scenario and the offset of its training sessions' seeds
STEP1 = {"Base": ("free-space", 0), "Seal": ("free-space-seal", 10000)}


def step1_training_seed(config: ReproductionConfig, name: str, k: int) -> int:
    """The seed of step-1 model ``name``'s ``k``-th training session."""
    return config.step1.seed + STEP1[name][1] + k


def step1_sets(config: ReproductionConfig, name: str) -> tuple[list[Session], list[Session]]:
    """Free-motion training and held-out sessions of step-1 model ``name`` (:data:`STEP1`)."""
    st = config.step1
    scenario = STEP1[name][0]
    n = math.ceil(st.duration_s / st.session_s - 1e-9)
    first = step1_training_seed(config, name, 0)
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
            for i, (name, (scenario, _)) in enumerate(STEP1.items())}


def _draw(session: Session) -> Any:
    return session.metadata.get("patient", {}).get("draw")


class ReproductionSets(BaseModel):
    """Every session of a run, by role."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    #: the nested trocar training sets, by length [s]
    training: dict[float, list[Session]]
    #: held-out trocar sessions (early stopping of Troc and Xfer)
    validation: list[Session]
    no_contact: list[Session]
    contact: list[Session]
    #: Base and Seal trained in the run: (training, held-out) free-motion sessions
    step1: dict[str, tuple[list[Session], list[Session]]]
    #: in-domain step-1 tests of Base and Seal
    step1_tests: dict[str, list[Session]]

    @property
    def longest(self) -> list[Session]:
        return self.training[max(self.training)]

    def draws_disjoint(self) -> bool:
        """No test session's patient equals a training session's (patient variation only)."""
        train = [s for d in self.training.values() for s in d] + self.validation + [
            s for tr, held in self.step1.values() for s in tr + held]
        test = self.no_contact + self.contact + [s for v in self.step1_tests.values()
                                                 for s in v]
        seen = [_draw(s) for s in train]
        return all(_draw(t) not in seen for t in test)

    def patients(self) -> Patients:
        """The patient draw of each training (longest set) and test session."""
        return Patients(training=[_draw(s) for s in self.longest],
                        no_contact=[_draw(s) for s in self.no_contact],
                        contact=[_draw(s) for s in self.contact])


def build_sets(config: ReproductionConfig) -> ReproductionSets:
    """Simulate every session of the run ``config`` describes."""
    free, contact = test_sets(config)
    validation = validation_set(config)
    step1 = {name: step1_sets(config, name) for name in STEP1} if config.step1 is not None else {}
    step1_tests = step1_test_sets(config) if config.step1_test_trials else {}
    training = {L: training_set(config, L) for L in config.lengths_s}
    return ReproductionSets(training=training, validation=validation, no_contact=free,
                            contact=contact, step1=step1, step1_tests=step1_tests)
