"""Sessions made of real recordings: free-motion truth, and recordings played one after another.

A real recording of free motion has a ground truth of its own: the tip wrench and the external
joint torque are zero, and the measured effort is all internal torque (plus the robot's
noise). :func:`free_motion_truth` writes that down in the fields the simulator fills
(:class:`~wrenchd.models.series.GroundTruth`), so replay's metrics score a real recording as
they score a simulated one.

:func:`concatenate` plays recordings one after another as one session. Time is continuous:
each part starts one sample spacing (its own median) after the previous part's last sample,
so the pipeline sees one gap-free stream at the recordings' rate. The joints themselves jump
there (the robot did not move from one recording's last pose to the next one's first; the WPI
recordings end up to 1 rad from where they start), which the pipeline meets as it would a
sudden motion: a transient of the estimate. ``metadata["seams_s"]`` lists the first sample of
every play after the first, repeats included. Every boundary where the recording changes
(not the repeats of one recording) is a set-up change, listed in ``metadata["setup_changes"]``
as ``{"id", "t_s", "from", "to"}``; :func:`~wrenchd.models.physics.effects.drift.drift_onsets`
reads them, so replay announces them with ``--announce`` and its metrics measure around them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wrenchd.models.errors import DataError
from wrenchd.models.series import GroundTruth, JointStates, Session

#: ``metadata`` key of the set-up changes of a session built from recordings.
SETUP_CHANGES_KEY = "setup_changes"


def finite_difference_acceleration(js: JointStates) -> np.ndarray:
    """(N, 6) joint accelerations [rad/s^2; m/s^2]: central differences of the measured
    velocities (one-sided at the ends; zeros for a single sample)."""
    if len(js) < 2:
        return np.zeros_like(js.velocity)
    return np.gradient(js.velocity, js.t, axis=0)


def free_motion_truth(js: JointStates) -> GroundTruth:
    """The ground truth of a free-motion recording: no tip wrench, no external torque, never
    in contact; the measured motion as the true one, the measured effort as the internal
    torque (noise included)."""
    zeros = np.zeros_like(js.effort)
    return GroundTruth(position=js.position, velocity=js.velocity,
                       acceleration=finite_difference_acceleration(js),
                       internal_torque=js.effort, external_torque=zeros,
                       external_wrench=zeros.copy(), in_contact=np.zeros(len(js), dtype=bool))


@dataclass(frozen=True)
class Part:
    """One recording of a concatenation and how many times it plays in a row.

    Attributes:
        name: the recording as given (its path); a change of name is a set-up change.
        session: its samples and truth (None: free motion, :func:`free_motion_truth`).
        times: plays in a row, >= 1.
    """

    name: str
    session: Session
    times: int = 1


def _base(name: str) -> str:
    return name.rstrip("/").rsplit("/", 1)[-1] or name


def _median_step(t: np.ndarray) -> float | None:
    return float(np.median(np.diff(t))) if len(t) > 1 else None


def concatenate(parts: list[Part], source: str = "") -> Session:
    """The parts played one after another, each ``times`` in a row (see the module docstring).

    Raises:
        DataError: no parts, a part without samples, a part played fewer than once, or no
            sample spacing to continue with (single-sample parts only).
    """
    if not parts:
        raise DataError("a concatenation needs at least one recording")
    ts, pos, vel, eff, truths, changes, played, seams = [], [], [], [], [], [], [], []
    end: float | None = None
    step: float | None = None
    previous: str | None = None
    for part in parts:
        js = part.session.joint_states
        if len(js) == 0:
            raise DataError(f"{part.name}: no samples")
        if part.times < 1:
            raise DataError(f"{part.name}: played {part.times} times; at least once")
        truth = part.session.truth if part.session.truth is not None \
            else free_motion_truth(js)
        step = _median_step(js.t) or step
        if step is None:
            raise DataError(f"{part.name}: one sample and no spacing to continue with")
        rel = js.t - js.t[0]
        for _ in range(part.times):
            start = 0.0 if end is None else end + step
            if end is not None:
                seams.append(start)
            if previous is not None and previous != part.name:
                changes.append({"id": f"recording:{_base(part.name)}", "t_s": round(start, 9),
                                "from": previous, "to": part.name})
            ts.append(start + rel)
            pos.append(js.position)
            vel.append(js.velocity)
            eff.append(js.effort)
            truths.append(truth)
            end = float(ts[-1][-1])
            previous = part.name
        played.append({"name": part.name, "times": part.times, "samples": len(js)})
    joint_states = JointStates(np.concatenate(ts), np.concatenate(pos), np.concatenate(vel),
                               np.concatenate(eff), parts[0].session.joint_states.names)
    return Session(joint_states, _concatenate_truths(truths),
                   {"source": source, "recordings": played, "seams_s": seams,
                    SETUP_CHANGES_KEY: changes})


def _concatenate_truths(truths: list[GroundTruth]) -> GroundTruth:
    """One truth from several; a per-effect torque missing from a part is zero there, and
    the sensor channel is kept only when every part has one."""
    keys = list(dict.fromkeys(k for tr in truths for k in tr.effects))
    effects = {k: np.concatenate([tr.effects.get(k, np.zeros_like(tr.position))
                                  for tr in truths]) for k in keys}
    sensor = (np.concatenate([tr.sensor_wrench for tr in truths])
              if all(tr.sensor_wrench is not None for tr in truths) else None)

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(tr, name) for tr in truths])

    return GroundTruth(cat("position"), cat("velocity"), cat("acceleration"),
                       cat("internal_torque"), cat("external_torque"), cat("external_wrench"),
                       cat("in_contact"), effects, sensor)
