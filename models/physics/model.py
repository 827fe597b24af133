"""A physics model file: the rigid body plus a list of switchable effects.

JSON layout (``wrenchd.physics/1``)::

    {
      "format": "wrenchd.physics/1",
      "description": "free space with the cannula seal",
      "rigid_body": {...},                      # optional, defaults in dynamics.py
      "effects": [
        {"name": "coulomb_friction", "params": {"fc": [0.05, 0.067, 0.45, 0.003, 0.005, 0.005]}},
        {"name": "seal_friction", "enabled": false},
        {"name": "drift", "id": "seal_wear",
         "params": {"target": "seal_friction", "param": "fc", "kind": "linear", "rate_per_hour": 0.5}}
      ]
    }

``id`` defaults to ``name`` and must be unique; ground truth and reports key each effect's
torque by its id. ``external_contact`` is the one *external* effect: its torque is what the
estimator must recover; everything else is the robot's own (internal) torque.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.dynamics import RigidBodyConfig, RigidBodyModel
from wrenchd.models.physics.effects import EFFECTS, Effect, Motion
from wrenchd.models.physics.effects.drift import Drift

FORMAT = "wrenchd.physics/1"
EXTERNAL_EFFECTS = frozenset({"external_contact"})


class EffectSpec(BaseModel):
    """One entry of a model file's ``effects`` list."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field(description="effect vocabulary word, e.g. 'seal_friction'")
    id: str | None = Field(default=None, description="unique id; defaults to name")
    enabled: bool = Field(default=True, description="switch the effect off without deleting it")
    params: dict[str, Any] = Field(default_factory=dict, description="the effect's parameters")

    @property
    def key(self) -> str:
        return self.id or self.name

    @model_validator(mode="after")
    def _known(self):
        if self.name not in EFFECTS:
            raise ValueError(f"unknown effect {self.name!r}; known: {sorted(EFFECTS)}")
        return self


class PhysicsModelConfig(BaseModel):
    """A whole model file."""

    model_config = ConfigDict(extra="forbid")

    format: Literal["wrenchd.physics/1"] = FORMAT
    description: str = ""
    rigid_body: RigidBodyConfig = Field(default_factory=RigidBodyConfig)
    effects: list[EffectSpec] = Field(default_factory=list)

    @model_validator(mode="after")
    def _unique_ids(self):
        keys = [e.key for e in self.effects]
        dupes = sorted({k for k in keys if keys.count(k) > 1})
        if dupes:
            raise ValueError(f"effect ids must be unique; repeated: {dupes} (set 'id')")
        return self


class PhysicsModel:
    """Rigid-body dynamics plus enabled effects; computes torques for a motion."""

    def __init__(self, config: PhysicsModelConfig | None = None) -> None:
        self.config = config if config is not None else PhysicsModelConfig()
        self.robot = RigidBodyModel(self.config.rigid_body)
        self.effects: dict[str, Effect] = {}
        for spec in self.config.effects:
            if spec.enabled:
                self.effects[spec.key] = EFFECTS[spec.name](spec.params)
        for key, effect in self.effects.items():
            if isinstance(effect, Drift):
                target = self.effects.get(effect.params.target)
                if target is None or isinstance(target, Drift):
                    raise ConfigError(
                        f"drift {key!r}: target {effect.params.target!r} is not an enabled, "
                        f"non-drift effect of this model ({sorted(self.effects)})"
                    )
                effect.bind(target)

    # -- files ---------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "PhysicsModel":
        try:
            return cls(PhysicsModelConfig.model_validate(data))
        except ValidationError as exc:
            raise ConfigError(f"invalid physics model: {exc}") from exc

    @classmethod
    def load(cls, path: str | Path) -> "PhysicsModel":
        """Read a model file; raises ConfigError naming the bad value."""
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"cannot read physics model {path}: {exc}") from exc
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        return self.config.model_dump(mode="json")

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2, sort_keys=False) + "\n")

    # -- torques -------------------------------------------------------------------------
    def motion(self, t, q, dq, ddq) -> Motion:
        return Motion(np.asarray(t, float), np.asarray(q, float), np.asarray(dq, float),
                      np.asarray(ddq, float), self.robot)

    def rigid_body_torque(self, motion: Motion) -> np.ndarray:
        """Inverse dynamics (N, 6), armature included."""
        return self.robot.inverse_dynamics(motion.q, motion.dq, motion.ddq)

    def effect_torques(self, motion: Motion, stateful: bool | None = None) -> dict[str, np.ndarray]:
        """Each enabled effect's torque (N, 6), by id; filter on ``stateful`` if given."""
        return {
            key: effect.torque(motion)
            for key, effect in self.effects.items()
            if stateful is None or effect.stateful == stateful
        }

    def is_external(self, key: str) -> bool:
        return self.effects[key].name in EXTERNAL_EFFECTS

    def torque(self, motion: Motion) -> np.ndarray:
        """Total drive torque (N, 6): rigid body plus every enabled effect."""
        total = self.rigid_body_torque(motion)
        for tau in self.effect_torques(motion).values():
            total = total + tau
        return total
