"""Fine-tuning steps of the correction net on NumPy: Adam on ``Linear -> ReLU -> Linear``.

The lifelong adaptation runs rounds of a few dozen Adam steps on mini-batches of 128 rows
through a net of 126 -> 64 -> 6 units. At that size torch's per-operator dispatch, autograd
bookkeeping and optimizer wrapper cost far more than the arithmetic (most of a torch step's
time is spent outside the matrix products). The forward and backward pass of this one
architecture is a handful of matrix products, written out here; the update is torch's
``Adam`` with L2 ``weight_decay`` (Kingma and Ba 2015, as ``torch.optim.Adam`` implements it:
``g += wd * p``; bias-corrected moments; ``p -= lr / bc1 * m / (sqrt(v) / sqrt(bc2) + eps)``).
``tests/models/estimator/test_corr_finetune.py`` checks the gradients and updates against
torch autograd and ``torch.optim.Adam``.

The matrix products are NumPy's (OpenBLAS) everywhere. After :func:`use_compiled_kernels`
has returned True in a process, the element-wise rest of a step (bias, ReLU and its gradient,
the column sums, the Adam update) runs as a few numba kernels
(:mod:`~wrenchd.models.estimator.compiled_kernels`) instead of a dozen NumPy calls; they
perform NumPy's float32 operations in NumPy's order, so a fine-tuning gives the same nets bit
for bit either way (``tests/models/estimator/test_corr_finetune.py``), whenever the switch
happens.

Loss: the mean over the batch and the six joints of the squared error of the net's output
(the correction in torque-std units) against the target.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

from wrenchd.models.errors import ConfigError

#: the element-wise kernels by name, once :func:`use_compiled_kernels` has loaded them
#: (replaced whole, never changed in place: a step reads it once)
elementwise_kernels: dict | None = None


def use_compiled_kernels() -> bool:
    """Load the compiled element-wise kernels (numba's import and its disk cache: a few tenths
    of a second, seconds where nothing is cached) and use them in every step after; False where
    numba is missing or switched off (NumPy goes on serving). Safe from any thread: steps
    before the kernels are ready run on NumPy, with the same results."""
    global elementwise_kernels
    from wrenchd.models.estimator.compiled import finetune_kernels

    kernels = finetune_kernels()
    if kernels is not None:
        elementwise_kernels = kernels
    return kernels is not None


class CorrFineTuner:
    """Adam on the weights of a ``Sequential(Linear, ReLU, Linear)``, in float32.

    Args:
        net: the net to start from (not modified until :meth:`write_to`).
        lr, weight_decay, betas, eps: as ``torch.optim.Adam``.
    Raises:
        ConfigError: a net of another structure.
    """

    def __init__(self, net: nn.Sequential, lr: float, weight_decay: float = 0.0,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        layers = list(net)
        if (len(layers) != 3 or not isinstance(layers[0], nn.Linear)
                or not isinstance(layers[1], nn.ReLU) or not isinstance(layers[2], nn.Linear)
                or layers[0].bias is None or layers[2].bias is None):
            raise ConfigError("CorrFineTuner needs Sequential(Linear, ReLU, Linear) with biases")
        first, last = layers[0], layers[2]
        n_in, hidden, n_out = first.in_features, first.out_features, last.out_features
        shapes = [(n_in, hidden), (hidden,), (hidden, n_out), (n_out,)]
        sizes = [int(np.prod(sh)) for sh in shapes]
        # All parameters (and their gradients and moments) are views of one flat buffer each,
        # so an Adam update is a few operations on one array, not a few per tensor.
        self.flat = np.zeros(sum(sizes), dtype=np.float32)
        # gradient and its square, first and second moments: stacked pairs, so the two
        # moment updates are one operation each (the same float32 operations per element)
        self._g_pair = np.zeros((2, len(self.flat)), dtype=np.float32)
        self._moments = np.zeros_like(self._g_pair)
        self.grad, self.m, self.v = self._g_pair[0], self._moments[0], self._moments[1]
        offsets = np.cumsum([0] + sizes)
        self.params = [self.flat[a:b].reshape(sh) for a, b, sh in
                       zip(offsets[:-1], offsets[1:], shapes)]
        self.grads = [self.grad[a:b].reshape(sh) for a, b, sh in
                      zip(offsets[:-1], offsets[1:], shapes)]
        to_np = lambda t: t.detach().cpu().numpy()  # noqa: E731
        self.params[0][...] = to_np(first.weight).T          # stored (in, out) for x @ W
        self.params[1][...] = to_np(first.bias)
        self.params[2][...] = to_np(last.weight).T
        self.params[3][...] = to_np(last.bias)
        self.lr, self.weight_decay = float(lr), float(weight_decay)
        self.beta1, self.beta2 = betas
        self.eps = float(eps)
        self.steps = 0
        self._tmp = np.zeros_like(self.flat)          # Adam's scratch, reused every step
        self._tmp_pair = np.zeros_like(self._g_pair)
        self._denom = np.zeros_like(self.flat)
        self._decay = np.array([[betas[0]], [betas[1]]], dtype=np.float32)
        self._gain = np.array([[1.0 - betas[0]], [1.0 - betas[1]]], dtype=np.float32)
        self._ws: dict[str, np.ndarray] | None = None

    def forward(self, inp: np.ndarray) -> np.ndarray:
        """The net's output for (B, n_in) inputs."""
        w1, b1, w2, b2 = self.params
        h = inp @ w1
        h += b1
        np.maximum(h, 0.0, out=h)
        out = h @ w2
        out += b2
        return out

    def _workspace(self, batch: int) -> dict[str, np.ndarray]:
        """Intermediate arrays of one step for ``batch`` rows, allocated once per size."""
        ws = self._ws
        if ws is None or ws["z"].shape[0] != batch:
            hidden, n_out = self.params[2].shape
            ws = self._ws = {"z": np.empty((batch, hidden), np.float32),
                             "h": np.empty((batch, hidden), np.float32),
                             "active": np.empty((batch, hidden), bool),
                             "d_h": np.empty((batch, hidden), np.float32),
                             "out": np.empty((batch, n_out), np.float32)}
        return ws

    def gradients(self, inp: np.ndarray, target: np.ndarray, with_loss: bool = True
                  ) -> tuple[float | None, list[np.ndarray]]:
        """Loss (None unless ``with_loss``) and its gradients w.r.t. ``params`` (written into
        ``grads``) for (B, n_in) inputs and (B, n_out) targets."""
        w1, b1, w2, b2 = self.params
        g_w1, g_b1, g_w2, g_b2 = self.grads
        ws = self._workspace(len(inp))
        z, h, d_h, err = ws["z"], ws["h"], ws["d_h"], ws["out"]
        kernels = elementwise_kernels
        if kernels is not None and not with_loss:
            return None, self._compiled_gradients(inp, target, ws, kernels)
        np.matmul(inp, w1, out=z)
        z += b1
        np.maximum(z, 0.0, out=h)
        np.matmul(h, w2, out=err)
        err += b2
        err -= target                       # the output's error
        loss = float(np.mean(err * err)) if with_loss else None
        d_out = err
        d_out *= np.float32(2.0 / err.size)
        np.matmul(h.T, d_out, out=g_w2)
        np.sum(d_out, axis=0, out=g_b2)
        np.matmul(d_out, w2.T, out=d_h)
        active = np.greater(z, 0.0, out=ws["active"])
        d_h *= active
        np.matmul(inp.T, d_h, out=g_w1)
        np.sum(d_h, axis=0, out=g_b1)
        return loss, self.grads

    def _compiled_gradients(self, inp: np.ndarray, target: np.ndarray,
                            ws: dict[str, np.ndarray], kernels: dict) -> list[np.ndarray]:
        """:meth:`gradients` without the loss, its element-wise parts compiled."""
        w1, b1, w2, b2 = self.params
        g_w1, g_b1, g_w2, g_b2 = self.grads
        z, h, d_h, err = ws["z"], ws["h"], ws["d_h"], ws["out"]
        np.matmul(inp, w1, out=z)
        kernels["hidden_forward"](z, b1, h)
        np.matmul(h, w2, out=err)
        kernels["output_error"](err, b2, target, np.float32(2.0 / err.size), g_b2)
        np.matmul(h.T, err, out=g_w2)
        np.matmul(err, w2.T, out=d_h)
        kernels["hidden_backward"](d_h, z, g_b1)
        np.matmul(inp.T, d_h, out=g_w1)
        return self.grads

    def step(self, inp: np.ndarray, target: np.ndarray, with_loss: bool = True) -> float | None:
        """One Adam step on a mini-batch; returns the loss before the step (None unless
        ``with_loss``)."""
        inp = np.asarray(inp, dtype=np.float32)
        target = np.asarray(target, dtype=np.float32)
        loss, _ = self.gradients(inp, target, with_loss)
        self.steps += 1
        b1, b2 = self.beta1, self.beta2
        step_size = self.lr / (1.0 - b1 ** self.steps)
        root_bc2 = math.sqrt(1.0 - b2 ** self.steps)
        g, m, v, tmp, denom = self.grad, self.m, self.v, self._tmp, self._denom
        kernels = elementwise_kernels
        if kernels is not None:
            f32 = np.float32
            kernels["adam_update"](self.flat, g, m, v, f32(self.weight_decay),
                                     self._decay[0, 0], self._decay[1, 0], self._gain[0, 0],
                                     self._gain[1, 0], f32(step_size), f32(root_bc2),
                                     f32(self.eps))
            return loss
        if self.weight_decay:
            np.multiply(self.flat, np.float32(self.weight_decay), out=tmp)
            g += tmp
        np.multiply(g, g, out=self._g_pair[1])
        self._moments *= self._decay                  # m *= b1; v *= b2
        np.multiply(self._g_pair, self._gain, out=self._tmp_pair)
        self._moments += self._tmp_pair               # m += (1 - b1) g; v += (1 - b2) g^2
        np.sqrt(v, out=denom)
        denom /= root_bc2
        denom += self.eps
        np.divide(m, denom, out=denom)
        denom *= step_size
        self.flat -= denom
        return loss

    def write_to(self, net: nn.Sequential) -> None:
        """Copy the trained weights into ``net`` (same structure as the one started from)."""
        w1, b1, w2, b2 = self.params
        with torch.no_grad():
            net[0].weight.copy_(torch.from_numpy(np.ascontiguousarray(w1.T)))
            net[0].bias.copy_(torch.from_numpy(b1))
            net[2].weight.copy_(torch.from_numpy(np.ascontiguousarray(w2.T)))
            net[2].bias.copy_(torch.from_numpy(b2))
