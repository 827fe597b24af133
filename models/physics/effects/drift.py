"""Drift: a slow (or sudden) change of another effect's parameter during a session.

Insufflation pressure changes when the surgeon adjusts the insufflator or the patient moves;
seal and wrist friction grow as an instrument wears. ``drift`` scales one numeric parameter
of a target effect by a factor that changes with time, and contributes the difference it
makes: ``tau = target(param * factor(t)) - target(param)``.

Shapes of ``factor(t)`` (1 before ``t_start_s``):
* ``step``: ``factor`` from ``t_start_s`` on;
* ``ramp``: linear from 1 at ``t_start_s`` to ``factor`` at ``t_end_s``, then held;
* ``linear``: ``1 + rate_per_hour * (t - t_start_s) / 3600``, unbounded.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, register


class DriftParams(EffectParams):
    target: str = Field(description="id of the effect whose parameter drifts")
    param: str = Field(description="name of the drifting parameter")
    kind: Literal["step", "ramp", "linear"] = Field(default="ramp", description="shape in time")
    factor: float = Field(default=1.5, gt=0.0, description="final scale (step, ramp)")
    rate_per_hour: float = Field(default=0.5, description="relative change per hour (linear)")
    t_start_s: float = Field(default=0.0, ge=0.0, description="when the change begins [s]")
    t_end_s: float = Field(default=600.0, ge=0.0, description="when a ramp ends [s]")

    @model_validator(mode="after")
    def _ramp_ordered(self):
        if self.kind == "ramp" and not self.t_end_s > self.t_start_s:
            raise ValueError(f"ramp needs t_end_s > t_start_s, got {self.t_start_s}, {self.t_end_s}")
        return self


def drift_factor(t: np.ndarray, p: DriftParams) -> np.ndarray:
    """Scale factor (N,) at times ``t`` [s]."""
    after = t >= p.t_start_s
    if p.kind == "step":
        return np.where(after, p.factor, 1.0)
    if p.kind == "ramp":
        frac = np.clip((t - p.t_start_s) / (p.t_end_s - p.t_start_s), 0.0, 1.0)
        return 1.0 + (p.factor - 1.0) * frac
    return 1.0 + p.rate_per_hour * np.maximum(t - p.t_start_s, 0.0) / 3600.0


@register
class Drift(Effect):
    """The change a drifting parameter makes to its target effect's torque."""

    name = "drift"
    Params = DriftParams

    def __init__(self, params=None) -> None:
        super().__init__(params)
        self.target: Effect | None = None

    def bind(self, target: Effect) -> None:
        """Attach the target effect; the model file resolves ``target`` by id."""
        if self.params.param not in target.numeric_params():
            raise ConfigError(
                f"drift: effect {self.params.target!r} has no numeric parameter "
                f"{self.params.param!r}; choose one of {target.numeric_params()}"
            )
        self.target = target

    @property
    def stateful(self) -> bool:  # type: ignore[override]
        return bool(self.target is not None and self.target.stateful)

    def scaled_parameter(self, t: np.ndarray) -> np.ndarray:
        """The drifting parameter over time, shape (N, ...)."""
        nominal = self.target.param(self.params.param)
        factor = drift_factor(t, self.params)
        return factor.reshape((-1,) + (1,) * nominal.ndim) * nominal

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        if self.target is None:
            raise ConfigError(f"drift on {self.params.target!r} is not bound to its target")
        drifted = self.target.torque(motion, {self.params.param: self.scaled_parameter(motion.t)})
        return drifted - self.target.torque(motion)


def drift_onsets(session) -> list[tuple[str, float, float | None]]:
    """Set-up changes a session's metadata announces (a :class:`~wrenchd.models.series.Session`):
    (id, start [s], end [s] or None).

    Reads the ``drift`` effects of the simulator's physics model (step: end None; ramp: end)
    and the ``setup_changes`` a session built from recordings lists (``{"id", "t_s"}``;
    :mod:`wrenchd.models.recorded`; end None). Sessions with neither (a single real
    recording, a daemon log) give an empty list.
    """
    physics = session.metadata.get("physics_model") or {}
    effects = physics.get("effects", []) if isinstance(physics, dict) else []
    out = [(str(c.get("id", "setup_change")), float(c["t_s"]), None)
           for c in session.metadata.get("setup_changes") or ()
           if isinstance(c, dict) and c.get("t_s") is not None]
    for spec in effects:
        if spec.get("name") != "drift" or spec.get("enabled") is False:
            continue
        params = spec.get("params", {})
        start = params.get("t_start_s")
        if start is None:
            continue
        end = params.get("t_end_s") if params.get("kind") == "ramp" else None
        out.append((str(spec.get("id") or params.get("target")), float(start),
                    None if end is None else float(end)))
    return sorted(out, key=lambda d: d[1])
