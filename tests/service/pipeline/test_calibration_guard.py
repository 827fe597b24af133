"""The calibration guard: contacts during the calibration never train (issue 4).

Short real replays of the simulator (24 s, calibration 20 s, the pipeline's default gate and
guard). ``trocar-contact`` seed 3 touches the handle from 1.6 s to 4.9 s and from 13.2 s to
17.2 s (36 % of its first 20 s): without the guard, every one of those samples trained.
``insufflation-change`` seed 3 is contact-free for 60 s: the guard must leave most of its
calibration to the correction net and raise no alarm.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.models.errors import ConfigError
from wrenchd.service.pipeline import ArmPipeline, CalibrationGuardConfig, PipelineConfig
from wrenchd.service.replay.loop import replay

DURATION_S, CALIBRATION_S = 24.0, 20.0


@lru_cache(maxsize=None)
def _session(scenario: str, seed: int):
    return run_scenario(scenario, DURATION_S, seed)


@lru_cache(maxsize=None)
def _replay(scenario: str, seed: int, action: str | None):
    """Replay with the guard's ``action`` (None: no guard)."""
    guard = (CalibrationGuardConfig(enabled=False) if action is None
             else CalibrationGuardConfig(action=action))
    config = PipelineConfig(calibration_s=CALIBRATION_S, calibration_guard=guard)
    return replay(_session(scenario, seed), load_pretrained("seal"), config,
                  adaptation="inline")


def _offered_in_contact(scenario: str, seed: int, action: str | None) -> tuple[int, int]:
    """(offered samples truly in contact, of them during the calibration)."""
    session, result = _session(scenario, seed), _replay(scenario, seed, action)
    rows = np.searchsorted(session.joint_states.t, result.offered_t)
    bad = session.truth.in_contact[rows]
    return int(bad.sum()), int(bad[result.offered_t < CALIBRATION_S].sum())


def test_without_the_guard_contact_trains_during_calibration():
    # the failure the guard is for, on this very session (so the next test can fail)
    total, calibrating = _offered_in_contact("trocar-contact", 3, None)
    assert calibrating > 500


def test_warning_guard_changes_nothing_it_only_counts():
    warned, plain = _replay("trocar-contact", 3, "warn"), _replay("trocar-contact", 3, None)
    np.testing.assert_array_equal(warned.offered_t, plain.offered_t)
    np.testing.assert_array_equal(warned.wrench, plain.wrench)
    np.testing.assert_array_equal(warned.free, plain.free)
    assert plain.status["counters"]["calibration_contact"] == 0
    assert warned.status["counters"]["calibration_contact"] > 0


def test_refusing_guard_keeps_calibration_contacts_out_of_training():
    total, calibrating = _offered_in_contact("trocar-contact", 3, "refuse")
    assert calibrating == 0
    result = _replay("trocar-contact", 3, "refuse")
    assert len(result.offered_t[result.offered_t < CALIBRATION_S]) > 1000   # still calibrates
    counters = result.status["counters"]
    # the guard called contact at least the contact time (7.3 s of 20 s at 200 Hz)
    assert counters["calibration_samples"] == int(CALIBRATION_S * 200)
    assert counters["calibration_contact"] > 0.3 * counters["calibration_samples"]


@pytest.mark.parametrize("action", ["warn", "refuse"])
def test_contaminated_calibration_is_reported(action):
    result = _replay("trocar-contact", 3, action)
    kinds = [e.kind for e in result.events]
    assert "calibration_contaminated" in kinds
    event = next(e for e in result.events if e.kind == "calibration_contaminated")
    assert event.t == pytest.approx(CALIBRATION_S, abs=0.01)
    assert event.detail["fraction"] > 0.3
    assert result.status["calibration"] == {"guard": True, "contaminated": True}


def test_contact_free_calibration_is_left_to_train():
    result = _replay("insufflation-change", 3, "refuse")
    assert "calibration_contaminated" not in [e.kind for e in result.events]
    assert result.status["calibration"] == {"guard": True, "contaminated": False}
    calibrating = result.offered_t < CALIBRATION_S
    # measured 0.7-0.85 of a contact-free calibration stays trainable (2.5 s delay line
    # besides); half is the floor that still lets the correction net calibrate
    assert calibrating.sum() > 0.5 * CALIBRATION_S * 200


def test_guard_scale_comes_from_the_step1_checkpoint():
    seal = load_pretrained("seal")
    assert len(seal.validation_rmse) == 6
    assert ArmPipeline("PSM1", seal, PipelineConfig()).guard is not None
    off = PipelineConfig(calibration_guard=CalibrationGuardConfig(enabled=False))
    assert ArmPipeline("PSM1", seal, off).guard is None
    assert ArmPipeline("PSM1", seal, PipelineConfig(calibration_s=0)).guard is None
    with pytest.raises(ConfigError):
        ArmPipeline("PSM1", seal, PipelineConfig(
            calibration_guard=CalibrationGuardConfig(residual_scale=(0.1, 0.1))))
