import os
import pickle

import numpy as np
import pytest
import torch

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.checkpoint import load_checkpoint, save_checkpoint, save_result
from wrenchd.models.estimator.correction import Xfer
from wrenchd.models.estimator.estimator import TwoStepEstimator
from wrenchd.models.estimator.free_space import FreeSpaceConfig
from wrenchd.models.estimator.correction_training import fit_xfer
from wrenchd.models.estimator.free_space_training import fit_free_space
from wrenchd.models.estimator.training import RECIPES, TrainConfig, recipe


def _rmse(err):
    return np.sqrt(np.mean(err ** 2, axis=0))


def test_recipes_follow_the_paper():
    fs, corr = RECIPES["free-space"], RECIPES["corr"]
    assert (fs.epochs, fs.lr, fs.lr_halving_epochs) == (1000, 1e-3, 125)
    assert (corr.epochs, corr.lr, corr.weight_decay) == (400, 1e-3, 0.01)
    assert RECIPES["troc"] == fs                       # Troc: step 1 trained on trocar data
    assert recipe("corr", epochs=3).weight_decay == 0.01
    with pytest.raises(ConfigError):
        recipe("nope")
    with pytest.raises(ValueError):
        recipe("corr", epochs=0)


def test_free_space_training_beats_the_mean(trained_free_space):
    v = trained_free_space.validation
    ratio = np.array(v["rmse"]) / np.array(v["baseline_rmse"])
    # Every joint well below "predict the training mean"; the gravity-loaded joints far below.
    assert np.all(ratio < 0.7), ratio
    assert ratio.mean() < 0.55, ratio
    assert trained_free_space.data["n_samples"] == 12000
    assert trained_free_space.history[-1] < trained_free_space.history[0]


def test_corr_beats_step1_on_held_out_trocar_data(trained_free_space, trained_corr,
                                                  trocar_held_out):
    js = trocar_held_out.joint_states
    base = TwoStepEstimator(trained_free_space.model).predict_batch(js).external_torque
    corr = TwoStepEstimator(trained_free_space.model, trained_corr.model).predict_batch(js)
    # No contact in "trocar": the external torque is the prediction error.
    rmse_base, rmse_corr = _rmse(base), _rmse(corr.external_torque)
    scale = js.effort.std(axis=0)
    assert np.mean(rmse_corr / scale) < 0.8 * np.mean(rmse_base / scale), (rmse_base, rmse_corr)
    assert rmse_corr[2] < 0.9 * rmse_base[2]            # insertion: the seal


def test_training_is_deterministic(free_space_session):
    js = free_space_session.joint_states.slice(0, 2000)
    cfg = recipe("free-space", epochs=2, window=20, lane_windows=2, batch_size=8, seed=7)
    small = FreeSpaceConfig(hidden_size=8, seal_hidden_size=8)
    a, b = (fit_free_space([js], small, cfg) for _ in range(2))
    for (k, va), vb in zip(a.model.state_dict().items(), b.model.state_dict().values()):
        assert torch.equal(va, vb), k
    c = fit_free_space([js], small, recipe("free-space", **{**cfg.model_dump(), "seed": 8}))
    assert not torch.equal(a.model.nets[0].lstm.weight_hh_l0, c.model.nets[0].lstm.weight_hh_l0)


def test_xfer_trains_only_the_new_layers(trained_free_space, trocar_train_sessions):
    base = trained_free_space.model
    js = trocar_train_sessions[0].joint_states.slice(0, 2000)
    cfg = recipe("xfer", epochs=2, window=20, lane_windows=2, batch_size=8)
    result = fit_xfer(base, [js], config=cfg)
    assert isinstance(result.model, Xfer) and result.model.uses_base(base)
    assert result.validation["epochs_run"] == 2


def _outputs(model, x):
    if hasattr(model, "predict_sequence"):
        return model.predict_sequence(x)
    return model.correct_sequence(x, x[:, :6])


@pytest.mark.parametrize("which", ["free_space", "corr", "xfer"])
def test_checkpoint_round_trip(which, tmp_path, trained_free_space, trained_corr, models_f64,
                               free_space_session):
    js = free_space_session.joint_states
    x = np.concatenate([js.position, js.velocity], axis=1)[:300]
    model = {"free_space": trained_free_space.model, "corr": trained_corr.model,
             "xfer": models_f64[2]}[which]
    path = tmp_path / "model.pt"
    if which == "xfer":
        save_checkpoint(path, model, TrainConfig(epochs=3), {"note": "untrained"}, {"score": 1.0})
    else:
        save_result(path, trained_free_space if which == "free_space" else trained_corr)
    ckpt = load_checkpoint(path)
    assert ckpt.kind == which and type(ckpt.model) is type(model)
    assert ckpt.model.config == model.config
    np.testing.assert_array_equal(_outputs(ckpt.model, x), _outputs(model, x))
    for (k, a), b in zip(model.state_dict().items(), ckpt.model.state_dict().values()):
        assert torch.equal(a, b) and a.dtype == b.dtype, k
    if which != "xfer":
        result = trained_free_space if which == "free_space" else trained_corr
        assert ckpt.validation == result.validation and ckpt.data == result.data
        assert ckpt.train_config == result.train_config
    raw = torch.load(path, weights_only=True)
    assert isinstance(raw["config"], str) and raw["version"] == 1


class _Payload:
    """Runs a command when unpickled: what a tampered checkpoint could carry."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_tampered_checkpoints_are_refused(tmp_path, models_f64):
    fs = models_f64[0]
    good = tmp_path / "good.pt"
    save_checkpoint(good, fs)
    marker = tmp_path / "executed"
    evil = tmp_path / "evil.pt"
    with open(evil, "wb") as fh:
        pickle.dump({"format": "wrenchd.estimator", "payload": _Payload(marker)}, fh, protocol=2)
    with pytest.raises(ConfigError, match="refused"):
        load_checkpoint(evil)
    assert not marker.exists()

    not_dict = tmp_path / "list.pt"
    torch.save([1, 2, 3], not_dict)
    with pytest.raises(ConfigError, match="not a wrenchd estimator checkpoint"):
        load_checkpoint(not_dict)

    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"\x00not a checkpoint" * 10)
    with pytest.raises(ConfigError, match="refused"):
        load_checkpoint(garbage)

    payload = torch.load(good, weights_only=True)
    for change, message in (({"version": 99}, "version"), ({"kind": "nope"}, "unknown kind"),
                            ({"config": "{not json"}, "invalid"),
                            ({"state_dict": {"x": torch.zeros(1)}}, "invalid")):
        bad = tmp_path / "bad.pt"
        torch.save({**payload, **change}, bad)
        with pytest.raises(ConfigError, match=message):
            load_checkpoint(bad)
    with pytest.raises(ConfigError, match="no such"):
        load_checkpoint(tmp_path / "missing.pt")
