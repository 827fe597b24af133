"""Simulated trocar and tip contacts added to a recorded session: real motion and noise, known truth.

A real free-motion recording has the robot's own noise (hysteresis, run-to-run drift,
non-Gaussian residuals) but no port and no contact. :func:`inject` adds both to its efforts
with the simulator's own effects, drawn from one seed:

* the trocar: the cannula seal (:mod:`~wrenchd.models.physics.effects.seal`) and the body wall
  (:mod:`~wrenchd.models.physics.effects.body_wall`) of a patient drawn as patient variation
  draws one (:func:`~wrenchd.adapters.sim.patients.draw_patient`, default ranges), driven by the
  session's own joint motion;
* contact episodes at the tip: a force only (no torque), in a fixed direction drawn uniformly
  on the sphere, of peak ``PEAK_N`` (uniform), lasting ``LENGTH_S`` (uniform), rising and
  falling over a raised cosine of ``RAMP_S`` (at most a third of the episode) around a
  plateau; episodes start after ``contact_free_s`` (the pipeline's contact-free calibration)
  and are separated by free motion (1 s plus an exponential gap of mean ``every_s``, as the
  simulated scenarios draw them: :func:`~wrenchd.adapters.sim.scenarios.contact_episodes`).
  The drive supplies ``tau = J_hybrid(q)^T [f; 0]`` (force in base axes at the tip,
  :meth:`~wrenchd.models.physics.effects.contact.ExternalContact.torque_from_wrench`).

The truth is recorded as a simulated session's is: ``internal_torque`` gains the seal and wall,
``external_torque`` the contact torque, ``external_wrench`` and ``in_contact`` the episodes,
``effects`` each added torque by name. The efforts change by exactly
``seal + wall + J^T f`` (N m; N for insertion). Metadata: ``metadata["injection"]`` (seed, the
episodes with their peak [N] and direction) and ``metadata["patient"]`` as the simulator
records a drawn patient.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from wrenchd.adapters.sim.patients import PatientRanges, apply_patient, draw_patient
from wrenchd.adapters.sim.scenarios import BODY_WALL, SEAL, contact_episodes
from wrenchd.models.errors import ConfigError
from wrenchd.models.physics.effects.contact import ExternalContact
from wrenchd.models.physics.model import PhysicsModel
from wrenchd.models.recorded import free_motion_truth
from wrenchd.models.series import GroundTruth, JointStates, Session

#: Peak tip force of an episode, uniform [N].
PEAK_N = (1.0, 6.0)
#: Length of an episode, uniform [s].
LENGTH_S = (0.5, 4.0)
#: Rise and fall of an episode's force [s] (at most a third of the episode).
RAMP_S = 0.25
#: Mean of the exponential part of the free gap between episodes [s].
EVERY_S = 8.0
#: No contact before this long after the first sample [s]: the pipeline's calibration.
CONTACT_FREE_S = 60.0


def episode_profile(t: np.ndarray, start: float, end: float) -> np.ndarray:
    """(N,) force scale in [0, 1]: a raised-cosine rise from ``start`` and fall to ``end``
    [s] of ``min(RAMP_S, (end - start) / 3)`` each around a plateau of 1; 0 outside."""
    ramp = min(RAMP_S, (end - start) / 3.0)
    w = np.clip(np.minimum(t - start, end - t) / ramp, 0.0, 1.0)
    return np.where((t >= start) & (t < end), 0.5 - 0.5 * np.cos(np.pi * w), 0.0)


def draw_contacts(rng: np.random.Generator, t: np.ndarray, contact_free_s: float = CONTACT_FREE_S,
                  every_s: float = EVERY_S) -> list[dict[str, Any]]:
    """Contact episodes over the times ``t`` [s]: ``start_s``, ``end_s``, ``peak_n`` and a unit
    ``direction`` (base axes) each (see the module docstring)."""
    t0 = float(t[0])
    spans = contact_episodes(rng, float(t[-1]) - t0, every_s, length_s=LENGTH_S,
                             start_s=contact_free_s)
    out = []
    for start, end in spans:
        d = rng.normal(size=3)
        out.append({"start_s": t0 + start, "end_s": t0 + end,
                    "peak_n": float(rng.uniform(*PEAK_N)),
                    "direction": (d / np.linalg.norm(d)).tolist()})
    return out


def contact_wrench(t: np.ndarray, episodes: list[dict[str, Any]]) -> np.ndarray:
    """(N, 6) tip wrench [N, N m] of ``episodes`` (:func:`draw_contacts`): force only."""
    wrench = np.zeros((len(t), 6))
    for e in episodes:
        scale = episode_profile(t, e["start_s"], e["end_s"]) * e["peak_n"]
        wrench[:, :3] += scale[:, None] * np.asarray(e["direction"])[None, :]
    return wrench


def inject(session: Session, seed: int, ranges: PatientRanges | None = None,
           contact_free_s: float = CONTACT_FREE_S, every_s: float = EVERY_S) -> Session:
    """``session`` with the trocar of a patient and contact episodes drawn with ``seed`` added
    to its efforts and truth (see the module docstring). A session without truth is taken
    as free motion (:func:`~wrenchd.models.recorded.free_motion_truth`).

    Raises:
        ConfigError: a negative seed.
    """
    if seed < 0:
        raise ConfigError(f"inject: the seed must be an integer >= 0, got {seed}")
    ranges = ranges if ranges is not None else PatientRanges()
    js = session.joint_states
    base = session.truth if session.truth is not None else free_motion_truth(js)
    patient_seed, contact_seed = np.random.SeedSequence(seed).spawn(2)
    patient = draw_patient(ranges, np.random.default_rng(patient_seed))
    physics = PhysicsModel.from_dict({
        "description": "trocar injected into a recorded session",
        "effects": apply_patient([dict(SEAL), dict(BODY_WALL)], patient)})
    motion = physics.motion(js.t, base.position, base.velocity, base.acceleration)
    trocar = physics.effect_torques(motion)                    # seal_friction, body_wall
    episodes = draw_contacts(np.random.default_rng(contact_seed), js.t, contact_free_s,
                             every_s) if len(js) > 1 else []
    wrench = contact_wrench(js.t, episodes)
    contact = np.linalg.norm(wrench[:, :3], axis=1) > 0
    contact_tau = ExternalContact.torque_from_wrench(motion, wrench, contact)
    trocar_tau = sum(trocar.values())
    effort = js.effort + trocar_tau + contact_tau
    effects = {**base.effects, **{k: base.effects.get(k, 0.0) + v for k, v in trocar.items()},
               "external_contact": base.effects.get("external_contact", 0.0) + contact_tau}
    truth = GroundTruth(
        position=base.position, velocity=base.velocity, acceleration=base.acceleration,
        internal_torque=base.internal_torque + trocar_tau,
        external_torque=base.external_torque + contact_tau,
        external_wrench=base.external_wrench + wrench, in_contact=base.in_contact | contact,
        effects=effects, sensor_wrench=base.sensor_wrench)
    meta = dict(session.metadata)
    meta["injection"] = {"seed": seed, "contact_free_s": contact_free_s, "every_s": every_s,
                         "peak_n": list(PEAK_N), "length_s": list(LENGTH_S),
                         "ramp_s": RAMP_S, "episodes": episodes,
                         "inner_source": session.metadata.get("source")}
    meta["patient"] = {"variation": True, "ranges": ranges.model_dump(mode="json"),
                       "draw": patient}
    return Session(JointStates(js.t, js.position, js.velocity, effort, js.names), truth, meta)
