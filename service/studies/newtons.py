"""Newtons at the tip on real recordings: the free-motion force each model publishes, and
known loads.

On free motion the true tip force is zero, so the force part of the wrench that a model's
external torque maps to (``WrenchMap``, the served map) is all error (``tip_force_N``: RMS and
95th percentile of its norm per model), beside ``measured_cf`` (the effort alone through
``J^-T``, as the dVRK computes it), ``measured_cf_minus_gravity`` (less the gravity torque the
least squares identify: velocity and acceleration zero) and the repeatability floor through
the same map (``tip_force_floor_N``).

Known loads (``known_loads``): a mass at a given point of a given link
(:mod:`wrenchd.models.physics.point_load`) gives the expected external torques; each model's
estimated external torque is scored against them and the mass refitted with the point held,
also with gravity turned about the yaw axis (:data:`GRAVITY_TILTS_DEG`) as a sensitivity to the
assumed gravity direction (the base frame's -z), and with the point moved by
:data:`POINT_SHIFT_M` along the link's x and y as a sensitivity to the given point. Two runs of
the same path with different loads give how far the runs themselves differ beyond the loads
(``known_load_pairs``, :func:`run_to_run`): the limit on one run's fitted mass.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.series import JointStates
from wrenchd.service.studies.real_data import Source, at_rate, rmse

if TYPE_CHECKING:
    from wrenchd.service.studies.real_data import Trained


def force_stats(force: np.ndarray) -> dict[str, float]:
    """RMS, 95th percentile and per-axis RMS [N] of forces (N, 3)."""
    norm = np.linalg.norm(force, axis=1)
    return {"rms": float(np.sqrt(np.mean(norm ** 2))), "p95": float(np.quantile(norm, 0.95)),
            "rms_xyz": np.sqrt(np.mean(force ** 2, axis=0)).tolist()}


def tip_forces(q: np.ndarray, external: np.ndarray) -> np.ndarray:
    """Force part (N, 3) [N] of the served map's wrench for external torques (N, 6)."""
    from wrenchd.models.estimator.wrench import WrenchMap

    return WrenchMap().wrench_batch(q, external)[:, :3]


def tip_force_table(trained: Trained, js: JointStates) -> dict[str, dict[str, float]]:
    """``{model: {rms, p95, rms_xyz}}`` [N] of the free-motion tip force on one series."""
    preds = trained.predict(js)
    out = {"measured_cf": force_stats(tip_forces(js.position, js.effort))}
    if "ls" in trained.models:
        zeros = np.zeros_like(js.velocity)
        gravity = trained.ls.predict(js.position, zeros, zeros)
        out["measured_cf_minus_gravity"] = force_stats(tip_forces(js.position,
                                                                   js.effort - gravity))
    for key, pred in preds.items():
        if not key.startswith("_"):
            out[key] = force_stats(tip_forces(js.position, js.effort - pred))
    return out


def tip_force_floor(js: JointStates, period_s: float) -> dict[str, float]:
    """The repeatability floor at the tip: the torque difference one period apart, over
    sqrt 2, through the served map (at the later sample's pose)."""
    p = int(round(period_s / float(np.median(np.diff(js.t)))))
    diff = (js.effort[p:] - js.effort[:-p]) / np.sqrt(2.0)
    return force_stats(tip_forces(js.position[p:], diff))


@dataclass(frozen=True)
class KnownLoad:
    """A recording with ``mass_kg`` added at ``point`` [m] in ``link``'s frame."""

    source: Source
    mass_kg: float
    link: str
    point: tuple[float, float, float]

    @classmethod
    def parse(cls, spec: str) -> KnownLoad:
        """``FILE:MASS_KG:LINK:X,Y,Z`` (FILE may carry a window, ``file:a:b``).

        Raises:
            ConfigError: the parts' count, a mass that is not a positive number, or a
                ``LINK:X,Y,Z`` that :func:`~wrenchd.models.physics.point_load.parse_link_point`
                refuses (its message).
        """
        from wrenchd.models.physics.point_load import parse_link_point

        parts = spec.rsplit(":", 3)
        if len(parts) != 4:
            raise ConfigError(f"known load {spec!r}: expected FILE:MASS_KG:LINK:X,Y,Z")
        path, mass, link, xyz = parts
        try:
            mass_kg = float(mass)
        except ValueError:
            raise ConfigError(f"known load {spec!r}: the mass [kg] must be a number") from None
        if not (np.isfinite(mass_kg) and mass_kg > 0):
            raise ConfigError(f"known load {spec!r}: expected a positive mass [kg]")
        try:
            link, point = parse_link_point(f"{link}:{xyz}")
        except DataError as exc:
            raise ConfigError(f"known load {spec!r}: {exc}") from None
        return cls(Source.parse(path), mass_kg, link, tuple(point.tolist()))


#: Rotations of gravity about the yaw axis [deg] over which the fitted mass's sensitivity to
#: the assumed gravity direction is reported.
GRAVITY_TILTS_DEG = (-5.0, 5.0)
#: Shift [m] of the load's point along the link frame's x and y (each way) over which the
#: fitted mass's sensitivity to the given point is reported: the WPI photographs' positions
#: were read off a tape, "a centimetre either way is plausible" (../shared/data/wpi-psm).
POINT_SHIFT_M = 0.01


def _yaw_axis() -> np.ndarray:
    from wrenchd.models.physics.point_load import link_poses

    return link_poses(np.zeros((1, 6)), "outer_yaw")[0, :3, 2]


def _rotated_gravity(degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    from wrenchd.models.physics.dynamics import RigidBodyConfig

    g = np.asarray(RigidBodyConfig().gravity_mps2, np.float64)
    return Rotation.from_rotvec(np.deg2rad(degrees) * _yaw_axis()).apply(g)


def fitted_mass(expected_per_kg: np.ndarray, external: np.ndarray) -> float:
    """Least-squares mass [kg] with the point held (:func:`~wrenchd.models.physics.point_load.
    fit_mass`)."""
    from wrenchd.models.physics.point_load import fit_mass

    return fit_mass(expected_per_kg, external)["mass_kg"]


@dataclass
class LoadRun:
    """One known load's recording on the scoring grid: the expected torque per kilogram at
    the load's point and each model's estimated external torque (effort minus prediction)."""

    load: KnownLoad
    js: JointStates
    rate_hz: float
    per_kg: np.ndarray
    external: dict[str, np.ndarray]


def load_runs(trained: Trained, loads: Sequence[KnownLoad]) -> list[LoadRun]:
    """Each load's recording at the hybrid's rate with every model's external torque."""
    from wrenchd.models.physics.point_load import point_load_torque

    runs = []
    for load in loads:
        js = load.source.load()
        rate_hz = 1.0 / float(np.median(np.diff(js.t)))
        if hasattr(trained, "hybrid"):
            js = at_rate(js, trained.hybrid.acceleration.dt_s)
        dt = float(np.median(np.diff(js.t)))
        per_kg = point_load_torque(js.position, load.link, np.asarray(load.point), dt)
        external = {key: js.effort - pred for key, pred in trained.predict(js).items()
                    if not key.startswith("_")}
        runs.append(LoadRun(load, js, rate_hz, per_kg, external))
    return runs


def known_load_study(runs: Sequence[LoadRun]) -> list[dict[str, Any]]:
    """Expected against estimated external torques for each known load's run
    (:func:`load_runs`), JSON-ready."""
    from wrenchd.models.physics.point_load import point_load_torque

    out = []
    for run in runs:
        load, js, rate_hz, per_kg = run.load, run.js, run.rate_hz, run.per_kg
        dt = float(np.median(np.diff(js.t)))
        point = np.asarray(load.point)
        static_per_kg = point_load_torque(js.position, load.link, point)
        joints = np.flatnonzero(np.sqrt(np.mean(per_kg ** 2, axis=0)) > 1e-9)
        expected = load.mass_kg * per_kg
        rec: dict[str, Any] = {
            "file": load.source.label, "mass_kg": load.mass_kg, "link": load.link,
            "rate_hz": rate_hz, "scored_at_hz": 1.0 / dt,
            "point_m": list(load.point), "joints": (joints + 1).tolist(),
            "gravity_mps2": list(_rotated_gravity(0.0)),
            "expected_rms": np.sqrt(np.mean(expected ** 2, axis=0)).tolist(), "models": {}}
        # the same load under gravity turned about the yaw axis: one per tilt, every model
        tilted = {f"{deg:+g}": point_load_torque(js.position, load.link, point, dt,
                                                 _rotated_gravity(deg))
                  for deg in GRAVITY_TILTS_DEG}
        # the same load at the point moved along the link's x and y: every model
        shifted = {}
        for axis, name in ((0, "x"), (1, "y")):
            for sign in (-1.0, 1.0):
                moved = point.copy()
                moved[axis] += sign * POINT_SHIFT_M
                shifted[f"{name}{sign * POINT_SHIFT_M * 100:+g}cm"] = point_load_torque(
                    js.position, load.link, moved, dt)
        for key, external in run.external.items():
            force = tip_forces(js.position, external - expected)
            rec["models"][key] = {
                "fitted_mass_kg": fitted_mass(per_kg, external),
                "fitted_mass_static_kg": fitted_mass(static_per_kg, external),
                "fitted_mass_gravity_rotated_kg": {
                    tilt: fitted_mass(torque, external) for tilt, torque in tilted.items()},
                "fitted_mass_point_moved_kg": {
                    move: fitted_mass(torque, external) for move, torque in shifted.items()},
                "torque_rmse": rmse(external, expected),
                "force_error_N": force_stats(force)}
        rec["served"] = "hybrid" if "hybrid" in rec["models"] else next(iter(rec["models"]))
        served = rec["models"][rec["served"]]
        rec["fitted_mass_kg"] = served["fitted_mass_kg"]
        rec["mass_error"] = served["fitted_mass_kg"] / load.mass_kg - 1.0
        rec["fitted_mass_point_moved_kg"] = served["fitted_mass_point_moved_kg"]
        rec["torque_rmse"] = served["torque_rmse"]
        rec["force_error_N"] = served["force_error_N"]
        out.append(rec)
    return out


#: Two known-load runs follow the same path where their joint positions (yaw, pitch,
#: insertion) agree within this [rad; m] sample by sample: the WPI loaded runs of trajectory
#: one agree within a few milliradians (../shared/data/wpi-psm/README.md).
SAME_PATH_TOL = 0.01


def _path_apart(a: LoadRun, b: LoadRun) -> float | None:
    """The largest difference [rad; m] of two runs' yaw, pitch and insertion, sample by
    sample; None where they cannot be one path (another link or rate, or lengths more than
    5 % apart)."""
    n = min(len(a.js), len(b.js))
    if a.load.link != b.load.link or abs(a.rate_hz / b.rate_hz - 1.0) > 0.01 or n < 0.95 * max(
            len(a.js), len(b.js)):
        return None
    return float(np.abs(a.js.position[:n, :3] - b.js.position[:n, :3]).max())


def run_to_run(runs: Sequence[LoadRun]) -> list[dict[str, Any]]:
    """What two runs of the same path with different loads on the same link tell apart.

    The difference of their external torques, sample by sample, is fitted to the difference
    of the loads' expected torques (the heavier load's point held, the lighter load's torque
    taken as given). Whatever error a model makes on the path itself cancels; with the
    measured efforts alone (``effort``) no model enters at all. What remains is how much the
    two runs differ beyond the loads: a limit on any one run's fitted mass, whatever the
    model. ``per_run_kg``: the difference's error over sqrt 2, one run's share where the two
    runs' errors are alike and independent.
    """
    out = []
    for i, a in enumerate(runs):
        for b in runs[i + 1:]:
            apart = _path_apart(a, b)
            if a.load.mass_kg == b.load.mass_kg or apart is None or apart >= SAME_PATH_TOL:
                continue
            light, heavy = sorted((a, b), key=lambda r: r.load.mass_kg)
            n = min(len(light.js), len(heavy.js))
            known = light.load.mass_kg * (heavy.per_kg[:n] - light.per_kg[:n])
            diffs = {"effort": heavy.js.effort[:n] - light.js.effort[:n]}
            diffs.update({key: heavy.external[key][:n] - light.external[key][:n]
                          for key in heavy.external if key in light.external})
            fitted = {key: fitted_mass(heavy.per_kg[:n], d - known) for key, d in diffs.items()}
            expected = heavy.load.mass_kg - light.load.mass_kg
            served = "hybrid" if "hybrid" in fitted else "effort"
            error = fitted[served] - expected
            out.append({
                "files": [light.load.source.label, heavy.load.source.label],
                "masses_kg": [light.load.mass_kg, heavy.load.mass_kg],
                "rate_hz": light.rate_hz,
                "path_difference_max": apart,
                "expected_difference_kg": expected,
                "fitted_difference_kg": {k: float(v) for k, v in fitted.items()},
                "served": served, "error_kg": float(error),
                "per_run_kg": float(abs(error) / np.sqrt(2.0))})
    return out
