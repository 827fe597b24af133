"""Joint-state time series: the array types every part of wrenchd passes around.

Joint order is the PSM's: 1 outer yaw [rad], 2 outer pitch [rad], 3 insertion [m],
4 tool roll [rad], 5 wrist pitch [rad], 6 wrist yaw [rad]. Efforts are N m for revolute
joints and N for the insertion joint. Wrenches are ``[Fx, Fy, Fz, Tx, Ty, Tz]`` in N and N m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wrenchd.models.errors import DataError

N_JOINTS = 6


def all_finite(*values: np.ndarray) -> bool:
    """Whether every element of the float arrays ``values`` is finite: a sample's check on
    the per-sample path. A NaN or an infinity makes the sum of Python floats non-finite, and
    a finite sum proves every term finite; only a sum that overflows is checked exactly (a
    few dozen floats add faster than NumPy tests them).

    >>> all_finite(np.ones(6), np.full((2, 6), 1e308)), all_finite(np.array([1.0, np.nan]))
    (True, False)
    """
    if math.isfinite(sum(sum(v.ravel().tolist()) for v in values)):
        return True
    return all(bool(np.isfinite(v).all()) for v in values)


JOINT_NAMES: tuple[str, ...] = (
    "outer_yaw",
    "outer_pitch",
    "outer_insertion",
    "outer_roll",
    "outer_wrist_pitch",
    "outer_wrist_yaw",
)
WRENCH_AXES: tuple[str, ...] = ("fx", "fy", "fz", "tx", "ty", "tz")


def _as_matrix(name: str, value: Any, n: int, width: int) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (n, width):
        raise DataError(f"{name} must have shape ({n}, {width}), got {arr.shape}")
    return arr


@dataclass(frozen=True)
class JointSample:
    """One joint state, as it arrives from a robot: the pipeline's input.

    Attributes:
        stamp_ns: header stamp [ns].
        frame_id: header frame.
        name: joint names.
        position, velocity, effort: (n,) float64 [rad; m], [rad/s; m/s], [N m; N].
    """

    stamp_ns: int
    frame_id: str
    name: tuple[str, ...]
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray

    def __init__(self, stamp_ns: int, frame_id: str, name: tuple[str, ...],
                 position: np.ndarray, velocity: np.ndarray, effort: np.ndarray) -> None:
        # One per sample: a dict update instead of the generated frozen __init__'s
        # object.__setattr__ per field; immutable all the same.
        self.__dict__.update(stamp_ns=stamp_ns, frame_id=frame_id, name=name,
                             position=position, velocity=velocity, effort=effort)

    @property
    def t(self) -> float:
        """Stamp [s]."""
        return self.stamp_ns / 1e9


@dataclass(frozen=True)
class JointStates:
    """Measured joint states, one row per sample.

    Attributes:
        t: (N,) sample times [s], strictly increasing.
        position: (N, 6) joint positions [rad, rad, m, rad, rad, rad].
        velocity: (N, 6) joint velocities [rad/s, rad/s, m/s, ...].
        effort: (N, 6) joint efforts [N m, N m, N, N m, N m, N m].
        names: joint names, length 6.
    """

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray
    names: tuple[str, ...] = JOINT_NAMES

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64)
        if t.ndim != 1:
            raise DataError(f"t must be one-dimensional, got shape {t.shape}")
        n = t.shape[0]
        object.__setattr__(self, "t", t)
        for name in ("position", "velocity", "effort"):
            object.__setattr__(self, name, _as_matrix(name, getattr(self, name), n, N_JOINTS))
        if len(self.names) != N_JOINTS:
            raise DataError(f"names must list {N_JOINTS} joints, got {len(self.names)}")
        if n > 1 and not np.all(np.diff(t) > 0):
            raise DataError("t must be strictly increasing")
        for name in ("t", "position", "velocity", "effort"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise DataError(f"{name} contains NaN or Inf")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def rate_hz(self) -> float:
        """Median sample rate [Hz]; nan for fewer than two samples."""
        if len(self) < 2:
            return float("nan")
        return float(1.0 / np.median(np.diff(self.t)))

    def slice(self, start: int, stop: int) -> "JointStates":
        """Rows ``start:stop`` as a new series."""
        return JointStates(
            self.t[start:stop], self.position[start:stop], self.velocity[start:stop],
            self.effort[start:stop], self.names,
        )


@dataclass(frozen=True)
class GroundTruth:
    """What the simulator knows and a real robot does not, aligned with :class:`JointStates`.

    Attributes:
        position, velocity, acceleration: (N, 6) true joint motion (before encoder effects).
        internal_torque: (N, 6) noise-free torque the robot needs for its own motion: rigid
            body plus every non-contact effect (friction, seal, body wall, ...).
        external_torque: (N, 6) joint torque caused by the tip wrench (J^T w).
        external_wrench: (N, 6) true tip wrench [N, N m], base-frame axes, about the tip.
        in_contact: (N,) bool, whether the tip is in contact.
        effects: per-effect (N, 6) torque contributions, keyed by effect name.
        sensor_wrench: (N, 6) noisy force/torque sensor reading of the tip wrench, or None
            where the scenario has no sensor.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    internal_torque: np.ndarray
    external_torque: np.ndarray
    external_wrench: np.ndarray
    in_contact: np.ndarray
    effects: dict[str, np.ndarray] = field(default_factory=dict)
    sensor_wrench: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = np.asarray(self.in_contact).shape[0]
        object.__setattr__(self, "in_contact", np.asarray(self.in_contact, dtype=bool))
        for name in ("position", "velocity", "acceleration", "internal_torque",
                     "external_torque", "external_wrench"):
            object.__setattr__(self, name, _as_matrix(name, getattr(self, name), n, 6))
        object.__setattr__(self, "effects", {
            k: _as_matrix(f"effects[{k}]", v, n, N_JOINTS) for k, v in self.effects.items()
        })
        if self.sensor_wrench is not None:
            object.__setattr__(self, "sensor_wrench",
                               _as_matrix("sensor_wrench", self.sensor_wrench, n, 6))

    def __len__(self) -> int:
        return int(self.in_contact.shape[0])

    def slice(self, start: int, stop: int) -> "GroundTruth":
        """Rows ``start:stop`` as a new ground truth."""
        sl = slice(start, stop)
        return GroundTruth(
            self.position[sl], self.velocity[sl], self.acceleration[sl],
            self.internal_torque[sl], self.external_torque[sl], self.external_wrench[sl],
            self.in_contact[sl], {k: v[sl] for k, v in self.effects.items()},
            None if self.sensor_wrench is None else self.sensor_wrench[sl],
        )


@dataclass(frozen=True)
class Session:
    """A recorded or simulated session: measurements, optional ground truth, metadata.

    ``metadata`` is JSON-serialisable (scenario name and parameters, seed, rates, the
    physics model used, its provenance).
    """

    joint_states: JointStates
    truth: GroundTruth | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.truth is not None and len(self.truth) != len(self.joint_states):
            raise DataError(
                f"truth has {len(self.truth)} samples, joint states {len(self.joint_states)}"
            )
