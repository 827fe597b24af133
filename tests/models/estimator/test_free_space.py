import copy

import numpy as np
import pytest
import torch
from torch import nn

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.free_space import JOINT_GROUPS, FreeSpaceConfig, FreeSpaceModel
from wrenchd.models.estimator.kernels import RecurrentStream


def _features(session, n=None):
    js = session.joint_states
    x = np.concatenate([js.position, js.velocity], axis=1)
    return x if n is None else x[:n]


def test_structure_follows_the_paper():
    m = FreeSpaceModel()
    assert m.groups == JOINT_GROUPS == ((0, 1), (2,), (3,), (4, 5))
    for k, net in enumerate(m.nets):
        assert net.lstm.hidden_size == 128 and net.lstm.input_size == 12
        kinds = [type(layer) for layer in net.head]
        if k == 1:                     # joint 3: extra hidden layer, ReLU, dropout
            assert kinds == [nn.Linear, nn.ReLU, nn.Dropout, nn.Linear]
            assert net.head[0].out_features == 128
        else:
            assert kinds == [nn.Linear]
        assert net.head[-1].out_features == len(m.groups[k])
    assert m(torch.zeros(2, 7, 12)).shape == (2, 7, 6)


def test_config_rejects_groups_that_do_not_partition_the_joints():
    with pytest.raises(ValueError):
        FreeSpaceConfig(groups=((0, 1), (3,), (2,), (4, 5)))
    with pytest.raises(ValueError):
        FreeSpaceConfig(groups=((0, 1, 2),))


def test_streaming_equals_sequence_float64(models_f64, free_space_session):
    fs = models_f64[0]
    x = _features(free_space_session, 400)
    seq = fs.predict_sequence(x)
    state, out = None, []
    for xi in x:
        y, state = fs.step(xi, state)
        out.append(y)
    np.testing.assert_allclose(np.array(out), seq, rtol=0, atol=1e-11)
    assert np.abs(seq).max() > 0.1          # a non-trivial output, not zeros on both sides


def test_streaming_equals_sequence_float32(models_f32, free_space_session):
    fs = models_f32[0]
    x = _features(free_space_session, 400)
    seq = fs.predict_sequence(x)
    stream = RecurrentStream(fs.kernel())
    out = np.array([stream.step(xi) for xi in x])
    np.testing.assert_allclose(out, seq, rtol=0, atol=2e-5 * np.abs(seq).max())


def test_batched_step_runs_independent_streams(models_f64, free_space_session):
    fs = models_f64[0]
    x = _features(free_space_session, 60)
    a, b = x[:30], x[30:]
    state = None
    for xa, xb in zip(a, b):
        y, state = fs.step(np.stack([xa, xb]), state)
    np.testing.assert_allclose(y[0], fs.predict_sequence(a)[-1], atol=1e-11)
    np.testing.assert_allclose(y[1], fs.predict_sequence(b)[-1], atol=1e-11)


def test_step_is_pure_and_reset_restarts(models_f64, free_space_session):
    fs = models_f64[0]
    x = _features(free_space_session, 20)
    _, state = fs.step(x[0])
    before = [s.copy() for s in state]
    y1, _ = fs.step(x[1], state)
    y2, _ = fs.step(x[1], state)
    assert all(np.array_equal(a, b) for a, b in zip(before, state))
    np.testing.assert_array_equal(y1, y2)
    stream = RecurrentStream(fs.kernel())
    first = [stream.step(xi) for xi in x]
    stream.reset_state()
    again = [stream.step(xi) for xi in x]
    np.testing.assert_array_equal(np.array(first), np.array(again))


def test_step_follows_weight_changes(models_f64, free_space_session):
    fs = copy.deepcopy(models_f64[0])
    x = _features(free_space_session, 1)[0]
    y_old, _ = fs.step(x)
    with torch.no_grad():
        fs.nets[0].head[-1].bias.add_(1.0)           # +1 normalised unit on joints 1 and 2
    y_new, _ = fs.step(x)
    np.testing.assert_allclose(y_new[:2] - y_old[:2], fs.out_std[:2].numpy(), rtol=1e-9)
    np.testing.assert_array_equal(y_new[2:], y_old[2:])


def test_step_ignores_dropout_even_in_train_mode(models_f64, free_space_session):
    fs = copy.deepcopy(models_f64[0]).train()
    x = _features(free_space_session, 50)
    state, out = None, []
    for xi in x:
        y, state = fs.step(xi, state)
        out.append(y)
    np.testing.assert_allclose(np.array(out), fs.predict_sequence(x), atol=1e-11)
    assert fs.training                               # predict_sequence restores the mode


def test_bad_shapes_raise():
    fs = FreeSpaceModel()
    with pytest.raises(DataError):
        fs.step(np.zeros(11))
    with pytest.raises(DataError):
        fs(torch.zeros(3, 12))
