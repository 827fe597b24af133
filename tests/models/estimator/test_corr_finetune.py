"""The NumPy fine-tuning steps of the correction net equal torch autograd + torch.optim.Adam."""

import numpy as np
import pytest
import torch
from torch import nn

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.corr_finetune import CorrFineTuner


def _net(seed: int = 0) -> nn.Sequential:
    torch.manual_seed(seed)
    return nn.Sequential(nn.Linear(126, 64), nn.ReLU(), nn.Linear(64, 6))


def _batches(n: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    return [(rng.normal(0, 1, (128, 126)).astype(np.float32),
             rng.normal(0, 0.3, (128, 6)).astype(np.float32)) for _ in range(n)]


def test_gradients_match_autograd():
    net = _net()
    inp, target = _batches(1)[0]
    loss, grads = CorrFineTuner(net, lr=1e-3).gradients(inp, target)
    out = net(torch.from_numpy(inp))
    ref = torch.mean((out - torch.from_numpy(target)) ** 2)
    ref.backward()
    assert loss == pytest.approx(float(ref.detach()), rel=1e-5)
    expected = [net[0].weight.grad.T, net[0].bias.grad, net[2].weight.grad.T, net[2].bias.grad]
    for g, e in zip(grads, expected):
        np.testing.assert_allclose(g, e.numpy(), rtol=1e-4, atol=1e-7)


def test_adam_steps_match_torch_adam_with_weight_decay():
    ours, ref = _net(), _net()
    tuner = CorrFineTuner(ours, lr=2e-3, weight_decay=0.01)
    opt = torch.optim.Adam(ref.parameters(), lr=2e-3, weight_decay=0.01)
    for inp, target in _batches(30):
        tuner.step(inp, target)
        loss = torch.mean((ref(torch.from_numpy(inp)) - torch.from_numpy(target)) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
    tuner.write_to(ours)
    for a, b in zip(ours.parameters(), ref.parameters()):
        np.testing.assert_allclose(a.detach().numpy(), b.detach().numpy(), rtol=0, atol=2e-5)
    # and the steps did something: the weights moved well beyond that tolerance
    assert np.abs(ours[0].weight.detach().numpy() - _net()[0].weight.detach().numpy()).max() > 1e-2


def test_other_structures_are_refused():
    with pytest.raises(ConfigError):
        CorrFineTuner(nn.Sequential(nn.Linear(3, 4), nn.Tanh(), nn.Linear(4, 2)), lr=1e-3)


@pytest.fixture
def compiled_steps(monkeypatch):
    """The compiled element-wise kernels, loaded; the module's switch off again after."""
    pytest.importorskip("numba")
    from wrenchd.models.estimator import corr_finetune

    monkeypatch.setattr(corr_finetune, "elementwise_kernels", None)
    assert corr_finetune.use_compiled_kernels()
    return corr_finetune.elementwise_kernels


@pytest.mark.parametrize("weight_decay", [0.0, 0.01])
@pytest.mark.parametrize("rows", [128, 37])
def test_compiled_steps_give_numpy_s_nets_bit_for_bit(compiled_steps, weight_decay, rows):
    """Two tuners from one net, one on NumPy, one compiled, through 200 steps: the same
    weights, moments and gradients to the last bit, not merely close (adaptation is chaotic
    in float32: a last-bit difference grows into another net within a round)."""
    from wrenchd.models.estimator import corr_finetune

    kernels = compiled_steps
    rng = np.random.default_rng(rows)
    on_numpy = CorrFineTuner(_net(), lr=2e-3, weight_decay=weight_decay)
    compiled = CorrFineTuner(_net(), lr=2e-3, weight_decay=weight_decay)
    for _ in range(200):
        inp = rng.normal(0, 1, (rows, 126)).astype(np.float32)
        target = rng.normal(0, 0.3, (rows, 6)).astype(np.float32)
        corr_finetune.elementwise_kernels = None
        on_numpy.step(inp, target, with_loss=False)
        corr_finetune.elementwise_kernels = kernels
        compiled.step(inp, target, with_loss=False)
    for a, b in ((on_numpy.flat, compiled.flat), (on_numpy.m, compiled.m),
                 (on_numpy.v, compiled.v), (on_numpy.grad, compiled.grad)):
        assert a.tobytes() == b.tobytes()
    assert compiled.steps == 200


def test_a_step_asked_for_its_loss_runs_on_numpy_and_agrees(compiled_steps):
    inp, target = _batches(1)[0]
    loss, _ = CorrFineTuner(_net(), lr=1e-3).gradients(inp, target)
    expected = float(np.mean((CorrFineTuner(_net(), lr=1e-3).forward(inp) - target) ** 2))
    assert loss == pytest.approx(expected, rel=1e-6)


def test_without_numba_the_switch_says_so_and_numpy_serves(monkeypatch):
    from wrenchd.models.estimator import compiled, corr_finetune

    monkeypatch.setattr(corr_finetune, "elementwise_kernels", None)
    monkeypatch.setenv(compiled.ENV, "0")
    assert corr_finetune.use_compiled_kernels() is False
    assert corr_finetune.elementwise_kernels is None
