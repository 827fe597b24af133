"""The effect library: named, parameterised, composable joint-torque contributions.

Importing this package registers every effect in :data:`EFFECTS` under the name model files
use: ``coulomb_friction``, ``viscous_friction``, ``stribeck_friction``, ``joint_offset``,
``spring``, ``seal_friction``, ``body_wall``, ``payload_mass``, ``cable_coupling``, ``drift``,
``external_contact``, ``inertial_delta`` (identified base parameters).
"""

from wrenchd.models.physics.effects import (  # noqa: F401  (imported to register)
    body_wall,
    contact,
    coupling,
    drift,
    friction,
    inertial,
    payload,
    seal,
    static,
)
from wrenchd.models.physics.effects.base import EFFECTS, Effect, EffectParams, Motion, register

__all__ = ["EFFECTS", "Effect", "EffectParams", "Motion", "register"]
