"""The effect interface: a named, parameterised joint-torque contribution.

An effect maps a motion (arrays) to joint torques (arrays); it never does I/O. Parameters are
a pydantic model beside the effect, so a model file validates with messages that name the bad
value. Any numeric parameter can vary in time: :meth:`Effect.torque` takes ``overrides``,
arrays whose first axis is time (that is how :mod:`~wrenchd.models.physics.effects.drift` works).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict

from wrenchd.models.errors import ConfigError
from wrenchd.models.series import N_JOINTS


@dataclass(frozen=True)
class Motion:
    """Joint motion sampled at times ``t``, plus the robot model for geometric effects.

    Attributes:
        t: (N,) time [s].
        q, dq, ddq: (N, 6) positions, velocities, accelerations [rad, m; per s; per s^2].
        robot: the :class:`~wrenchd.models.physics.dynamics.RigidBodyModel` (pinocchio model with
            inertias), for effects that need kinematics or the regressor.
    """

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    robot: Any

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def slice(self, idx: slice | np.ndarray) -> "Motion":
        return Motion(self.t[idx], self.q[idx], self.dq[idx], self.ddq[idx], self.robot)

    @property
    def dt(self) -> float:
        """Median step [s]."""
        return float(np.median(np.diff(self.t))) if len(self) > 1 else 0.0


class EffectParams(BaseModel):
    """Base of every effect's parameters: unknown keys are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def per_joint(value: float | list[float] | tuple[float, ...]) -> tuple[float, ...]:
    """Expand a scalar to six per-joint values; check a sequence has six."""
    if isinstance(value, (int, float)):
        return (float(value),) * N_JOINTS
    value = tuple(float(v) for v in value)
    if len(value) != N_JOINTS:
        raise ValueError(f"expected {N_JOINTS} per-joint values, got {len(value)}")
    return value


class Effect(ABC):
    """A joint-torque contribution ``tau = f(motion; params)``, shape (N, 6).

    Subclasses set ``name`` (the vocabulary word used in model files), ``Params`` (pydantic)
    and ``stateful`` (True when the torque depends on the motion's history, so it must be
    evaluated on the simulator's internal 1 kHz step rather than on published samples).
    """

    name: ClassVar[str]
    Params: ClassVar[type[EffectParams]]
    stateful: ClassVar[bool] = False

    def __init__(self, params: EffectParams | dict[str, Any] | None = None) -> None:
        if params is None:
            params = {}
        if isinstance(params, dict):
            try:
                params = self.Params(**params)
            except Exception as exc:  # pydantic.ValidationError, TypeError
                raise ConfigError(f"effect {self.name!r}: invalid parameters: {exc}") from exc
        self.params = params

    def param(self, key: str, overrides: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """A parameter as an array: ``(...)`` nominal, or ``(N, ...)`` when overridden in time."""
        if overrides and key in overrides:
            return np.asarray(overrides[key], dtype=np.float64)
        return np.asarray(getattr(self.params, key), dtype=np.float64)

    @abstractmethod
    def torque(self, motion: Motion, overrides: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """Joint torques (N, 6) [N m; N on insertion]."""

    def numeric_params(self) -> list[str]:
        """Names of parameters that may be overridden in time (numbers or number tuples)."""
        out = []
        for key, value in self.params.model_dump().items():
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                out.append(key)
            elif isinstance(value, (list, tuple)) and value and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
            ):
                out.append(key)
        return out


EFFECTS: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: add an effect to the vocabulary of model files."""
    if cls.name in EFFECTS:
        raise ValueError(f"effect {cls.name!r} registered twice")
    EFFECTS[cls.name] = cls
    return cls


def zeros(motion: Motion) -> np.ndarray:
    return np.zeros((len(motion), N_JOINTS))
