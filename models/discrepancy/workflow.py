"""The discrepancy workflow: find, name, add, and show the gap shrink (pure: arrays in and out).

1. **Find**: run the measured motion through the model; per-joint residual against the noise
   floor, where it concentrates, whiteness and correlation with the inputs
   (:mod:`~wrenchd.models.discrepancy.residual`).
2. **Name**: candidate effects (:mod:`~wrenchd.models.discrepancy.candidates`) tested by held-out BIC,
   bootstrap stability and size (:mod:`~wrenchd.models.discrepancy.selection`).
3. **Add**: the model plus the named effects (:func:`~wrenchd.models.discrepancy.merging.merge_effects`).
4. **Gap**: held-out (out-of-fold) residual RMS per joint before and after.

The JSON contract (:meth:`DiscrepancyResult.to_json`)::

    {"disagreements": [{"joint": 1, "rmse": ..., "noise_floor": ..., "where": "..."}],
     "effects": [{"name": "payload_mass", "joints": [1, 2], "params": {...},
                  "evidence": {"delta_bic": ..., "stability": ...}}],
     "gap": {"before_rmse": [...], "after_rmse": [...], "heldout": true},
     "updated_model": "path"}

``disagreements`` lists the joints whose residual RMS exceeds ``DISAGREE_RATIO`` times the
noise floor; ``effects`` is ordered by evidence (most negative ``delta_bic`` first) and empty
when nothing has real support; joints are numbered from 1. Each effect lists its
``alternatives``: other candidates (kinds or places) that reproduce its fitted torque almost
as well, and ``told_apart`` is false when one of them leaves less of it than an effect must
reach to be named: the motion cannot tell the two apart. Extra keys (``joints``,
``candidates``, ``gap.noise_floor``, ``gap.excess_shrink``...) add detail without changing
these.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wrenchd.models.discrepancy.candidates import NOT_CANDIDATES, build_candidates
from wrenchd.models.discrepancy.merging import merge_effects
from wrenchd.models.discrepancy.residual import find, noise_floor
from wrenchd.models.discrepancy.selection import (
    Alternative,
    Named,
    Stacked,
    alternatives,
    heldout_prediction,
    select,
)
from wrenchd.models.errors import DataError
from wrenchd.models.identification.differentiation import smoothed_acceleration, zero_phase_velocity
from wrenchd.models.physics.model import PhysicsModel

#: A named effect "acts on" a joint when its fitted torque there reaches this many floors.
JOINT_SHARE = 0.25
FORMAT = "wrenchd.discrepancy/1"


def excess(rmse: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """RMS above the noise floor, in quadrature, per joint: ``sqrt(max(rmse^2 - floor^2, 0))``."""
    return np.sqrt(np.maximum(rmse**2 - floor**2, 0.0))


def excess_shrink(before: np.ndarray, after: np.ndarray, floor: np.ndarray,
                  joints: np.ndarray | None = None) -> float:
    """Fraction of the excess (in noise floors, summed in quadrature) the fix removed.

    1 = residual down to the noise floor, 0 = no change, negative = worse. ``joints``
    (0-based) restricts it; default: every joint.
    """
    sel = np.arange(6) if joints is None else np.asarray(joints, int)
    e0 = np.sum((excess(before, floor) / floor)[sel] ** 2)
    e1 = np.sum((excess(after, floor) / floor)[sel] ** 2)
    return float(1.0 - np.sqrt(e1 / e0)) if e0 > 0 else 0.0


@dataclass
class DiscrepancyResult:
    """Everything one run found (arrays for plots, dicts for the JSON and the report)."""

    t: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    residual: np.ndarray               # (N, 6) measured - model [N m; N]
    floor: np.ndarray                  # (6,)
    findings: list[dict]
    named: list[Named]
    effect_torque: dict[str, np.ndarray]   # label -> (N, 6) full-data fitted torque
    heldout_prediction: np.ndarray     # (N, 6) out-of-fold torque of all named effects
    updated_model: PhysicsModel
    candidates: list[dict]
    notes: list[str] = field(default_factory=list)
    #: label of a named effect -> other candidates that reproduce its torque (best first)
    alternatives: dict[str, list[Alternative]] = field(default_factory=dict)

    @property
    def before_rmse(self) -> np.ndarray:
        return np.sqrt(np.mean(self.residual**2, axis=0))

    @property
    def after_rmse(self) -> np.ndarray:
        return np.sqrt(np.mean((self.residual - self.heldout_prediction) ** 2, axis=0))

    def effect_joints(self, nm: Named) -> list[int]:
        tau = self.effect_torque[nm.candidate.label]
        ratio = np.sqrt(np.mean(tau**2, axis=0)) / self.floor
        return [int(j) + 1 for j in np.flatnonzero(ratio >= JOINT_SHARE)]

    def effects_json(self) -> list[dict[str, Any]]:
        out = []
        for nm in self.named:
            c = nm.candidate
            beta = nm.full_beta()
            ev = nm.evidence
            tau = self.effect_torque[c.label]
            out.append({
                "name": c.name, "label": c.label, "joints": self.effect_joints(nm),
                "params": c.to_params(beta),
                "coefficients": {n: float(b) for n, b in zip(c.names, beta)},
                "std_errors": {c.names[i]: float(s) for i, s in zip(nm.keep, nm.bse)},
                "evidence": {"delta_bic": ev.delta_bic, "stability": ev.stability,
                             "folds_in_favour": ev.folds_in_favour, "size_noise_floors": ev.size,
                             "entry_delta_bic": ev.entry_delta_bic},
                "rms_torque": [float(v) for v in np.sqrt(np.mean(tau**2, axis=0))],
                "alternatives": [{"label": a.label, "r2": a.r2, "misfit_noise_floors": a.misfit,
                                  "indistinguishable": a.indistinguishable}
                                 for a in self.alternatives.get(c.label, [])],
                "told_apart": not any(a.indistinguishable
                                      for a in self.alternatives.get(c.label, [])),
            })
        return out

    def to_json(self, updated_model_path: str | None) -> dict[str, Any]:
        before, after = self.before_rmse, self.after_rmse
        return {
            "format": FORMAT,
            "disagreements": [
                {"joint": f["joint"], "rmse": f["rmse"], "noise_floor": f["noise_floor"],
                 "where": f["where"]} for f in self.findings if f["disagrees"]],
            "effects": self.effects_json(),
            "gap": {"before_rmse": before.tolist(), "after_rmse": after.tolist(),
                    "heldout": True, "noise_floor": self.floor.tolist(),
                    "before_excess": excess(before, self.floor).tolist(),
                    "after_excess": excess(after, self.floor).tolist(),
                    "excess_shrink": excess_shrink(before, after, self.floor)},
            "updated_model": updated_model_path,
            "joints": self.findings,
            "candidates": self.candidates,
            "not_candidates": NOT_CANDIDATES,
            "notes": self.notes,
            "samples": int(self.t.shape[0]),
        }


def run_discrepancy(model: PhysicsModel, t: np.ndarray, q: np.ndarray, dq: np.ndarray,
                    tau: np.ndarray, seed: int = 0) -> DiscrepancyResult:
    """Find, name and add what ``model`` misses in the measured free motion.

    Args:
        model: the physics model to test.
        t: (N,) [s]; q, dq, tau: (N, 6) measured positions, velocities, efforts.
        seed: bootstrap seed.

    Raises:
        DataError: fewer than 500 samples (five folds of at least 100).
    """
    t, q, dq, tau = (np.asarray(a, float) for a in (t, q, dq, tau))
    if t.shape[0] < 500:
        raise DataError(f"discrepancy needs at least 500 samples, got {t.shape[0]}")
    dq, from_position = zero_phase_velocity(t, q, dq)
    ddq = smoothed_acceleration(t, dq)
    motion = model.motion(t, q, dq, ddq)
    residual = tau - model.torque(motion)
    floor = noise_floor(residual, model)
    findings = find(t, q, dq, ddq, residual, floor)
    regressor = model.robot.regressor(q, dq, ddq)
    cands = build_candidates(motion, model, residual, floor, regressor)
    st = Stacked(residual, floor, t, seed)
    named, table = select(st, cands)
    alts = alternatives(st, named, cands)
    torques = {nm.candidate.label: nm.candidate.torque(nm.full_beta()) for nm in named}
    pred = heldout_prediction(st, named)
    updated, notes = merge_effects(
        model, [(nm.candidate, nm.candidate.to_params(nm.full_beta())) for nm in named],
        description=(model.config.description + " + " if model.config.description else "")
        + "effects named by wrenchd discrepancy: "
        + (", ".join(nm.candidate.label for nm in named) or "none"))
    notes.append("velocity from positions (zero phase) on joints "
                 f"{[int(j) + 1 for j in np.flatnonzero(from_position)]}, recorded elsewhere")
    return DiscrepancyResult(t, q, dq, ddq, residual, floor, findings, named, torques, pred,
                             updated, table, notes, alts)
