"""Hidden-effect cases: simulate a recording with an effect the given model lacks.

The discrepancy workflow (:mod:`wrenchd.models.discrepancy`) is only worth trusting on real
data if it finds effects whose truth is known. For each effect of the library that free motion
can reveal, :func:`make_case` simulates the PSM (the ``free-space`` scenario's workspace and
physics: rigid body, Coulomb, viscous and Stribeck friction, wrist cable coupling) with that
effect switched on at a random magnitude in its realistic range (:func:`sample_effect`, with
the ranges and their sources: WPI's identification, van den Dobbelsteen 2007), and gives the
workflow the model *without* it. :func:`judge` then checks that the effect is named first, its
parameters are within the stated tolerance (:data:`TOLERANCE`, relative), and the held-out gap
(RMS above the noise floor [N m; N], on the joints the effect acts on) shrank by at least
:data:`MIN_SHRINK`.

Not tested: ``external_contact`` (not free motion) and ``inertial_delta`` (the identified rigid
body, never a candidate); see :data:`wrenchd.models.discrepancy.candidates.NOT_CANDIDATES`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np

from wrenchd.adapters.sim.scenarios import FREE_SPACE_EFFECTS, FREE_SPACE_WORKSPACE
from wrenchd.adapters.sim.sensors import SensorConfig
from wrenchd.adapters.sim.simulator import simulate
from wrenchd.adapters.sim.trajectory import FourierTrajectory
from wrenchd.models.discrepancy.candidates import SPRING_JOINTS
from wrenchd.models.discrepancy.workflow import DiscrepancyResult, excess_shrink
from wrenchd.models.physics.effects import EFFECTS
from wrenchd.models.physics.model import PhysicsModel
from wrenchd.models.series import Session

HIDDEN_EFFECTS = ("coulomb_friction", "viscous_friction", "stribeck_friction", "joint_offset",
                  "spring", "seal_friction", "body_wall", "payload_mass", "cable_coupling",
                  "drift")
PAIRS = (("payload_mass", "seal_friction"), ("joint_offset", "viscous_friction"),
         ("spring", "body_wall"), ("cable_coupling", "payload_mass"))
NOISE_STD = np.asarray(SensorConfig().effort_noise_std)
#: Relative tolerance of the checked parameters (:func:`judge`).
TOLERANCE = {"coulomb_friction": 0.15, "viscous_friction": 0.15, "stribeck_friction": 0.3,
             "joint_offset": 0.1, "spring": 0.2, "seal_friction": 0.2, "body_wall": 0.2,
             "payload_mass": 0.1, "cable_coupling": 0.25, "drift": 0.25}
MIN_SHRINK = 0.5


def _default(name: str, key: str) -> np.ndarray:
    return np.asarray(EFFECTS[name].Params().model_dump()[key], float)


def _scaled(rng, name, key, lo=0.5, hi=2.0):
    base = _default(name, key)
    return [float(v) for v in base * rng.uniform(lo, hi, base.shape)]


def sample_effect(name: str, rng: np.random.Generator, duration_s: float) -> dict[str, Any]:
    """A random effect spec of ``name`` in its realistic range.

    Ranges (sources in each effect's module docstring):

    =====================  ==========================================================================
    coulomb_friction       fc = library default (WPI identification) x U(0.5, 2) per joint
    viscous_friction       fv = default x U(0.5, 2) per joint
    stribeck_friction      fs = default x U(0.5, 2) (yaw, pitch, insertion), vs = default x U(0.5, 2)
    joint_offset           |offset| U(0.02, 0.3) N m or N on joints 1-3, U(0.003, 0.03) N m on 4-6
                           (WPI ``Fo``), random sign
    spring                 half the cases roll and wrist: stiffness U(0.002, 0.02) N m/rad (WPI wrist
                           K ~0.002 and 10x), rest U(-0.3, 0.3) rad; the other half the insertion (a
                           cable or hose pulled along the tool axis; assumed, no published figure):
                           U(5, 50) N/m, 0.5-5 N over half the stroke, rest U(0.03, 0.22) m
    seal_friction          insertion fc U(0.25, 3) N (van den Dobbelsteen 2007), fs_excess and the
                           roll values scaled alike, sigma2 default x U(0.5, 2)
    body_wall              insufflation U(8, 16) mmHg, other parameters default
    payload_mass           a third each: link 2 (parallelogram, WPI load position) U(0.05, 0.3) kg;
                           the insertion stage (link 3) U(0.05, 0.3) kg at U(-0.05, 0.05) m on each
                           axis of its frame; the instrument tip (link 6 origin) U(0.05, 0.2) kg
    cable_coupling         motor_fc U(0.002, 0.008) N m, motor_fv U(0.0015, 0.006) N m s/rad
    drift                  Coulomb friction wear, linear: fc grows by U(30, 100) % over the recording
    =====================  ==========================================================================
    """
    if name == "coulomb_friction":
        return {"name": name, "params": {"fc": _scaled(rng, name, "fc")}}
    if name == "viscous_friction":
        return {"name": name, "params": {"fv": _scaled(rng, name, "fv")}}
    if name == "stribeck_friction":
        return {"name": name, "params": {"fs": _scaled(rng, name, "fs"), "vs": _scaled(rng, name, "vs")}}
    if name == "joint_offset":
        mag = np.concatenate([rng.uniform(0.02, 0.3, 3), rng.uniform(0.003, 0.03, 3)])
        return {"name": name, "params": {"offset": [float(v) for v in mag * rng.choice([-1, 1], 6)]}}
    if name == "spring":
        k = np.zeros(6)
        rest = np.zeros(6)
        if rng.random() < 0.5:
            k[3:] = rng.uniform(0.002, 0.02, 3)
            rest[3:] = rng.uniform(-0.3, 0.3, 3)
        else:
            k[2], rest[2] = rng.uniform(5.0, 50.0), rng.uniform(0.03, 0.22)
        return {"name": name, "params": {"stiffness": k.tolist(), "rest": rest.tolist()}}
    if name == "seal_friction":
        s = rng.uniform(0.25, 3.0)          # insertion fc [N]; default 1 N
        d = EFFECTS[name].Params()
        return {"name": name, "params": {
            "fc": [d.fc[0] * s, d.fc[1] * s], "fs_excess": [d.fs_excess[0] * s, d.fs_excess[1] * s],
            "sigma2": [float(v) * rng.uniform(0.5, 2.0) for v in d.sigma2]}}
    if name == "body_wall":
        return {"name": name, "params": {"pressure_mmhg": float(rng.uniform(8.0, 16.0))}}
    if name == "payload_mass":
        site = rng.integers(3)
        if site == 0:
            return {"name": name, "params": {"mass_kg": float(rng.uniform(0.05, 0.3)), "link": 2}}
        if site == 1:
            return {"name": name, "params": {
                "mass_kg": float(rng.uniform(0.05, 0.3)), "link": 3,
                "position_m": [float(v) for v in rng.uniform(-0.05, 0.05, 3)]}}
        return {"name": name, "params": {"mass_kg": float(rng.uniform(0.05, 0.2)), "link": 6,
                                         "position_m": [0.0, 0.0, 0.0]}}
    if name == "cable_coupling":
        return {"name": name, "params": {
            "motor_fc": [float(v) for v in rng.uniform(0.002, 0.008, 2)],
            "motor_fv": [float(v) for v in rng.uniform(0.0015, 0.006, 2)]}}
    if name == "drift":
        growth = rng.uniform(0.3, 1.0)
        return {"name": name, "id": "wear", "params": {
            "target": "coulomb_friction", "param": "fc", "kind": "linear",
            "rate_per_hour": float(growth * 3600.0 / duration_s), "t_start_s": 0.0}}
    raise ValueError(f"no hidden-effect sampler for {name!r}")


@dataclass
class HiddenCase:
    """A simulated recording, the model given to the workflow, and what was hidden."""

    hidden: tuple[str, ...]
    specs: list[dict[str, Any]]          # the hidden effects' specs as simulated
    given: PhysicsModel
    truth: PhysicsModel
    session: Session
    seed: int


def make_case(hidden: tuple[str, ...] | list[str], seed: int, duration_s: float = 30.0) -> HiddenCase:
    """Simulate ``duration_s`` of free motion with ``hidden`` effects the given model lacks."""
    root = np.random.SeedSequence([seed, 6])
    traj_seed, param_seed, sensor_seed = root.spawn(3)
    rng = np.random.default_rng(param_seed)
    base = copy.deepcopy(FREE_SPACE_EFFECTS)
    given_effects = [e for e in base if e["name"] not in hidden]
    specs = [sample_effect(name, rng, duration_s) for name in hidden]
    truth_effects = copy.deepcopy(given_effects) + copy.deepcopy(specs)
    if "drift" in hidden and not any(e["name"] == "coulomb_friction" for e in truth_effects):
        truth_effects.insert(0, {"name": "coulomb_friction"})
    truth = PhysicsModel.from_dict({"description": f"hidden {list(hidden)}", "effects": truth_effects})
    given_data = {"description": "given model", "effects": given_effects}
    given = PhysicsModel.from_dict(given_data)
    trajectory = FourierTrajectory(FREE_SPACE_WORKSPACE, np.random.default_rng(traj_seed),
                                   duration_s, freq_hz=(0.05, 0.4))
    session = simulate(truth, trajectory, duration_s, sensor_seed)
    return HiddenCase(tuple(hidden), specs, given, truth, session, seed)


def _true_effect_torque(case: HiddenCase, spec: dict[str, Any]) -> np.ndarray:
    key = spec.get("id") or spec["name"]
    return case.session.truth.effects[key]


def _checks(spec: dict[str, Any], fitted: dict[str, Any], tau_rms: np.ndarray,
            floor: np.ndarray) -> list[tuple[str, float, float, bool]]:
    """(parameter, true, fitted, within tolerance) for the parameters that show in the data."""
    name, p = spec["name"], spec["params"]
    tol = TOLERANCE[name]
    full = EFFECTS[name](p).params.model_dump()
    out = []

    def check(label, true, got, weight=1.0):
        out.append((label, float(true), float(got), abs(got - true) <= tol * abs(true)))

    def per_joint(key, joints=range(6)):
        for j in joints:
            if tau_rms[j] >= 2 * floor[j]:
                check(f"{key}[{j + 1}]", full[key][j], fitted[key][j])

    if name in ("coulomb_friction", "viscous_friction"):
        per_joint({"coulomb_friction": "fc", "viscous_friction": "fv"}[name])
    elif name == "stribeck_friction":
        per_joint("fs")
    elif name == "joint_offset":
        per_joint("offset")
    elif name == "spring":
        per_joint("stiffness", SPRING_JOINTS)
    elif name == "seal_friction":
        # the sliding level at rest, fc + fs_excess, is what the data fix; the split between
        # them rests on the shape of the breakaway hump and is reported, not checked
        check("fc+fs_excess[insertion]", full["fc"][0] + full["fs_excess"][0],
              fitted["fc"][0] + fitted["fs_excess"][0])
    elif name == "body_wall":
        k = full["k0_n_per_m"] + full["k_per_mmhg"] * full["pressure_mmhg"]
        check("k [N/m]", k, fitted["k0_n_per_m"] + fitted["k_per_mmhg"] * fitted.get("pressure_mmhg", 0.0))
    elif name == "payload_mass":
        check("mass_kg", full["mass_kg"], fitted["mass_kg"] if fitted.get("link") == full["link"] else 0.0)
    elif name == "cable_coupling":
        for i in range(2):
            check(f"motor_fc[{i + 1}]", full["motor_fc"][i], fitted["motor_fc"][i])
    elif name == "drift":
        check("rate_per_hour", full["rate_per_hour"], fitted["rate_per_hour"])
    return out


def judge(case: HiddenCase, result: DiscrepancyResult) -> dict[str, Any]:
    """Did the workflow name the hidden effects, right, and close the gap?

    Per hidden effect: ``named`` (anywhere), ``first`` (the top effect is it; for two hidden
    effects, the top two are them), ``params_ok`` (every checked parameter within
    ``TOLERANCE[name]`` relative error; parameters are checked where their torque is at least
    2 noise floors on that joint), ``shrink`` (held-out excess shrink on the joints where the
    true effect's torque RMS is at least half the noise floor; >= ``MIN_SHRINK`` passes).
    """
    effects = result.effects_json()
    names = [e["name"] for e in effects]
    floor = result.floor
    per = []
    for spec in case.specs:
        tau = _true_effect_torque(case, spec)
        rms = np.sqrt(np.mean(tau**2, axis=0))
        joints = np.flatnonzero(rms >= 0.5 * floor)
        match = next((e for e in effects if e["name"] == spec["name"]), None)
        checks = _checks(spec, match["params"], rms, floor) if match else []
        shrink = excess_shrink(result.before_rmse, result.after_rmse, floor, joints)
        per.append({"effect": spec["name"], "named": match is not None,
                    "params_ok": bool(match) and all(c[3] for c in checks),
                    "checks": [{"param": c[0], "true": c[1], "fitted": c[2], "ok": c[3]}
                               for c in checks],
                    "joints": [int(j) + 1 for j in joints], "shrink": shrink})
    top = set(names[:len(case.specs)])
    first = {s["name"] for s in case.specs} == top if case.specs else not names
    extra = [n for n in names if n not in {s["name"] for s in case.specs}]
    ok = (first and all(p["named"] and p["params_ok"] and p["shrink"] >= MIN_SHRINK for p in per)
          and (bool(case.specs) or not names))
    return {"hidden": list(case.hidden), "seed": case.seed, "named": names, "first": first,
            "extra": extra, "per_effect": per, "passed": bool(ok)}
