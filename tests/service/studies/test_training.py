"""Early stopping on held-out sessions: the fits of ``wrenchd train`` and the reproduction."""

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.models.estimator.training import recipe
from wrenchd.service.studies.training import (
    TrainCommandConfig,
    fit_step1_held_out,
    fit_xfer_held_out,
    train,
)

TINY = {"window": 20, "lane_windows": 2, "batch_size": 8}


@pytest.fixture(scope="module")
def sessions():
    train = [run_scenario("free-space", 8.0, seed=s).joint_states for s in (1, 2)]
    held = [run_scenario("free-space", 6.0, seed=s).joint_states for s in (90, 91)]
    return train, held


def test_step1_scores_the_held_out_sessions_and_trains_on_every_training_sample(sessions):
    series, held = sessions
    res = fit_step1_held_out(series, held, recipe("free-space", epochs=2, **TINY))
    assert res.validation["epochs_run"] == 2 and len(res.history) == 2
    assert res.data["held_out_series"] == 2 and res.data["n_samples"] == 3200
    # the reported RMSE is the model's on the held-out sessions, not on a tail of the data
    pred = np.concatenate([res.model.predict_sequence(
        np.concatenate([s.position, s.velocity], 1)) for s in held])
    target = np.concatenate([s.effort for s in held])
    np.testing.assert_allclose(res.validation["rmse"], np.sqrt(np.mean((pred - target) ** 2, 0)),
                               rtol=1e-4)


def test_epochs_are_a_ceiling_and_patience_stops_a_run_that_no_longer_improves(sessions):
    series, held = sessions
    # a rate too small to move float32 weights: after the first epoch nothing improves
    frozen = fit_step1_held_out(series, held, recipe("free-space", epochs=10, patience=2,
                                                     lr=1e-30, **TINY))
    assert frozen.validation["epochs_run"] == 3
    moving = fit_step1_held_out(series, held, recipe("free-space", epochs=3, patience=2, **TINY))
    assert moving.validation["epochs_run"] == 3


def test_xfer_on_held_out_trocar_sessions():
    series = [run_scenario("trocar", 8.0, seed=s).joint_states for s in (1, 2)]
    held = [run_scenario("trocar", 6.0, seed=80).joint_states]
    res = fit_xfer_held_out(load_pretrained("seal"), series, held,
                            recipe("xfer", epochs=1, **TINY))
    assert res.kind == "xfer" and res.validation["epochs_run"] == 1
    assert np.isfinite(res.validation["score"])


def test_train_command_with_validation_sessions_and_patient_variation(tmp_path):
    config = TrainCommandConfig(
        configuration="base", overrides={"epochs": 1, **TINY}, output=str(tmp_path / "b.pt"),
        data=[{"scenario": "free-space-seal", "duration_s": 6, "seed": 3,
               "patient_variation": True}],
        validation=[{"scenario": "free-space-seal", "duration_s": 5, "seed": 4,
                     "patient_variation": True}])
    summary = train(config, progress=False)
    assert summary["epochs_run"] == 1
    from wrenchd.models.estimator.checkpoint import load_checkpoint

    data = load_checkpoint(tmp_path / "b.pt").data
    assert data["held_out_series"] == 1 and data["val_fraction"] is None
    seen, held = data["series"][0]["patient"], data["validation_series"][0]["patient"]
    assert seen["seal_friction"]["fc"] != held["seal_friction"]["fc"]
    with pytest.raises(ValueError, match="held-out validation sessions"):
        TrainCommandConfig(configuration="corr", base_checkpoint="pretrained:base",
                           output="x.pt", data=[{"scenario": "trocar", "duration_s": 5}],
                           validation=[{"scenario": "trocar", "duration_s": 5, "seed": 1}])
