"""NumPy inference kernels: the estimator's networks advanced one sample at a time.

A torch call costs microseconds of dispatch per operator, and one streaming step of the
two-step estimator is dozens of tiny operators. These kernels are eval-mode snapshots of the
torch modules with the per-step maths fused:

* the joint-group LSTMs of one layer run as a single batched matmul
  ``[x, h] (G, B, n_in + H) @ W (G, n_in + H, 4H)``;
* the input normalisation is folded into the first layer's weights, the output
  de-normalisation into the last layer's;
* the gate columns are reordered to ``i, f, o, g`` and the sigmoid gates pre-scaled by 1/2,
  so one ``tanh`` over all 4H columns gives every gate (``sigmoid(z) = (1 + tanh(z/2)) / 2``).

Dropout is the identity (eval mode). A kernel is a snapshot: it does not follow later changes
of the module's weights; build a new one after training or loading.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch import nn

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.compiled import DEFERRED, compile_now, compiled_step

#: Recurrent state of a kernel: ``(h_1, c_1, h_2, c_2, ...)``, one pair per LSTM layer, each
#: (G, B, H) for G joint groups, batch B and hidden size H.
RecurrentState = tuple[np.ndarray, ...]


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().to(torch.float64).cpu().numpy()


class LSTMLayerKernel:
    """G single-layer LSTMs of equal size stepped together.

    Args:
        lstms: ``nn.LSTM`` modules (one layer, with biases, no projection), same sizes.
        dtype: NumPy dtype of the weights and of the arithmetic.
        in_shift, in_scale: optional (n_in,) input normalisation ``(x - shift) / scale``,
            folded into the weights.
    """

    def __init__(self, lstms: Sequence[nn.LSTM], dtype=np.float32,
                 in_shift: np.ndarray | None = None, in_scale: np.ndarray | None = None) -> None:
        sizes = {(m.input_size, m.hidden_size, m.num_layers, m.bias, m.proj_size) for m in lstms}
        if len(sizes) != 1:
            raise ConfigError(f"LSTMs of one kernel layer must match in size, got {sizes}")
        n_in, hidden, layers, bias, proj = sizes.pop()
        if layers != 1 or not bias or proj:
            raise ConfigError("kernel LSTMs must have one layer, biases and no projection")
        h = hidden
        # torch gate order i, f, g, o -> i, f, o, g; sigmoid gates scaled by 1/2.
        order = np.r_[0:2 * h, 3 * h:4 * h, 2 * h:3 * h]
        gate_scale = np.r_[np.full(3 * h, 0.5), np.ones(h)]
        weights, biases = [], []
        for m in lstms:
            w_ih, w_hh = _np(m.weight_ih_l0), _np(m.weight_hh_l0)        # (4H, n_in), (4H, H)
            b = _np(m.bias_ih_l0) + _np(m.bias_hh_l0)                    # (4H,)
            if in_scale is not None:
                w_ih = w_ih / np.asarray(in_scale, dtype=np.float64)[None, :]
                b = b - w_ih @ np.asarray(in_shift, dtype=np.float64)
            w = np.concatenate([w_ih, w_hh], axis=1).T                   # (n_in + H, 4H)
            weights.append(w[:, order] * gate_scale)
            biases.append((b[order] * gate_scale)[None, :])
        self.n_groups, self.input_size, self.hidden_size = len(lstms), n_in, h
        w = np.stack(weights)                                                # (G, n_in+H, 4H)
        self.weight = np.ascontiguousarray(w, dtype=dtype)
        self.bias = np.stack(biases).astype(dtype)                           # (G, 1, 4H)
        # For an input shared by all groups: one (n_in, G*4H) projection, then (G, H, 4H).
        self.weight_x = np.ascontiguousarray(
            w[:, :n_in, :].transpose(1, 0, 2).reshape(n_in, -1), dtype=dtype)
        self.weight_h = np.ascontiguousarray(w[:, n_in:, :], dtype=dtype)
        self.bias_flat = np.ascontiguousarray(self.bias[:, 0, :].reshape(-1), dtype=dtype)

    def step(self, x: np.ndarray, h: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One time step.

        Args:
            x: (B, n_in) input shared by every group, or (G, B, n_in) one per group.
            h, c: (G, B, H) previous hidden and cell state (not modified).
        Returns:
            new ``(h, c)``, each (G, B, H).
        """
        if x.ndim == 2:
            xp = x @ self.weight_x                                           # (B, G*4H)
            xp += self.bias_flat
            return self.step_projected(
                xp.reshape(x.shape[0], self.n_groups, -1).transpose(1, 0, 2), h, c)
        z = np.matmul(np.concatenate([x, h], axis=-1), self.weight)
        z += self.bias
        return self._gates(z, c)

    def step_projected(self, xp: np.ndarray, h: np.ndarray,
                       c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One step given the input's projection plus bias ``xp`` (G, B, 4H) (broadcastable)."""
        z = np.matmul(h, self.weight_h)                                      # (G, B, 4H)
        z += xp
        return self._gates(z, c)

    def _gates(self, z: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """New ``(h, c)`` from the pre-activations ``z`` (G, B, 4H), overwritten."""
        np.tanh(z, out=z)
        hh = self.hidden_size
        sig = z[..., :3 * hh]
        sig *= 0.5
        sig += 0.5
        c_new = z[..., hh:2 * hh] * c
        c_new += z[..., :hh] * z[..., 3 * hh:]
        h_new = np.tanh(c_new)
        h_new *= z[..., 2 * hh:3 * hh]
        return h_new, c_new


class MLPKernel:
    """A feed-forward stack of ``nn.Linear`` / ``nn.ReLU`` / ``nn.Dropout`` (identity).

    Args:
        modules: the layers in order.
        dtype: NumPy dtype.
        in_shift, in_scale: optional input normalisation ``(x - shift) / scale``, folded in.
        out_shift, out_scale: optional output de-normalisation ``y * scale + shift``, folded in.
    """

    def __init__(self, modules: Sequence[nn.Module], dtype=np.float32,
                 in_shift: np.ndarray | None = None, in_scale: np.ndarray | None = None,
                 out_shift: np.ndarray | None = None,
                 out_scale: np.ndarray | None = None) -> None:
        layers: list[list] = []                                   # [W (in, out), b (out,), relu]
        for m in modules:
            if isinstance(m, nn.Linear):
                b = _np(m.bias) if m.bias is not None else np.zeros(m.out_features)
                layers.append([_np(m.weight).T, b, False])
            elif isinstance(m, nn.ReLU):
                if not layers:
                    raise ConfigError("an MLP kernel cannot start with a ReLU")
                layers[-1][2] = True
            elif not isinstance(m, (nn.Dropout, nn.Identity)):
                raise ConfigError(f"MLP kernel does not support {type(m).__name__}")
        self._fold(layers, dtype, in_shift, in_scale, out_shift, out_scale)

    @classmethod
    def from_arrays(cls, layers: Sequence[tuple[np.ndarray, np.ndarray, bool]], dtype=np.float32,
                    in_shift: np.ndarray | None = None, in_scale: np.ndarray | None = None,
                    out_shift: np.ndarray | None = None,
                    out_scale: np.ndarray | None = None) -> MLPKernel:
        """The same kernel from ``(weight (out, in), bias (out,), relu after)`` arrays, as
        ``nn.Linear`` stores them: no torch modules needed (a process that receives trained
        weights builds its kernel with NumPy alone)."""
        kernel = cls.__new__(cls)
        kernel._fold([[np.asarray(w, dtype=np.float64).T, np.asarray(b, dtype=np.float64), relu]
                      for w, b, relu in layers], dtype, in_shift, in_scale, out_shift, out_scale)
        return kernel

    def _fold(self, layers: list[list], dtype, in_shift, in_scale, out_shift, out_scale) -> None:
        """Fold the normalisation into float64 ``[W (in, out), b, relu]`` layers and keep them
        in ``dtype``."""
        if not layers:
            raise ConfigError("an MLP kernel needs at least one Linear layer")
        if in_scale is not None:
            w, b, _ = layers[0]
            w = w / np.asarray(in_scale, dtype=np.float64)[:, None]
            layers[0][:2] = [w, b - np.asarray(in_shift, dtype=np.float64) @ w]
        if out_scale is not None:
            w, b, _ = layers[-1]
            scale = np.asarray(out_scale, dtype=np.float64)
            shift = np.asarray(out_shift, dtype=np.float64)
            layers[-1][:2] = [w * scale[None, :], b * scale + shift]
        self.layers = [(np.ascontiguousarray(w, dtype=dtype), b.astype(dtype), relu)
                       for w, b, relu in layers]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """(B, n_in) -> (B, n_out)."""
        for w, b, relu in self.layers:
            x = x @ w
            x += b
            if relu:
                np.maximum(x, 0.0, out=x)
        return x


class GroupedRecurrentKernel:
    """Stacked grouped LSTM layers followed by one output head per group.

    Each head is a trunk (its layers but the last) and a final linear layer; the final layers
    of all groups run as one block-diagonal matmul over the concatenated trunk outputs, so the
    outputs come out in group order (the groups are contiguous joints in order: joint order).
    """

    def __init__(self, layers: Sequence[LSTMLayerKernel], heads: Sequence[MLPKernel],
                 dtype=np.float32) -> None:
        if any(layer.n_groups != len(heads) for layer in layers):
            raise ConfigError("every kernel layer needs one group per head")
        self.layers, self.dtype = list(layers), np.dtype(dtype)
        self.trunks: list[list] = []
        finals = []
        for head in heads:
            *trunk, final = head.layers
            if final[2]:
                raise ConfigError("a head must end with a linear layer (no ReLU)")
            self.trunks.append(trunk)
            finals.append(final)
        n_in = sum(w.shape[0] for w, _, _ in finals)
        n_out = sum(w.shape[1] for w, _, _ in finals)
        block = np.zeros((n_in, n_out), dtype=self.dtype)
        r = c = 0
        for w, _, _ in finals:
            block[r:r + w.shape[0], c:c + w.shape[1]] = w
            r, c = r + w.shape[0], c + w.shape[1]
        self.final_weight = block
        self.final_bias = np.concatenate([b for _, b, _ in finals]).astype(self.dtype)
        # the step compiled with numba where it is installed (compiled.py), now or on first use
        self._compiled = compiled_step(self) if compile_now() else DEFERRED

    def __getstate__(self) -> dict:
        # the compiled step stays in its process: the receiver builds its own
        return {k: v for k, v in self.__dict__.items() if k != "_compiled"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._compiled = compiled_step(self) if compile_now() else DEFERRED

    def initial_state(self, batch: int = 1) -> RecurrentState:
        """Zero state for ``batch`` parallel streams."""
        state: list[np.ndarray] = []
        for layer in self.layers:
            shape = (layer.n_groups, batch, layer.hidden_size)
            state += [np.zeros(shape, self.dtype), np.zeros(shape, self.dtype)]
        return tuple(state)

    def step(self, x: np.ndarray, state: RecurrentState) -> tuple[np.ndarray, RecurrentState]:
        """One sample: (B, n_in) raw inputs -> ((B, n_out) outputs, new state)."""
        compiled = self._compiled
        if compiled is DEFERRED:
            compiled = self._compiled = compiled_step(self)
        if compiled is not None:
            return compiled(x, state)
        new: list[np.ndarray] = []
        inp = x.astype(self.dtype, copy=False)
        for k, layer in enumerate(self.layers):
            h, c = layer.step(inp, state[2 * k], state[2 * k + 1])
            new += [h, c]
            inp = h
        return self.head(inp), tuple(new)

    def head(self, top: np.ndarray) -> np.ndarray:
        """The output heads on the last layer's hidden states: (G, B, H) -> (B, n_out)."""
        feats = []
        for g, trunk in enumerate(self.trunks):
            f = top[g]
            for w, b, relu in trunk:
                f = f @ w
                f += b
                if relu:
                    np.maximum(f, 0.0, out=f)
            feats.append(f)
        y = np.concatenate(feats, axis=-1) @ self.final_weight
        y += self.final_bias
        return y

    def run(self, x: np.ndarray, state: RecurrentState) -> tuple[np.ndarray, RecurrentState]:
        """A sequence of one stream: (T, n_in) raw inputs -> ((T, n_out) outputs, new state).

        The same numbers as T calls of :meth:`step` up to float32 rounding (the first layer's
        input projection and the heads run as one matmul over the sequence, the recurrence
        step by step): the daemon estimates a backlog of samples this way.
        """
        steps = len(x)
        seq = x.astype(self.dtype, copy=False)
        new: list[np.ndarray] = []
        for k, layer in enumerate(self.layers):
            h, c = state[2 * k], state[2 * k + 1]
            out = np.empty((steps, layer.n_groups, h.shape[1], layer.hidden_size), self.dtype)
            if k == 0:                          # one (T, G*4H) projection of the shared input
                proj = seq @ layer.weight_x
                proj += layer.bias_flat
                proj = proj.reshape(steps, layer.n_groups, 1, -1)
                for i in range(steps):
                    h, c = layer.step_projected(proj[i], h, c)
                    out[i] = h
            else:
                for i in range(steps):
                    h, c = layer.step(seq[i], h, c)
                    out[i] = h
            new += [h, c]
            seq = out
        top = seq[:, :, 0, :].transpose(1, 0, 2)                     # (G, T, H)
        return self.head(top), tuple(new)


class RecurrentStream:
    """A kernel with its state: ``step(x) -> y`` sample by sample, ``reset_state()``."""

    def __init__(self, kernel: GroupedRecurrentKernel) -> None:
        self.kernel = kernel
        self.reset_state()

    def reset_state(self) -> None:
        """Forget the past: the next step starts from the zero state."""
        self.state = self.kernel.initial_state(1)

    def step(self, x: np.ndarray) -> np.ndarray:
        """(n_in,) raw input -> (n_out,) output; advances the stored state."""
        y, self.state = self.kernel.step(np.asarray(x)[None, :], self.state)
        return y[0]
