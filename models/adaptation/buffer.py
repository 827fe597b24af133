"""The adaptation's sample buffer: fixed-capacity rings of rows with their network inputs."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class RowRing:
    """A fixed-capacity ring of (window, step1, measured) rows, with the rows' network input
    and target (:meth:`~wrenchd.models.adaptation.adapter.Adapter`'s ``net_io``) kept beside them: rows written since the last
    :meth:`normalise` are normalised then, each row once, not once per mini-batch."""

    capacity: int
    width: int
    rows: np.ndarray = field(init=False)
    n: int = 0
    head: int = 0

    def __post_init__(self) -> None:
        self.rows = np.zeros((self.capacity, self.width), dtype=np.float32)
        self.dirty = np.zeros(self.capacity, dtype=bool)
        self.inp = self.target = np.zeros((0, 0), dtype=np.float32)
        self._scaling: tuple | None = None
        # beside each row: its sample time [s] (NaN: unknown) and the stiffness change [N/m]
        # its measured torques were carried over by
        self.stamp = np.full(self.capacity, np.nan)
        self.shift = np.zeros(self.capacity)

    def push(self, row: np.ndarray, stamp: float = np.nan, shift: float = 0.0) -> None:
        self.put(self.head, row, stamp, shift)
        self.head = (self.head + 1) % self.capacity
        self.n = min(self.n + 1, self.capacity)

    def put(self, k: int, row: np.ndarray, stamp: float = np.nan, shift: float = 0.0) -> None:
        self.rows[k] = row
        self.dirty[k] = True
        self.stamp[k] = stamp
        self.shift[k] = shift

    def data(self) -> np.ndarray:
        return self.rows[:self.n]

    def clear(self) -> None:
        self.n = self.head = 0

    def order(self) -> np.ndarray:
        """Indices of the rows from the oldest to the newest."""
        if self.n < self.capacity:
            return np.arange(self.n)
        return (self.head + np.arange(self.capacity)) % self.capacity

    def normalise(self, scaling: tuple, net_io) -> None:
        """Bring ``inp`` and ``target`` up to date for ``scaling`` (``shift``, ``scale``,
        ``tau_std``, then anything else the target depends on; ``net_io(rows, scaling)`` ->
        (input, target), row by row)."""
        if scaling is not self._scaling:
            self._scaling = scaling
            self.dirty[:self.n] = True
        shift, tau_std = scaling[0], scaling[2]
        if self.inp.shape != (self.capacity, len(shift)):
            self.inp = np.zeros((self.capacity, len(shift)), dtype=np.float32)
            self.target = np.zeros((self.capacity, len(tau_std)), dtype=np.float32)
        idx = np.flatnonzero(self.dirty[:self.n])
        if len(idx) == 0:
            return
        inp, target = net_io(self.rows[idx], scaling)
        self.inp[idx] = inp
        self.target[idx] = target
        self.dirty[idx] = False
