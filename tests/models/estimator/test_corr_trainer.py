"""The Corr fine-tuning API used by fit_corr and by lifelong adaptation."""

import numpy as np
import pytest
import torch

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.correction import Corr
from wrenchd.models.estimator.correction_training import (
    CorrTrainer,
    corr_inputs,
    fit_corr,
    predict_segments,
)
from wrenchd.models.estimator.training import recipe


def test_batched_step1_equals_one_segment_at_a_time(trained_free_space, trocar_train_sessions):
    model = trained_free_space.model
    xs = [np.c_[s.joint_states.position, s.joint_states.velocity][:n]
          for s, n in zip(trocar_train_sessions[:3], (700, 250, 1000))]
    for got, x in zip(predict_segments(model, xs), xs):
        np.testing.assert_allclose(got, model.predict_sequence(x), rtol=1e-5, atol=1e-6)


def test_steps_fit_a_new_seal_and_keep_the_optimiser(trained_free_space, trocar_train_sessions):
    base = trained_free_space.model
    js = [s.joint_states for s in trocar_train_sessions[:4]]
    xs = [np.c_[j.position, j.velocity] for j in js]
    windows, step1 = corr_inputs(base, xs, 10)
    measured = np.concatenate([j.effort for j in js])
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        corr = Corr()
    corr.set_normalisation(np.concatenate(xs), step1)
    trainer = CorrTrainer(corr, recipe("corr-fast"))

    def rmse():
        with torch.no_grad():
            pred = corr(torch.as_tensor(windows, dtype=torch.float32),
                        torch.as_tensor(step1, dtype=torch.float32)).double().numpy()
        return np.sqrt(np.mean((pred - measured) ** 2, 0)) / measured.std(0)

    before = rmse()
    first = trainer.steps(windows, step1, measured, 40)
    second = trainer.steps(windows, step1, measured, 40)
    after = rmse()
    assert second < first                               # the optimiser state carries over
    assert after.mean() < 0.8 * before.mean(), (before, after)
    assert not corr.training
    with pytest.raises(DataError):
        trainer.steps(windows[:5], step1, measured, 1)


def test_sample_stride_rotates_over_the_data(trained_free_space, trocar_train_sessions):
    js = [s.joint_states for s in trocar_train_sessions[:2]]
    fast = fit_corr(trained_free_space.model, js, config=recipe("corr-fast", epochs=4))
    assert fast.validation["epochs_run"] == 4 and fast.train_config.sample_stride == 4
    assert fast.history[-1] < fast.history[0]
