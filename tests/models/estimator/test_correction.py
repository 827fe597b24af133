import copy

import numpy as np
import pytest
import torch

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.correction import Corr, CorrKernel, HistoryWindow, Xfer, XferConfig
from wrenchd.models.estimator.features import history_windows
from wrenchd.models.estimator.free_space import FreeSpaceConfig, FreeSpaceModel
from wrenchd.models.estimator.kernels import RecurrentStream


def _features(session, n):
    js = session.joint_states
    return np.concatenate([js.position, js.velocity], axis=1)[:n], js.effort[:n]


def test_corr_structure_follows_the_paper():
    corr = Corr()
    assert corr.window == 10
    first, relu, last = corr.net
    assert first.in_features == 10 * 12 + 6 and first.out_features == 256
    assert isinstance(relu, torch.nn.ReLU) and last.out_features == 6


def test_history_window_matches_batch_windows():
    x = np.random.default_rng(0).normal(size=(25, 12))
    ring = HistoryWindow(10)
    streamed = np.array([ring.push(xi).copy() for xi in x])
    np.testing.assert_array_equal(streamed, history_windows(x, 10))
    np.testing.assert_array_equal(streamed[0], np.repeat(x[:1], 10, axis=0))
    ring.reset()
    np.testing.assert_array_equal(ring.push(x[5]), np.repeat(x[5:6], 10, axis=0))


def test_corr_adds_its_output_to_the_step1_prediction(models_f64, free_space_session):
    corr = models_f64[1]
    x, tau = _features(free_space_session, 50)
    w = torch.as_tensor(history_windows(x, 10))
    s = torch.as_tensor(tau)
    with torch.no_grad():
        delta = corr.correction_normalised(w, s) * corr.tau_std
        np.testing.assert_allclose(corr(w, s).numpy(), (s + delta).numpy(), atol=1e-12)
    with pytest.raises(DataError):
        corr.correction_normalised(w[:, :5], s)


@pytest.mark.parametrize("fixture,atol", [("models_f64", 1e-11), ("models_f32", 1e-5)])
def test_corr_kernel_streaming_equals_sequence(fixture, atol, request, free_space_session):
    corr = request.getfixturevalue(fixture)[1]
    x, tau = _features(free_space_session, 200)
    seq = corr.correct_sequence(x, tau)
    kernel, ring = corr.kernel(), HistoryWindow(corr.window)
    out = np.array([kernel.correct(ring.push(xi)[None], ti[None])[0] for xi, ti in zip(x, tau)])
    np.testing.assert_allclose(out, seq, rtol=0, atol=atol * max(1.0, np.abs(seq).max()))


def test_xfer_copies_and_freezes_the_step1_lstms(models_f64):
    fs = models_f64[0]
    xfer = Xfer(base=fs)
    assert xfer.uses_base(fs)
    for net, base_net in zip(xfer.nets, fs.nets):
        assert all(not p.requires_grad for p in net.base_lstm.parameters())
        assert net.lstm.input_size == 128 and net.lstm.hidden_size == 128
    trainable = {id(p) for p in xfer.trainable_parameters()}
    assert all(id(p) not in trainable for net in xfer.nets for p in net.base_lstm.parameters())
    # One optimiser step leaves the frozen layers as they were.
    before = copy.deepcopy([net.base_lstm.state_dict() for net in xfer.nets])
    opt = torch.optim.Adam(xfer.trainable_parameters(), lr=1e-2)
    xfer(torch.randn(2, 20, 12, dtype=torch.float64)).pow(2).mean().backward()
    opt.step()
    for net, state in zip(xfer.nets, before):
        for k, v in net.base_lstm.state_dict().items():
            assert torch.equal(v, state[k])
    assert xfer.uses_base(fs)


def test_xfer_rejects_a_mismatched_base():
    base = FreeSpaceModel(FreeSpaceConfig(hidden_size=16))
    with pytest.raises(ConfigError):
        Xfer(XferConfig(), base=base)
    assert not Xfer(XferConfig.for_base(base), base=base).uses_base(FreeSpaceModel())


def test_xfer_streaming_equals_sequence(models_f64, free_space_session):
    xfer = models_f64[2]
    x, _ = _features(free_space_session, 300)
    seq = xfer.predict_sequence(x)
    stream = RecurrentStream(xfer.kernel())
    out = np.array([stream.step(xi) for xi in x])
    np.testing.assert_allclose(out, seq, rtol=0, atol=1e-11)


def test_corr_kernel_from_a_state_dict_equals_the_modules_kernel(free_space_session):
    """The adaptation worker builds the serving kernel from NumPy weights alone; it must be
    the kernel the torch module gives, to the bit, and the module rebuilt from the same
    state must predict the same."""
    torch.manual_seed(3)
    corr = Corr()
    x, tau = _features(free_space_session, 40)
    corr.set_normalisation(x, tau)
    state = {k: v.detach().numpy().copy() for k, v in corr.state_dict().items()}
    from_module, from_state = corr.kernel(), CorrKernel.from_state(state, corr.window)
    assert from_state.dtype == np.float32 and from_state.window == corr.window
    for (w1, b1, r1), (w2, b2, r2) in zip(from_module.mlp.layers, from_state.mlp.layers):
        np.testing.assert_array_equal(w1, w2)
        np.testing.assert_array_equal(b1, b2)
        assert r1 == r2
    windows, step1 = history_windows(x, 10), tau
    np.testing.assert_array_equal(from_module.correct(windows, step1),
                                  from_state.correct(windows, step1))
    rebuilt = Corr.from_state(corr.config, state)
    with torch.no_grad():
        np.testing.assert_array_equal(
            rebuilt(torch.as_tensor(windows, dtype=torch.float32),
                    torch.as_tensor(step1, dtype=torch.float32)).numpy(),
            corr(torch.as_tensor(windows, dtype=torch.float32),
                 torch.as_tensor(step1, dtype=torch.float32)).numpy())
    assert not rebuilt.training
