"""Step 2 of the two-step estimator: adapt a free-space model to a trocar set-up.

Wu, Yilmaz, Kazanzides, Tumerdem (arXiv 2012.01479) compare two ways to add the forces of
the cannula seal and the body wall to a step-1 (free-space) network, trained on a few minutes
of intra-operative motion without contact:

* ``Corr``: a feed-forward network reads a window of the last 10 samples of the positions and
  velocities of all joints plus the step-1 predicted torques, has one hidden layer of 256
  units with ReLU, and outputs a torque correction added to the step-1 prediction (trained
  with L2 weight decay 0.01, see :mod:`wrenchd.models.estimator.training`).
* ``Xfer`` (transfer learning): each step-1 network truncated after its LSTM and frozen, with a
  new LSTM and fully connected layers appended and trained, per joint group. Its output
  replaces the step-1 prediction (it contains the step-1 LSTMs).

Streaming: :class:`HistoryWindow` keeps the last ``window`` feature rows. After a reset (start,
gap) and until it is full, the window is padded at the old end by repeating the first sample
of the segment; :func:`wrenchd.models.estimator.features.history_windows` pads the batch path alike.
"""

from __future__ import annotations

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator
from torch import nn

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.compiled import DEFERRED, compile_now, compiled_correction
from wrenchd.models.estimator.features import N_FEATURES, history_windows
from wrenchd.models.estimator.free_space import MIN_STD, FreeSpaceModel, GroupedTorqueModel, check_groups
from wrenchd.models.estimator.kernels import GroupedRecurrentKernel, LSTMLayerKernel, MLPKernel
from wrenchd.models.estimator.trocar_physics import (N_TROCAR, trocar_torque, wall_matrices,
                                                     wall_torque_one)
from wrenchd.models.series import N_JOINTS


class CorrConfig(BaseModel):
    """Structure of the correction network."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    window: int = Field(default=10, ge=1, le=1000, description="history samples per input")
    hidden_size: int = Field(default=256, ge=1, description="units of the hidden layer")
    trocar_physics: bool = Field(
        default=False, description="add the body wall's physics, linear in 12 parameters "
                                   "(buffer trocar_theta, fitted by least squares: "
                                   "models/estimator/trocar_physics.py), to the net's output")


class Corr(nn.Module):
    """``tau = tau_1 + f([x_{t-W+1..t}], tau_1)``: (B, W, 12), (B, 6) -> (B, 6); with
    ``trocar_physics``, ``+ X(q_t, dq_t) theta`` (:mod:`~wrenchd.models.estimator.trocar_physics`;
    ``theta`` is the buffer ``trocar_theta``, set by least squares, not by gradients)."""

    def __init__(self, config: CorrConfig | None = None) -> None:
        super().__init__()
        self.config = config if config is not None else CorrConfig()
        n_in = self.config.window * N_FEATURES + N_JOINTS
        self.net = nn.Sequential(nn.Linear(n_in, self.config.hidden_size), nn.ReLU(),
                                 nn.Linear(self.config.hidden_size, N_JOINTS))
        self.register_buffer("in_mean", torch.zeros(N_FEATURES))
        self.register_buffer("in_std", torch.ones(N_FEATURES))
        self.register_buffer("tau_mean", torch.zeros(N_JOINTS))   # of step-1 torques
        self.register_buffer("tau_std", torch.ones(N_JOINTS))     # also the correction's unit
        if self.config.trocar_physics:
            self.register_buffer("trocar_theta", torch.zeros(N_TROCAR))

    @property
    def window(self) -> int:
        return self.config.window

    @classmethod
    def from_state(cls, config: CorrConfig, state: dict[str, np.ndarray]) -> Corr:
        """An eval-mode net of ``config`` holding ``state`` (a ``state_dict`` as NumPy arrays),
        in the state's float type; with the trocar physics if and only if the state has its
        parameters (a net served from a checkpoint of either kind takes the adapter's next)."""
        f64 = np.asarray(state["net.0.weight"]).dtype == np.float64
        config = config.model_copy(update={"trocar_physics": "trocar_theta" in state})
        corr = cls(config).to(torch.float64 if f64 else torch.float32)
        corr.load_state_dict({k: torch.from_numpy(np.array(v)) for k, v in state.items()})
        return corr.eval()

    def state_arrays(self) -> dict[str, np.ndarray]:
        """The ``state_dict`` as NumPy copies (what :meth:`from_state` and
        :meth:`CorrKernel.from_state` take; safe to ship to another process)."""
        return {k: v.detach().cpu().numpy().copy() for k, v in self.state_dict().items()}

    def set_normalisation(self, features: np.ndarray, step1_torques: np.ndarray) -> None:
        """Store mean/std of (N, 12) training features and (N, 6) step-1 torques."""
        f = np.asarray(features, dtype=np.float64).reshape(-1, N_FEATURES)
        y = np.asarray(step1_torques, dtype=np.float64).reshape(-1, N_JOINTS)
        for buf, value in ((self.in_mean, f.mean(0)), (self.in_std, np.maximum(f.std(0), MIN_STD)),
                           (self.tau_mean, y.mean(0)),
                           (self.tau_std, np.maximum(y.std(0), MIN_STD))):
            buf.copy_(torch.from_numpy(value))

    def normalised_input(self, windows: torch.Tensor, step1: torch.Tensor) -> torch.Tensor:
        """(B, W, 12) raw windows, (B, 6) step-1 torques -> (B, W * 12 + 6) network input."""
        if windows.ndim != 3 or windows.shape[1:] != (self.window, N_FEATURES):
            raise DataError(f"windows must have shape (B, {self.window}, {N_FEATURES}), "
                            f"got {tuple(windows.shape)}")
        xw = ((windows - self.in_mean) / self.in_std).flatten(1)
        xt = (step1 - self.tau_mean) / self.tau_std
        return torch.cat([xw, xt], dim=-1)

    def correction_normalised(self, windows: torch.Tensor, step1: torch.Tensor) -> torch.Tensor:
        """(B, W, 12) raw windows, (B, 6) step-1 torques -> (B, 6) correction in tau_std units."""
        return self.net(self.normalised_input(windows, step1))

    def forward(self, windows: torch.Tensor, step1: torch.Tensor) -> torch.Tensor:
        """Corrected torques (B, 6) [N m; N]."""
        out = step1 + self.correction_normalised(windows, step1) * self.tau_std
        if self.config.trocar_physics:
            last = windows[:, -1].detach().to("cpu", torch.float64).numpy()
            tau = trocar_torque(last[:, :N_JOINTS], last[:, N_JOINTS:],
                                self.trocar_theta.detach().cpu().double().numpy())
            out = out + torch.as_tensor(tau, dtype=out.dtype, device=out.device)
        return out

    @torch.inference_mode()
    def correct_sequence(self, features: np.ndarray, step1: np.ndarray) -> np.ndarray:
        """Eval-mode corrected torques of one gap-free segment: (T, 12), (T, 6) -> (T, 6)."""
        dtype = self.in_mean.dtype
        w = torch.as_tensor(history_windows(np.asarray(features), self.window), dtype=dtype)
        s = torch.as_tensor(np.asarray(step1), dtype=dtype)
        return self(w, s).to(torch.float64).numpy()

    def kernel(self, dtype=None) -> "CorrKernel":
        """A NumPy snapshot for streaming; ``dtype`` defaults to the parameters' dtype."""
        if dtype is None:
            dtype = np.float64 if self.in_mean.dtype == torch.float64 else np.float32
        return CorrKernel(self, np.dtype(dtype))


def zero_corr(config: CorrConfig, windows: np.ndarray | None = None,
              step1: np.ndarray | None = None, seed: int = 0,
              normalisation: dict[str, np.ndarray] | None = None) -> Corr:
    """A ``Corr`` whose correction is exactly zero (its output layer zeroed), in eval mode.

    Its normalisation is ``normalisation`` (arrays named as the buffers), else fitted on
    ``windows`` (B, W, 12) and ``step1`` (B, 6) torques, else the identity. The hidden layers
    are initialised from ``seed`` without touching torch's global generator.
    """
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        corr = Corr(config)
    if normalisation is not None:
        for name, value in normalisation.items():
            getattr(corr, name).copy_(torch.as_tensor(np.asarray(value), dtype=torch.float32))
    elif windows is not None and step1 is not None:
        corr.set_normalisation(windows.reshape(-1, windows.shape[-1]), step1)
    last = corr.net[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
    return corr.eval()


class CorrKernel:
    """Eval-mode :class:`Corr` on NumPy, normalisation folded into the weights."""

    def __init__(self, corr: Corr, dtype: np.dtype) -> None:
        self._build(corr.state_arrays(), corr.window, dtype)

    @classmethod
    def from_state(cls, state: dict[str, np.ndarray], window: int,
                   dtype: np.dtype | None = None) -> CorrKernel:
        """The kernel of the ``Corr`` whose ``state_dict`` (as NumPy arrays) is ``state``, built
        without a torch module: the same numbers as ``Corr.kernel()`` of that net. ``dtype``
        defaults to the state's (float32 for a float32 net)."""
        kernel = cls.__new__(cls)
        kernel._build(state, window, np.dtype(dtype if dtype is not None
                                                else state["net.0.weight"].dtype))
        return kernel

    def _build(self, state: dict[str, np.ndarray], w: int, dtype: np.dtype) -> None:
        f64 = {k: np.asarray(v, dtype=np.float64) for k, v in state.items()}
        shift = np.concatenate([np.tile(f64["in_mean"], w), f64["tau_mean"]])
        scale = np.concatenate([np.tile(f64["in_std"], w), f64["tau_std"]])
        self.window, self.dtype = w, dtype
        theta = f64.get("trocar_theta")
        self.theta = theta if theta is not None and theta.any() else None
        self._wall = (None if self.theta is None
                      else tuple(m.tolist() for m in wall_matrices(self.theta)))
        self.mlp = MLPKernel.from_arrays(
            [(f64["net.0.weight"], f64["net.0.bias"], True),
             (f64["net.2.weight"], f64["net.2.bias"], False)], dtype,
            in_shift=shift, in_scale=scale, out_shift=np.zeros(N_JOINTS),
            out_scale=f64["tau_std"])
        # one row compiled with numba where it is installed (compiled.py), now or on first use
        self._compiled = compiled_correction(self.mlp) if compile_now() else DEFERRED

    def __getstate__(self) -> dict:
        # the compiled form stays in its process: the receiver builds its own
        return {k: v for k, v in self.__dict__.items() if k != "_compiled"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._compiled = compiled_correction(self.mlp) if compile_now() else DEFERRED

    def correct(self, windows: np.ndarray, step1: np.ndarray) -> np.ndarray:
        """(B, W, 12) raw windows, (B, 6) step-1 torques -> (B, 6) corrected torques."""
        b = step1.shape[0]
        compiled = self._compiled
        if b == 1 and compiled is DEFERRED:
            compiled = self._compiled = compiled_correction(self.mlp)
        if b == 1 and compiled is not None:
            out = compiled(windows[0], step1[0])[None, :]
        else:
            v = np.concatenate([windows.reshape(b, -1), step1], axis=1).astype(self.dtype,
                                                                              copy=False)
            out = step1 + self.mlp(v)
        if self.theta is None:
            return out
        last = windows[:, -1]
        if b == 1:                      # the streaming case: plain floats
            row = last[0].tolist()
            yaw, pitch = wall_torque_one(row, row[N_JOINTS:], *self._wall)
            out[0, 0] += yaw
            out[0, 1] += pitch
        else:
            out += trocar_torque(last[:, :N_JOINTS], last[:, N_JOINTS:], self.theta)
        return out


class HistoryWindow:
    """The last ``window`` feature rows of a stream, oldest first.

    After :meth:`reset` the first pushed row fills the whole window (padding by repetition),
    matching :func:`wrenchd.models.estimator.features.history_windows`.
    """

    def __init__(self, window: int, n_features: int = N_FEATURES, dtype=np.float64) -> None:
        self.rows = np.zeros((window, n_features), dtype=dtype)
        self.empty = True

    def reset(self) -> None:
        """Forget the stored rows."""
        self.empty = True

    def push(self, x: np.ndarray) -> np.ndarray:
        """Append one (F,) row; returns the (W, F) window (a view, valid until the next push)."""
        if self.empty:
            self.rows[:] = x
            self.empty = False
        else:
            self.rows[:-1] = self.rows[1:]
            self.rows[-1] = x
        return self.rows


class XferConfig(BaseModel):
    """Structure of the transfer-learning model (the step-1 LSTMs plus new layers)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    groups: tuple[tuple[int, ...], ...] = Field(
        default=((0, 1), (2,), (3,), (4, 5)), description="joint groups, as the step-1 model's")
    base_hidden_size: int = Field(default=128, ge=1, description="hidden units of the frozen LSTM")
    hidden_size: int = Field(default=128, ge=1, description="hidden units of the new LSTM")
    head_hidden_size: int = Field(default=128, ge=1, description="units of the new hidden layer")
    dropout: float = Field(default=0.0, ge=0.0, lt=1.0, description="dropout after that layer")

    @field_validator("groups")
    @classmethod
    def validate_groups(cls, value: tuple[tuple[int, ...], ...]) -> tuple[tuple[int, ...], ...]:
        return check_groups(value)

    @classmethod
    def for_base(cls, base: FreeSpaceModel, **overrides) -> "XferConfig":
        """The config matching a step-1 model's groups and LSTM size."""
        return cls(groups=base.config.groups, base_hidden_size=base.config.hidden_size, **overrides)


class XferGroupNet(nn.Module):
    """Frozen step-1 LSTM, new LSTM, new fully connected layers."""

    def __init__(self, n_out: int, cfg: XferConfig) -> None:
        super().__init__()
        self.base_lstm = nn.LSTM(N_FEATURES, cfg.base_hidden_size, batch_first=True)
        self.base_lstm.requires_grad_(False)
        self.lstm = nn.LSTM(cfg.base_hidden_size, cfg.hidden_size, batch_first=True)
        self.head = nn.Sequential(nn.Linear(cfg.hidden_size, cfg.head_hidden_size), nn.ReLU(),
                                  nn.Dropout(cfg.dropout), nn.Linear(cfg.head_hidden_size, n_out))

    def forward(self, x: torch.Tensor, state: tuple | None = None) -> tuple[torch.Tensor, tuple]:
        """(B, T, 12) normalised features -> ((B, T, n_out) normalised torques, state pair)."""
        base_state, state = state if state is not None else (None, None)
        h, base_state = self.base_lstm(x, base_state)
        h, state = self.lstm(h, state)
        return self.head(h), (base_state, state)


class Xfer(GroupedTorqueModel):
    """Transfer-learning step 2: (B, T, 12) raw features -> (B, T, 6) trocar torques.

    Args:
        config: structure; ``XferConfig.for_base(base)`` matches a step-1 model.
        base: the step-1 model whose LSTMs and input normalisation are copied in and frozen
            (omit when the weights come from a checkpoint).
    """

    def __init__(self, config: XferConfig | None = None,
                 base: FreeSpaceModel | None = None) -> None:
        super().__init__()
        if config is None:
            config = XferConfig.for_base(base) if base is not None else XferConfig()
        self.config = config
        self.groups = config.groups
        self.nets = nn.ModuleList(XferGroupNet(len(g), config) for g in config.groups)
        self.to(base.in_mean.dtype if base is not None else torch.float32)
        if base is not None:
            if (base.config.groups != config.groups
                    or base.config.hidden_size != config.base_hidden_size):
                raise ConfigError("Xfer config does not match the step-1 model's groups or size")
            for net, base_net in zip(self.nets, base.nets):
                net.base_lstm.load_state_dict(base_net.lstm.state_dict())
            for name in ("in_mean", "in_std", "out_mean", "out_std"):
                getattr(self, name).copy_(getattr(base, name))

    def uses_base(self, base: FreeSpaceModel) -> bool:
        """Whether the frozen layers and input normalisation are exactly ``base``'s."""
        if base.config.groups != self.groups or len(base.nets) != len(self.nets):
            return False
        same = all(torch.equal(a, b) for net, base_net in zip(self.nets, base.nets)
                   for a, b in zip(net.base_lstm.state_dict().values(),
                                   base_net.lstm.state_dict().values()))
        return (same and torch.equal(self.in_mean, base.in_mean)
                and torch.equal(self.in_std, base.in_std))

    def trainable_parameters(self) -> list[nn.Parameter]:
        """The new layers only (the base LSTMs stay frozen)."""
        return [p for p in self.parameters() if p.requires_grad]

    def kernel(self, dtype=None) -> GroupedRecurrentKernel:
        dtype = self._default_dtype(dtype)
        base = LSTMLayerKernel([net.base_lstm for net in self.nets], dtype,
                               in_shift=self.in_mean.double().numpy(),
                               in_scale=self.in_std.double().numpy())
        new = LSTMLayerKernel([net.lstm for net in self.nets], dtype)
        return GroupedRecurrentKernel([base, new], self._heads(dtype), dtype)
