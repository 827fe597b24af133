"""Adding named effects to a physics model: levels of an effect the model already has grow by
the fitted amount, new effects are appended, and parameters that must stay >= 0 are clipped."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from wrenchd.models.discrepancy.candidates import Candidate
from wrenchd.models.physics.model import PhysicsModel

_ADDITIVE = {
    "coulomb_friction": ("fc",), "viscous_friction": ("fv",), "stribeck_friction": ("fs",),
    "joint_offset": ("offset",), "seal_friction": ("fc", "sigma2", "fs_excess"),  # sigma0: set
    "cable_coupling": ("motor_fc", "motor_fv"), "payload_mass": ("mass_kg",),
}
_NON_NEGATIVE = {"seal_friction": ("fc", "sigma2", "fs_excess"), "payload_mass": ("mass_kg",),
                 "cable_coupling": ("motor_fc", "motor_fv"),
                 "body_wall": ("k0_n_per_m", "damping_ns_per_m")}


def _add(a, b):
    if isinstance(a, (list, tuple)):
        return [float(x) + float(y) for x, y in zip(a, b)]
    return float(a) + float(b)


def _clip(name: str, params: dict[str, Any], notes: list[str]) -> dict[str, Any]:
    for key in _NON_NEGATIVE.get(name, ()):
        value = params.get(key)
        if value is None:
            continue
        arr = np.atleast_1d(np.asarray(value, float))
        if np.any(arr < 0):
            notes.append(f"{name}.{key} fitted {arr.round(6).tolist()} < 0, clipped to 0")
            arr = np.maximum(arr, 0.0)
            params[key] = [float(v) for v in arr] if isinstance(value, (list, tuple)) else float(arr[0])
    return params


def merge_effects(model: PhysicsModel, named: list[tuple[Candidate, dict[str, Any]]],
                  description: str = "") -> tuple[PhysicsModel, list[str]]:
    """The model plus named effects (adding to an existing effect's level where one exists).

    Returns:
        (updated model, notes on clipped or adapted parameters).
    """
    data = copy.deepcopy(model.to_dict())
    notes: list[str] = []
    keys = {spec.get("id") or spec["name"] for spec in data["effects"]}
    for cand, params in named:
        params = dict(params)
        existing = None
        for spec in data["effects"]:
            if (spec["name"] != cand.name or not spec.get("enabled", True) or cand.name == "drift"
                    or (spec.get("id") or spec["name"]) not in model.effects):
                continue
            if cand.name == "payload_mass":
                current = model.effects[spec.get("id") or spec["name"]].params
                if current.link != params["link"] or not np.allclose(
                        current.position_m, params["position_m"], atol=1e-6):
                    continue
            existing = spec
            break
        if existing is not None and cand.name in _ADDITIVE:
            full = model.effects[existing.get("id") or existing["name"]].params.model_dump()
            for key in _ADDITIVE[cand.name]:
                if key in params:
                    existing["params"][key] = _add(full[key], params[key])
            for key, value in params.items():
                if key not in _ADDITIVE[cand.name]:
                    existing["params"][key] = value
            _clip(cand.name, existing["params"], notes)
            continue
        key = cand.name if cand.name not in keys else f"{cand.name}_found"
        if cand.name == "drift":
            key = f"drift_{params['target']}"
        while key in keys:
            key += "_"
        keys.add(key)
        spec = {"name": cand.name, "params": _clip(cand.name, params, notes)}
        if key != cand.name:
            spec["id"] = key
        data["effects"].append(spec)
    if description:
        data["description"] = description
    return PhysicsModel.from_dict(data), notes
