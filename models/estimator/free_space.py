"""Step 1 of the two-step estimator: joint torques of free motion from joint states.

Wu, Yilmaz, Kazanzides, Tumerdem, "Estimation of Trocar and Tool Interaction Forces on the da
Vinci Research Kit with Two-Step Deep Learning" (arXiv 2012.01479): the torque the robot needs
for its own motion is learned from the positions and velocities of all six joints by one
network per joint group, (1, 2), (3), (4) and (5, 6). Each network is an LSTM with 128 hidden
units and a fully connected output; the network of the insertion joint 3 has an extra
128-node hidden layer with ReLU and dropout, for the hysteresis of the cannula seal.

The same structure trained directly on trocar data is the paper's ``Troc`` baseline
(training recipe ``"troc"`` in :mod:`wrenchd.models.estimator.training`).

Shapes: features (B, T, 12) ``[q, dq]`` raw (see :mod:`wrenchd.models.estimator.features`); torques
(B, T, 6) [N m, N m, N, N m, N m, N m]. Normalisation is stored in buffers, so a checkpoint
carries it.
"""

from __future__ import annotations

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from torch import nn

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.features import N_FEATURES
from wrenchd.models.estimator.kernels import (GroupedRecurrentKernel, LSTMLayerKernel, MLPKernel,
                                      RecurrentState)
from wrenchd.models.series import N_JOINTS

#: Joint groups of the paper, zero-based: joints (1, 2), (3), (4), (5, 6).
JOINT_GROUPS: tuple[tuple[int, ...], ...] = ((0, 1), (2,), (3,), (4, 5))
#: Smallest standard deviation used for normalising (a feature that never moves).
MIN_STD = 1e-6


def check_groups(groups: tuple[tuple[int, ...], ...]) -> tuple[tuple[int, ...], ...]:
    """Groups must be contiguous runs covering joints 0..5 in order (outputs concatenate)."""
    flat = [j for g in groups for j in g]
    if flat != list(range(N_JOINTS)) or any(len(g) == 0 for g in groups):
        raise ValueError(f"groups must partition joints 0..5 in order, got {groups}")
    return groups


class FreeSpaceConfig(BaseModel):
    """Structure of the step-1 networks."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    groups: tuple[tuple[int, ...], ...] = Field(
        default=JOINT_GROUPS, description="zero-based joint groups, one network each")
    hidden_size: int = Field(default=128, ge=1, description="LSTM hidden units per network")
    seal_groups: tuple[int, ...] = Field(
        default=(1,), description="indices of groups with the extra hidden layer (joint 3)")
    seal_hidden_size: int = Field(default=128, ge=1, description="units of that hidden layer")
    seal_dropout: float = Field(default=0.2, ge=0.0, lt=1.0,
                                description="dropout after that hidden layer (assumed value)")

    @field_validator("groups")
    @classmethod
    def validate_groups(cls, value: tuple[tuple[int, ...], ...]) -> tuple[tuple[int, ...], ...]:
        return check_groups(value)

    @model_validator(mode="after")
    def _seal_groups(self) -> FreeSpaceConfig:
        n = len(self.groups)
        if len(set(self.seal_groups)) != len(self.seal_groups) or not all(
                0 <= g < n for g in self.seal_groups):
            raise ValueError(f"seal_groups must be distinct indices of the {n} groups "
                             f"(0..{n - 1}), got {self.seal_groups}")
        return self


class JointGroupNet(nn.Module):
    """One joint group: LSTM, then an optional hidden layer, then a linear output."""

    def __init__(self, n_out: int, hidden_size: int, head_hidden: int | None = None,
                 dropout: float = 0.0, input_size: int = N_FEATURES) -> None:
        super().__init__()
        self.lstm = nn.LSTM(input_size, hidden_size, batch_first=True)
        layers: list[nn.Module] = []
        width = hidden_size
        if head_hidden:
            layers += [nn.Linear(hidden_size, head_hidden), nn.ReLU(), nn.Dropout(dropout)]
            width = head_hidden
        layers.append(nn.Linear(width, n_out))
        self.head = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor, state: tuple | None = None) -> tuple[torch.Tensor, tuple]:
        """(B, T, 12) normalised features -> ((B, T, n_out) normalised torques, LSTM state)."""
        h, state = self.lstm(x, state)
        return self.head(h), state


class GroupedTorqueModel(nn.Module):
    """Base of the per-joint-group torque models: normalisation, sequence and streaming paths.

    Subclasses set ``self.groups`` and ``self.nets`` (an ``nn.ModuleList``, one per group, each
    mapping normalised (B, T, 12) to normalised (B, T, len(group))) and implement
    :meth:`kernel`.
    """

    groups: tuple[tuple[int, ...], ...]
    nets: nn.ModuleList

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("in_mean", torch.zeros(N_FEATURES))
        self.register_buffer("in_std", torch.ones(N_FEATURES))
        self.register_buffer("out_mean", torch.zeros(N_JOINTS))
        self.register_buffer("out_std", torch.ones(N_JOINTS))
        self._kernel: GroupedRecurrentKernel | None = None
        self._kernel_key: tuple | None = None

    # -- normalisation -------------------------------------------------------------------
    def set_input_normalisation(self, features: np.ndarray) -> None:
        """Store mean and std of (N, 12) training features."""
        f = np.asarray(features, dtype=np.float64).reshape(-1, N_FEATURES)
        self.in_mean.copy_(torch.from_numpy(f.mean(0)))
        self.in_std.copy_(torch.from_numpy(np.maximum(f.std(0), MIN_STD)))

    def set_output_normalisation(self, torques: np.ndarray) -> None:
        """Store mean and std of (N, 6) training torques."""
        y = np.asarray(torques, dtype=np.float64).reshape(-1, N_JOINTS)
        self.out_mean.copy_(torch.from_numpy(y.mean(0)))
        self.out_std.copy_(torch.from_numpy(np.maximum(y.std(0), MIN_STD)))

    # -- sequence path -------------------------------------------------------------------
    def forward_normalised(self, x: torch.Tensor, states: list | None = None
                           ) -> tuple[list[torch.Tensor], list]:
        """Per-group outputs in normalised units, for training with carried state.

        Args:
            x: (B, T, 12) raw features.
            states: per-group recurrent states from a previous call, or None (zero state).
        Returns:
            a list of (B, T, len(group)) normalised torques and the list of new states.
        """
        if x.ndim != 3 or x.shape[-1] != N_FEATURES:
            raise DataError(f"features must have shape (B, T, {N_FEATURES}), got {tuple(x.shape)}")
        xn = (x - self.in_mean) / self.in_std
        states = states if states is not None else [None] * len(self.nets)
        outs = [net(xn, s) for net, s in zip(self.nets, states)]
        return [y for y, _ in outs], [s for _, s in outs]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, T, 12) raw features -> (B, T, 6) torques, every stream from the zero state."""
        ys, _ = self.forward_normalised(x)
        return torch.cat(ys, dim=-1) * self.out_std + self.out_mean

    @torch.inference_mode()
    def predict_sequence(self, features: np.ndarray) -> np.ndarray:
        """Eval-mode torques of one stream: (T, 12) raw features -> (T, 6), float64."""
        was_training = self.training
        self.eval()
        try:
            dtype = self.in_mean.dtype
            x = torch.as_tensor(np.asarray(features), dtype=dtype)[None]
            return self(x)[0].to(torch.float64).numpy()
        finally:
            self.train(was_training)

    # -- streaming path ------------------------------------------------------------------
    def kernel(self, dtype=None) -> GroupedRecurrentKernel:
        """A NumPy eval-mode snapshot for streaming (see :mod:`wrenchd.models.estimator.kernels`).

        ``dtype`` defaults to the parameters' dtype (float32 or float64).
        """
        raise NotImplementedError

    def _default_dtype(self, dtype) -> np.dtype:
        if dtype is not None:
            return np.dtype(dtype)
        return np.dtype(np.float64 if self.in_mean.dtype == torch.float64 else np.float32)

    def _heads(self, dtype) -> list[MLPKernel]:
        heads, mean, std = [], self.out_mean.double().numpy(), self.out_std.double().numpy()
        for group, net in zip(self.groups, self.nets):
            idx = list(group)
            heads.append(MLPKernel(list(net.head), dtype, out_shift=mean[idx], out_scale=std[idx]))
        return heads

    def _current_kernel(self) -> GroupedRecurrentKernel:
        # Rebuilt when any weight or buffer changed: in-place updates (optimiser steps,
        # load_state_dict) bump a tensor's version counter, dtype casts change its storage.
        key = tuple((t.data_ptr(), t._version) for t in (*self.parameters(), *self.buffers()))
        if self._kernel is None or key != self._kernel_key:
            self._kernel, self._kernel_key = self.kernel(), key
        return self._kernel

    def initial_state(self, batch: int = 1) -> RecurrentState:
        """Zero recurrent state for ``batch`` streams."""
        return self._current_kernel().initial_state(batch)

    def step(self, x: np.ndarray, state: RecurrentState | None = None
             ) -> tuple[np.ndarray, RecurrentState]:
        """Advance one sample, eval mode (no dropout); pure: ``state`` is not modified.

        Args:
            x: (12,) or (B, 12) raw features ``[q, dq]``.
            state: the state returned by the previous step, or None to start from zero.
        Returns:
            torques (6,) or (B, 6) [N m; N], and the new state.
        """
        x = np.asarray(x)
        single = x.ndim == 1
        xb = x[None, :] if single else x
        if xb.ndim != 2 or xb.shape[1] != N_FEATURES:
            raise DataError(f"features must have shape (12,) or (B, 12), got {x.shape}")
        kernel = self._current_kernel()
        if state is None:
            state = kernel.initial_state(xb.shape[0])
        y, state = kernel.step(xb, state)
        return (y[0] if single else y), state


class FreeSpaceModel(GroupedTorqueModel):
    """The four step-1 networks: (B, T, 12) raw features -> (B, T, 6) joint torques."""

    def __init__(self, config: FreeSpaceConfig | None = None) -> None:
        super().__init__()
        self.config = config if config is not None else FreeSpaceConfig()
        cfg = self.config
        for g in cfg.seal_groups:
            if not 0 <= g < len(cfg.groups):
                raise ConfigError(f"seal group index {g} outside 0..{len(cfg.groups) - 1}")
        self.groups = cfg.groups
        self.nets = nn.ModuleList(
            JointGroupNet(len(group), cfg.hidden_size,
                          cfg.seal_hidden_size if k in cfg.seal_groups else None,
                          cfg.seal_dropout)
            for k, group in enumerate(cfg.groups))

    def kernel(self, dtype=None) -> GroupedRecurrentKernel:
        dtype = self._default_dtype(dtype)
        layer = LSTMLayerKernel([net.lstm for net in self.nets], dtype,
                                in_shift=self.in_mean.double().numpy(),
                                in_scale=self.in_std.double().numpy())
        return GroupedRecurrentKernel([layer], self._heads(dtype), dtype)
