"""The streaming step-1 kernel compiled with numba, where numba is installed.

One streaming step of the joint-group LSTMs is a few dozen NumPy calls on small arrays: their
dispatch costs more than the arithmetic, which is bound by reading the weights (about 1 MB
in float32). :func:`compiled_step` fuses a
:class:`~wrenchd.models.estimator.kernels.GroupedRecurrentKernel`'s step (every LSTM layer,
the gates, the output heads) into one compiled call, for one stream or a batch of them
(the arms of a daemon).

Numerics: float32 throughout, as the NumPy kernel; the sums run in another order and
``tanh`` is a rational approximation (the minimax form Eigen uses for float32, its
coefficients below; at most 6 units in the last place off ``tanh`` in float64, NumPy's float32
``tanh`` at most 2). Outputs agree with the NumPy kernel to float32 rounding (about 1e-6
relative), not bit for bit; every path that must agree bit for bit with the streaming
estimator calls the same kernel.

numba is optional: without it, or with ``WRENCHD_NUMBA=0`` in the environment, every kernel
runs on NumPy (:func:`compiled_step` returns None); so it does, with a warning, where numba
cannot compile or cache them (``NUMBA_CACHE_DIR`` names a writable cache; the systemd unit
sets one). Compiled functions are cached on disk
(numba's ``cache=True``) and compiled at most once per process, when the first kernel is
built (seconds without the cache), not on the first sample served. Inside
:func:`deferred_compilation` (a replay: most of its kernels never stream) kernels are built
without their compiled form and compile on first use instead (:data:`DEFERRED`).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import warnings
from collections.abc import Iterator
from typing import Any, Callable

import numpy as np

from wrenchd.models.estimator.features import N_FEATURES

#: environment variable: ``0`` keeps the NumPy kernels even where numba is installed
ENV = "WRENCHD_NUMBA"

_compiled: dict[str, Any] = {}

#: a kernel's compiled form not built yet: built on the kernel's first use
DEFERRED = object()
_deferring = [0]            # how many deferred_compilation blocks are open in this process


@contextlib.contextmanager
def deferred_compilation() -> Iterator[None]:
    """Kernels built while the block is open (in this process, by any thread) compile on
    first use, not when built: a process that builds kernels it may never stream with (a
    replay, whose step 1 runs in batches and whose correction nets arrive with every
    accepted round) does not pay numba's import and cache load for them."""
    _deferring[0] += 1
    try:
        yield
    finally:
        _deferring[0] -= 1


def compile_now() -> bool:
    """Whether a kernel built now builds its compiled form now (no
    :func:`deferred_compilation` block open)."""
    return not _deferring[0]


def numba_wanted() -> bool:
    """Whether the compiled kernels may be used (not switched off by :data:`ENV`)."""
    return os.environ.get(ENV, "1").strip() not in ("0", "false", "no", "off")


def _numba():
    if not numba_wanted():
        return None
    try:
        import numba
    except ImportError:
        return None
    return numba


def kernels_in_use() -> str:
    """``"numba"`` where float32 kernels are compiled in this process, else ``"numpy"``."""
    return "numba" if _kernels() is not None else "numpy"


def _kernels() -> dict[str, Callable] | None:
    numba = _numba()
    if numba is None:
        return None
    if not _compiled:                    # a race only imports the module twice
        kernels = _import_kernels(numba)
        if kernels is None:
            return None
        _compiled.update(layer=kernels.layer_step, heads=kernels.heads_step,
                         one_layer=kernels.one_layer_step, mlp2=kernels.mlp2_residual)
    return _compiled


#: the element-wise kernels of the correction net's fine-tuning
FINETUNE_KERNELS = ("hidden_forward", "output_error", "hidden_backward", "adam_update")


def finetune_kernels() -> dict[str, Callable] | None:
    """The fine-tuning's element-wise kernels (:data:`FINETUNE_KERNELS`), each called once
    on a few elements so that it is compiled or read from numba's cache now; None where
    numba is missing, switched off or fails here (NumPy serves)."""
    kernels = _kernels()
    if kernels is None:
        return None
    from wrenchd.models.estimator import compiled_kernels as ck

    f32 = np.float32
    one, row = np.ones((1, 2), f32), np.ones(2, f32)
    try:
        ck.hidden_forward(one.copy(), row, one.copy())
        ck.output_error(one.copy(), row, one, f32(1.0), row.copy())
        ck.hidden_backward(one.copy(), one, row.copy())
        ck.adam_update(row.copy(), row.copy(), row.copy(), row.copy(), *([f32(0.5)] * 8))
    except Exception as exc:  # noqa: BLE001 - the NumPy kernels serve instead
        warnings.warn(f"compiled kernels unavailable, NumPy serves: {exc}", RuntimeWarning)
        return None
    return {name: getattr(ck, name) for name in FINETUNE_KERNELS}


#: the hybrid step 1's streaming kernels (models/estimator/hybrid.py)
HYBRID_KERNELS = ("hybrid_motion", "hybrid_combine")


def hybrid_kernels() -> dict[str, Callable] | None:
    """The hybrid step 1's streaming kernels (:data:`HYBRID_KERNELS`), each called once on one
    stream so that it is compiled or read from numba's cache now; None where numba is
    missing, switched off or fails here (NumPy serves)."""
    if _kernels() is None:
        return None
    from wrenchd.models.estimator import compiled_kernels as ck

    row, one = np.zeros((1, 6)), np.ones(6)
    try:
        ck.hybrid_motion(row, row, np.zeros((1, 2, 6)), np.zeros(1, dtype=bool),
                         np.zeros((6, 2)), row, one)
        ck.hybrid_combine(row, row, row, row, row, np.zeros((6, 6)), 1.0, True, True, row,
                          np.zeros((1, 18)), np.zeros(18), np.ones(18), np.zeros((2, 18)),
                          np.zeros(2), 0.5, 1.0, -one, one, 1.0)
    except Exception as exc:  # noqa: BLE001 - the NumPy kernels serve instead
        warnings.warn(f"compiled kernels unavailable, NumPy serves: {exc}", RuntimeWarning)
        return None
    return {name: getattr(ck, name) for name in HYBRID_KERNELS}


def wrench_kernel() -> Callable | None:
    """The wrench map's fast path compiled (``plain_wrench``), called once so that it is
    compiled or read from numba's cache now; None where numba is missing, switched off or
    fails here (LAPACK serves)."""
    if _kernels() is None:
        return None
    from wrenchd.models.estimator import compiled_kernels as ck

    try:
        ck.plain_wrench(np.eye(6), np.zeros(6), 1.0, np.empty(6))
    except Exception as exc:  # noqa: BLE001 - LAPACK serves instead
        warnings.warn(f"compiled kernels unavailable, LAPACK serves: {exc}", RuntimeWarning)
        return None
    return ck.plain_wrench


def _import_kernels(numba):
    """The kernels' module; its functions cache their machine code next to it or in the
    user's cache, and where neither is writable (a hardened service: a read-only system, no
    home) numba refuses to define them: then in a cache under the temporary directory, and
    failing that (or on any other error) None, with a warning: NumPy serves."""
    try:
        from wrenchd.models.estimator import compiled_kernels
        return compiled_kernels
    except RuntimeError:
        pass                              # "cannot cache function ...: no locator available"
    except Exception as exc:  # noqa: BLE001 - the NumPy kernels serve instead
        warnings.warn(f"compiled kernels unavailable, NumPy serves: {exc}", RuntimeWarning)
        return None
    numba.config.CACHE_DIR = os.path.join(tempfile.gettempdir(), f"wrenchd-numba-{os.getuid()}")
    try:
        from wrenchd.models.estimator import compiled_kernels
        return compiled_kernels
    except Exception as exc:  # noqa: BLE001 - the NumPy kernels serve instead
        warnings.warn(f"compiled kernels unavailable (no writable cache; set NUMBA_CACHE_DIR), "
                      f"NumPy serves: {exc}", RuntimeWarning)
        return None


def _built(cls, kernels, source):
    """``cls(kernels, source)`` (which compiles on first use), or None with a warning where
    numba fails to compile on this machine: NumPy serves."""
    try:
        return cls(kernels, source)
    except Exception as exc:  # noqa: BLE001 - the NumPy kernels serve instead
        warnings.warn(f"compiled kernels unavailable, NumPy serves: {exc}", RuntimeWarning)
        return None


class CompiledStep:
    """The compiled step of one
    :class:`~wrenchd.models.estimator.kernels.GroupedRecurrentKernel` (its weights packed once).

    Call with ``(x (B, n_in) raw inputs, state)`` where ``state`` is the kernel's
    ``(h_1, c_1, ...)`` (each (G, B, H)); returns ``((B, n_out) outputs, new state)`` as the
    kernel's :meth:`step` does.
    """

    def __init__(self, kernels: dict[str, Callable], kernel) -> None:
        self._kernels = kernels
        f32 = np.float32
        self.weights = tuple(np.ascontiguousarray(layer.weight, f32) for layer in kernel.layers)
        self.biases = tuple(np.ascontiguousarray(layer.bias[:, 0, :], f32)
                            for layer in kernel.layers)
        groups = kernel.layers[-1].n_groups
        hidden = kernel.layers[-1].hidden_size
        widths = [trunk[0][0].shape[1] if trunk else 0 for trunk in kernel.trunks]
        width = max(widths + [1])
        self.trunk_w = np.zeros((groups, width, hidden), f32)
        self.trunk_b = np.zeros((groups, width), f32)
        for g, trunk in enumerate(kernel.trunks):
            if trunk:
                w, b, _ = trunk[0]
                self.trunk_w[g, :w.shape[1], :] = w.T
                self.trunk_b[g, :w.shape[1]] = b
        self.trunk_n = np.asarray(widths, dtype=np.int64)
        sizes = [n if n else hidden for n in widths]
        self.offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        self.final_w = np.ascontiguousarray(kernel.final_weight.T, f32)
        self.final_b = np.ascontiguousarray(kernel.final_bias, f32)
        self._heads = (self.trunk_w, self.trunk_b, self.trunk_n, self.offsets, self.final_w,
                       self.final_b)
        # compiled (or read from numba's cache) now, not on the first sample served
        self(np.zeros((1, kernel.layers[0].input_size)), kernel.initial_state(1))

    def __call__(self, x: np.ndarray, state) -> tuple[np.ndarray, tuple]:
        inp = np.ascontiguousarray(x, dtype=np.float32)[None]                 # (1, B, n_in)
        state = tuple(np.ascontiguousarray(s) for s in state)
        if len(self.weights) == 1:
            y, h, c = self._kernels["one_layer"](inp, self.weights[0], self.biases[0],
                                                 state[0], state[1], *self._heads)
            return y, (h, c)
        new: list[np.ndarray] = []
        for k, (w, b) in enumerate(zip(self.weights, self.biases)):
            inp, c = self._kernels["layer"](inp, w, b, state[2 * k], state[2 * k + 1])
            new += [inp, c]
        return self._kernels["heads"](inp, *self._heads), tuple(new)


def compiled_step(kernel) -> CompiledStep | None:
    """The compiled step of ``kernel`` (a
    :class:`~wrenchd.models.estimator.kernels.GroupedRecurrentKernel`), or None where the
    NumPy kernel must run: numba missing or switched off (:data:`ENV`), a float64 kernel, or
    heads the compiled form does not cover (a trunk of more than one layer, or without ReLU).
    Compiles on first use in a process (seconds without numba's disk cache)."""
    if kernel.dtype != np.float32:
        return None
    if any(len(trunk) > 1 or (trunk and not trunk[0][2]) for trunk in kernel.trunks):
        return None
    kernels = _kernels()
    return None if kernels is None else _built(CompiledStep, kernels, kernel)


class CompiledCorrection:
    """The compiled one-row form of a correction net's
    :class:`~wrenchd.models.estimator.kernels.MLPKernel` (two layers, ReLU between, the
    normalisation folded in): ``(window (W, F), step1 (6,)) -> step1 + net`` (6,) float32."""

    def __init__(self, kernels: dict[str, Callable], mlp) -> None:
        (w1, b1, _), (w2, b2, _) = mlp.layers
        self._mlp2 = kernels["mlp2"]
        self.w1 = np.ascontiguousarray(w1.T, np.float32)
        self.b1 = np.ascontiguousarray(b1, np.float32)
        self.w2 = np.ascontiguousarray(w2.T, np.float32)
        self.b2 = np.ascontiguousarray(b2, np.float32)
        window = (self.w1.shape[1] - len(self.b2)) // N_FEATURES
        self(np.zeros((window, N_FEATURES)), np.zeros(len(self.b2), np.float32))

    def __call__(self, window: np.ndarray, step1: np.ndarray) -> np.ndarray:
        return self._mlp2(window, np.asarray(step1, dtype=np.float32), self.w1, self.b1,
                          self.w2, self.b2)


def compiled_correction(mlp) -> CompiledCorrection | None:
    """The compiled one-row form of ``mlp`` (a correction net's
    :class:`~wrenchd.models.estimator.kernels.MLPKernel`), or None where the NumPy kernel must
    run: numba missing or switched off, not float32, or not two layers with a ReLU between."""
    layers = mlp.layers
    if (len(layers) != 2 or not layers[0][2] or layers[1][2]
            or any(w.dtype != np.float32 for w, _, _ in layers)):
        return None
    kernels = _kernels()
    return None if kernels is None else _built(CompiledCorrection, kernels, mlp)
