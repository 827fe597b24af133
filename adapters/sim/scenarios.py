"""Named simulation scenarios: a workspace, a physics model, contacts and drifts, so that every
study, test and ``sim:`` session names the conditions it runs under by one word.

=======================  ================================================================
``free-space``           rigid body + free-space friction (Coulomb, viscous, Stribeck,
                         wrist cable coupling); wide workspace; no seal, no contact.
``free-space-seal``      the same with the instrument through a cannula seal.
``trocar``               seal + body wall at the port (insufflated at 12 mmHg), the smaller
                         workspace of work inside a phantom, slower motion, no contact.
``trocar-contact``       ``trocar`` plus contact episodes: the tip grasps a compliant handle
                         on a 6-axis force sensor (sensor channel recorded).
``insufflation-change``  ``trocar`` with the pressure stepping from 12 to 20 mmHg at 40 % of
                         the session, plus occasional contacts (sensor recorded).
``instrument-drift``     ``trocar`` with seal friction ramping up 60 % and wrist friction up
                         80 % over the session (wear), plus occasional contacts.
``insufflation-high``    ``insufflation-change`` at 20 mmHg from the start; a seed's motion,
                         contacts and noise are those of ``insufflation-change`` (the
                         reference of ``wrenchd recovery --settled``).
=======================  ================================================================

Everything random (trajectory, contact times, noise, the patient) comes from one seed, so a
scenario is reproducible to the byte. Every session is the same patient unless
:func:`run_scenario` is given patient ranges (:mod:`wrenchd.adapters.sim.patients`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.model import PhysicsModel
from wrenchd.models.series import Session
from wrenchd.adapters.sim.patients import (
    PatientRanges,
    apply_patient,
    draw_patient,
    fixed_patient,
)
from wrenchd.adapters.sim.simulator import SimulatorConfig, simulate
from wrenchd.adapters.sim.trajectory import FourierTrajectory, Workspace

FREE_SPACE_WORKSPACE = Workspace(
    lower=(-1.2, -0.75, 0.03, -2.5, -1.2, -1.2),
    upper=(1.2, 0.75, 0.22, 2.5, 1.2, 1.2),
)
#: Inside a phantom: the shaft pivots through the port, the tip stays in a smaller volume.
TROCAR_WORKSPACE = Workspace(
    lower=(-0.6, -0.45, 0.07, -1.8, -1.0, -1.0),
    upper=(0.6, 0.45, 0.19, 1.8, 1.0, 1.0),
)

FREE_SPACE_EFFECTS: list[dict[str, Any]] = [
    {"name": "coulomb_friction"},
    {"name": "viscous_friction"},
    {"name": "stribeck_friction"},
    {"name": "cable_coupling"},
]
SEAL = {"name": "seal_friction"}
BODY_WALL = {"name": "body_wall"}


@dataclass(frozen=True)
class Scenario:
    """What a scenario fixes; ``build`` turns it into a model, trajectory and contacts."""

    name: str
    description: str
    workspace: Workspace
    effects: Callable[[float], list[dict[str, Any]]]      # duration -> effect specs
    freq_hz: tuple[float, float] = (0.03, 0.3)
    contact_every_s: float | None = None                   # mean gap between contacts
    force_sensor: bool = False
    #: no contact before this time [s]: the contact-free calibration of step 2 that the
    #: two-step paper (and wrenchd's daemon) assume at the start of a procedure
    contact_free_s: float = 0.0


def _free(duration: float) -> list[dict[str, Any]]:
    return copy.deepcopy(FREE_SPACE_EFFECTS)


def _seal(duration: float) -> list[dict[str, Any]]:
    return _free(duration) + [dict(SEAL)]


def _trocar(duration: float) -> list[dict[str, Any]]:
    return _seal(duration) + [dict(BODY_WALL)]


def _insufflation(duration: float) -> list[dict[str, Any]]:
    return _trocar(duration) + [{
        "name": "drift", "id": "insufflation_step",
        "params": {"target": "body_wall", "param": "pressure_mmhg", "kind": "step",
                   "factor": 20.0 / 12.0, "t_start_s": round(0.4 * duration, 3)},
    }]


def _insufflated_high(duration: float) -> list[dict[str, Any]]:
    effects = _insufflation(duration)
    effects[-1]["params"]["t_start_s"] = 0.0      # the same step, from the first sample on
    return effects


def _wear(duration: float) -> list[dict[str, Any]]:
    start, end = round(0.1 * duration, 3), round(0.9 * duration, 3)
    return _trocar(duration) + [
        {"name": "drift", "id": "seal_wear",
         "params": {"target": "seal_friction", "param": "fc", "kind": "ramp", "factor": 1.6,
                    "t_start_s": start, "t_end_s": end}},
        {"name": "drift", "id": "wrist_wear",
         "params": {"target": "cable_coupling", "param": "motor_fc", "kind": "ramp",
                    "factor": 1.8, "t_start_s": start, "t_end_s": end}},
    ]


SCENARIOS: dict[str, Scenario] = {s.name: s for s in (
    Scenario("free-space", "free motion, no seal, wide workspace", FREE_SPACE_WORKSPACE, _free,
             freq_hz=(0.05, 0.4)),
    Scenario("free-space-seal", "free motion through a cannula seal", FREE_SPACE_WORKSPACE, _seal,
             freq_hz=(0.05, 0.4)),
    Scenario("trocar", "seal and body wall inside a phantom, no contact", TROCAR_WORKSPACE,
             _trocar, freq_hz=(0.02, 0.2)),
    Scenario("trocar-contact", "trocar with grasped-handle contacts on a force sensor",
             TROCAR_WORKSPACE, _trocar, freq_hz=(0.02, 0.2), contact_every_s=8.0,
             force_sensor=True),
    Scenario("insufflation-change", "trocar; pressure steps 12 -> 20 mmHg at 40 %",
             TROCAR_WORKSPACE, _insufflation, freq_hz=(0.02, 0.2), contact_every_s=20.0,
             force_sensor=True, contact_free_s=60.0),
    Scenario("insufflation-high", "insufflation-change at 20 mmHg from the start",
             TROCAR_WORKSPACE, _insufflated_high, freq_hz=(0.02, 0.2), contact_every_s=20.0,
             force_sensor=True, contact_free_s=60.0),
    Scenario("instrument-drift", "trocar; seal +60 % and wrist +80 % friction (wear)",
             TROCAR_WORKSPACE, _wear, freq_hz=(0.02, 0.2), contact_every_s=20.0,
             force_sensor=True, contact_free_s=60.0),
)}


def contact_episodes(rng: np.random.Generator, duration_s: float, every_s: float,
                     length_s: tuple[float, float] = (1.5, 4.0),
                     start_s: float = 0.0) -> list[list[float]]:
    """Random contact intervals after ``start_s``: gaps ~ exponential(mean ``every_s``),
    lengths uniform [s]."""
    episodes, t = [], start_s + rng.exponential(every_s) + 1.0
    while True:
        length = rng.uniform(*length_s)
        if t + length + 0.5 > duration_s:
            return episodes
        episodes.append([round(t, 3), round(t + length, 3)])
        t += length + 1.0 + rng.exponential(every_s)


def scenario_model(scenario: Scenario, duration_s: float, episodes: list[list[float]],
                   model: PhysicsModel | None, patient: dict[str, dict[str, Any]] | None = None,
                   handle_nm_per_rad: float | None = None) -> PhysicsModel:
    """The scenario's physics model, or ``model`` with the scenario's contacts put in.

    ``patient``: effect parameters by effect name (:func:`~wrenchd.adapters.sim.patients.
    draw_patient`) put into the scenario's effects; ``handle_nm_per_rad``: the contact handle's
    torsional stiffness [N m/rad] (None: the contact effect's default). A user model replaces
    the scenario's physics (neither is applied to it); if it has an ``external_contact`` effect
    without episodes, it receives the scenario's.
    """
    if model is None:
        effects = scenario.effects(duration_s)
        if patient:
            effects = apply_patient(effects, patient)
        if episodes:
            contact: dict[str, Any] = {"episodes": episodes}
            if handle_nm_per_rad is not None:
                contact["torsional_nm_per_rad"] = handle_nm_per_rad
            effects.append({"name": "external_contact", "params": contact})
        return PhysicsModel.from_dict({"description": f"scenario {scenario.name}",
                                       "effects": effects})
    data = model.to_dict()
    for spec in data["effects"]:
        if spec["name"] == "external_contact" and not spec["params"].get("episodes"):
            spec["params"]["episodes"] = episodes
    return PhysicsModel.from_dict(data)


def _streams(seed: int) -> list[np.random.SeedSequence]:
    """A session seed's random streams: trajectory, contacts, sensor noise, patient."""
    # children depend on their index only: the fourth (the patient's) leaves the others as
    # they are without variation
    return np.random.SeedSequence(seed).spawn(4)


def session_patient(seed: int, patients: PatientRanges) -> dict[str, dict[str, Any]]:
    """The patient a session of ``seed`` draws from ``patients`` (what
    :func:`run_scenario` records in ``metadata["patient"]["draw"]``), without simulating."""
    return draw_patient(patients, np.random.default_rng(_streams(seed)[3]))


def run_scenario(name: str, duration_s: float, seed: int, model: PhysicsModel | None = None,
                 config: SimulatorConfig | None = None,
                 contact_free_s: float | None = None, patients: PatientRanges | None = None,
                 handle_nm_per_rad: float | None = None,
                 force_sensor: bool | None = None,
                 patient: dict[str, dict[str, Any]] | None = None) -> Session:
    """Simulate scenario ``name`` for ``duration_s`` seconds with ``seed``.

    ``contact_free_s`` overrides the scenario's contact-free start [s]; ``patients`` draws
    this session's patient from those ranges (None: the fixed default patient);
    ``handle_nm_per_rad`` sets the contact handle's torsional stiffness [N m/rad];
    ``force_sensor`` overrides whether the sensor channel is recorded (its noise has its own
    stream, so recording it changes nothing else).

    Patients: by default every session is the same patient (the effects' default seal, body
    wall, incision and pressure). ``patients=PatientRanges()`` draws a patient per session
    instead (:mod:`wrenchd.adapters.sim.patients`: ranges and sources); the draw comes from
    its own stream of the seed, so the motion, contacts and noise of a seed are the same with
    or without variation, and it is recorded in ``metadata["patient"]``. ``patient``: this
    very patient (a draw as another session's ``metadata["patient"]["draw"]``) instead of
    one drawn from ``patients``: new motion of a patient already seen.
    """
    try:
        scenario = SCENARIOS[name]
    except KeyError:
        raise ConfigError(f"unknown scenario {name!r}; choose one of {sorted(SCENARIOS)}") from None
    if not duration_s > 0:
        raise ConfigError(f"duration must be > 0 s, got {duration_s}")
    if patient is not None and (model is not None or patients is not None):
        raise ConfigError("a given patient excludes a custom model and patient ranges")
    traj_seed, contact_seed, sensor_seed, patient_seed = _streams(seed)
    trajectory = FourierTrajectory(scenario.workspace, np.random.default_rng(traj_seed),
                                   duration_s, freq_hz=scenario.freq_hz)
    free_s = scenario.contact_free_s if contact_free_s is None else contact_free_s
    episodes = (contact_episodes(np.random.default_rng(contact_seed), duration_s,
                                 scenario.contact_every_s, start_s=free_s)
                if scenario.contact_every_s else [])
    if patients is not None:
        patient = draw_patient(patients, np.random.default_rng(patient_seed))
    sensor = scenario.force_sensor if force_sensor is None else force_sensor
    physics = scenario_model(scenario, duration_s, episodes, model, patient, handle_nm_per_rad)
    metadata = {
        "scenario": {
            "name": scenario.name, "description": scenario.description,
            "duration_s": duration_s, "seed": seed,
            "workspace": {"lower": list(scenario.workspace.lower),
                          "upper": list(scenario.workspace.upper)},
            "freq_hz": list(scenario.freq_hz), "contact_episodes": episodes,
            "contact_free_s": free_s,
            "force_sensor": sensor, "custom_model": model is not None,
            "handle_nm_per_rad": handle_nm_per_rad,
        },
        "patient": {"variation": patients is not None or patient is not None,
                    "ranges": patients.model_dump(mode="json") if patients else None,
                    "draw": (patient or fixed_patient()) if model is None else None},
    }
    return simulate(physics, trajectory, duration_s, sensor_seed, config,
                    force_sensor=sensor, metadata=metadata)
