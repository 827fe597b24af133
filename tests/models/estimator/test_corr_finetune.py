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
