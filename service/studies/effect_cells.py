"""The effect-cell study: every (kind, place) an effect can take, at sizes set in noise floors.

The hidden-effect study (:mod:`wrenchd.service.studies.hidden_effects`) draws each effect in
its realistic range; it cannot say whether the workflow tells a load on the insertion stage
from one on the parallelogram, or a spring on the insertion from an offset. Here each *cell*
is one effect kind at one place (:data:`CELLS`), added to the ``free-space`` physics at a size
of 2, 5 or 20 times the effort noise on the joint it shows most on (:data:`MULTIPLES`), and
the workflow is given the model without it. Each run is classed (:func:`classify`):

* ``right``: the first named effect is the cell's kind at the cell's place, its size within
  :data:`SIZE_TOLERANCE`;
* ``size off``: kind and place right, the size not;
* ``wrong place``: the kind right, the place not (a per-joint effect's place is the joint its
  fitted torque is largest on, in noise floors; a payload's is its link);
* ``wrong kind``: another effect named first;
* ``not named``: nothing named.

Every run also records whether the workflow said it could not tell the effect it named from
another candidate (``told_apart``). Seeds start at :data:`FIRST_SEED`, far from the seeds the
workflow was tuned on (the hidden-effect study's 0-14 and 1000-1004, the tests' 101-107).

Sizes are set without a second simulation: the simulator's motion follows the trajectory
whatever the effects, and a cell's torque is linear in its parameter, so the effort of the
run at size ``s`` is the effort at size 1 plus ``(s - 1)`` times the effect's torque there.
"""

from __future__ import annotations

import copy
import json
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wrenchd.adapters.sim.scenarios import FREE_SPACE_EFFECTS, FREE_SPACE_WORKSPACE
from wrenchd.adapters.sim.simulator import simulate
from wrenchd.adapters.sim.trajectory import FourierTrajectory
from wrenchd.models.discrepancy.candidates import PAYLOAD_SITES
from wrenchd.models.discrepancy.workflow import DiscrepancyResult, run_discrepancy
from wrenchd.models.physics.model import PhysicsModel
from wrenchd.models.series import Session
from wrenchd.service.provenance import PROVENANCE_KEY, RunMeter, provenance
from wrenchd.service.runtime import stopping
from wrenchd.service.studies.hidden_effects import NOISE_STD

#: Payload positions per carrying link, in its DH frame [m]: the yaw link 10 cm from its
#: origin in a direction with both of its first moments, the parallelogram and the tip at
#: their candidates' points (:data:`PAYLOAD_SITES`: on the parallelogram only the first
#: moment shows, and the mass is read at that lever), the insertion stage at a point drawn
#: per run (:func:`cell_spec`).
PAYLOAD_POINTS = {1: (0.06, 0.08, 0.0), **{link: PAYLOAD_SITES[link] for link in (2, 6)}}
#: The cells: (effect kind, place); places are links for payloads, joints (1-based) else.
CELLS: tuple[tuple[str, int], ...] = (
    *(("payload_mass", link) for link in (1, 2, 3, 6)),
    *(("spring", j) for j in (3, 4, 5, 6)),
    *(("joint_offset", j) for j in range(1, 7)),
    *(("coulomb_friction", j) for j in range(1, 7)),
    *(("viscous_friction", j) for j in range(1, 7)),
)
#: Sizes: the effect's torque RMS on the joint it shows most on, in effort noise std.
MULTIPLES = (2.0, 5.0, 20.0)
#: A named effect's size counts as right within this relative error.
SIZE_TOLERANCE = 0.2
#: First seed of the study (see the module docstring).
FIRST_SEED = 9000
#: The classes of :func:`classify`, in the confusion table's order.
CLASSES = ("right", "size off", "wrong place", "wrong kind", "not named")
#: The kind of the control runs: nothing added, nothing should be named (one per seed and
#: multiple of the cells, so as many as a cell has).
CONTROL = "nothing"
#: The parameter a per-joint cell sets, per kind.
PER_JOINT_PARAM = {"spring": "stiffness", "joint_offset": "offset",
                   "coulomb_friction": "fc", "viscous_friction": "fv"}


def cell_spec(kind: str, place: int, value: float, rng: np.random.Generator) -> dict[str, Any]:
    """The effect spec of one cell at parameter ``value`` (mass [kg], stiffness, offset,
    Coulomb or viscous coefficient on joint ``place``), as an extra effect (id ``cell``) beside
    the scenario's own: a friction cell is a change of that joint's friction."""
    if kind == "payload_mass":
        point = (PAYLOAD_POINTS[place] if place in PAYLOAD_POINTS
                 else tuple(float(v) for v in rng.uniform(-0.05, 0.05, 3)))
        return {"name": kind, "id": "cell",
                "params": {"mass_kg": value, "link": place, "position_m": list(point)}}
    vec = np.zeros(6)
    vec[place - 1] = value
    params: dict[str, Any] = {PER_JOINT_PARAM[kind]: vec.tolist()}
    if kind == "spring":
        rest = np.zeros(6)
        rest[place - 1] = (rng.uniform(0.03, 0.22) if place == 3 else rng.uniform(-0.3, 0.3))
        params["rest"] = rest.tolist()
    return {"name": kind, "id": "cell", "params": params}


@dataclass
class CellCase:
    """One run's recording, the model given, and the cell's truth."""

    kind: str
    place: int
    multiple: float
    seed: int
    spec: dict[str, Any]          # as simulated at size 1, ``value`` the parameter used
    value: float
    strongest_joint: int          # 0-based
    given: PhysicsModel
    session: Session
    effect_torque: np.ndarray     # (N, 6) the cell's torque at ``value``


def make_cell_case(kind: str, place: int, multiple: float, seed: int,
                   duration_s: float = 30.0) -> CellCase:
    """Simulate ``duration_s`` of free motion with the cell's effect at ``multiple`` noise
    floors on its strongest joint; the given model is the scenario's physics without it."""
    root = np.random.SeedSequence([seed, 9])
    traj_seed, param_seed, sensor_seed = root.spawn(3)
    rng = np.random.default_rng(param_seed)
    control = kind == CONTROL
    spec = {} if control else cell_spec(kind, place, 1.0, rng)
    given_effects = copy.deepcopy(FREE_SPACE_EFFECTS)
    truth = PhysicsModel.from_dict({"description": f"cell {kind}@{place}",
                                    "effects": copy.deepcopy(given_effects)
                                    + ([] if control else [spec])})
    given = PhysicsModel.from_dict({"description": "given model", "effects": given_effects})
    trajectory = FourierTrajectory(FREE_SPACE_WORKSPACE, np.random.default_rng(traj_seed),
                                   duration_s, freq_hz=(0.05, 0.4))
    session = simulate(truth, trajectory, duration_s, sensor_seed)
    if control:
        zero = np.zeros_like(session.joint_states.effort)
        return CellCase(kind, place, 0.0, seed, spec, 0.0, -1, given, session, zero)
    unit = session.truth.effects["cell"]
    in_floors = np.sqrt(np.mean(unit**2, axis=0)) / NOISE_STD
    strongest = int(np.argmax(in_floors))
    value = float(multiple / in_floors[strongest])
    session.joint_states.effort[...] = session.joint_states.effort + (value - 1.0) * unit
    return CellCase(kind, place, multiple, seed, spec, value, strongest, given, session,
                    value * unit)


def _place_and_size(kind: str, effect: dict[str, Any], floor: np.ndarray,
                    truth_place: int) -> tuple[int, float]:
    """The place a named effect of ``kind`` sits at and its size at the cell's place."""
    params = effect["params"]
    if kind == "payload_mass":
        return int(params["link"]), float(params["mass_kg"])
    ratio = np.asarray(effect["rms_torque"]) / floor
    place = int(np.argmax(ratio)) + 1
    return place, float(params[PER_JOINT_PARAM[kind]][truth_place - 1])


def classify(case: CellCase, result: DiscrepancyResult) -> dict[str, Any]:
    """The run's class (:data:`CLASSES`), what was named first, and its place and size."""
    effects = result.effects_json()
    row: dict[str, Any] = {"kind": case.kind, "place": case.place, "multiple": case.multiple,
                           "seed": case.seed, "value": case.value,
                           "named": [e["label"] for e in effects]}
    if case.kind == CONTROL:
        return {**row, "class": "right" if not effects else "named something"}
    if not effects:
        return {**row, "class": "not named"}
    first = effects[0]
    row["told_apart"] = bool(first["told_apart"])
    row["alternatives"] = [a["label"] for a in first["alternatives"]]
    if first["name"] != case.kind:
        return {**row, "class": "wrong kind"}
    place, size = _place_and_size(case.kind, first, result.floor, case.place)
    row.update(named_place=place, named_size=size)
    if place != case.place:
        return {**row, "class": "wrong place"}
    ok = abs(size - case.value) <= SIZE_TOLERANCE * abs(case.value)
    return {**row, "class": "right" if ok else "size off"}


def confusion(rows: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, int]]]:
    """``{"kind@place": {multiple: {class: count}}}`` over the runs."""
    out: dict[str, dict[str, dict[str, int]]] = {}
    for r in rows:
        cell = out.setdefault(f"{r['kind']}@{r['place']}", {})
        counts = cell.setdefault(f"{r['multiple']:g}", {c: 0 for c in CLASSES})
        counts[r["class"]] += 1
    return out


def effect_cell_study(out, seeds: int, duration: float, cells=None, multiples=MULTIPLES,
                      log=print) -> dict[str, Any]:
    """Run every cell at every multiple on ``seeds`` seeds; write ``effect-cells.json`` and
    ``effect-cells.md`` (the confusion table) in ``out``; return the JSON."""
    meter = RunMeter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cells = list(cells or CELLS)
    plan = [(k, p, m, FIRST_SEED + s) for k, p in cells for m in multiples for s in range(seeds)]
    n_controls = seeds * len(multiples)
    plan += [(CONTROL, 0, 0.0, FIRST_SEED + 500 + s) for s in range(n_controls)]
    rows = []
    start = time.perf_counter()
    for i, (kind, place, mult, seed) in enumerate(plan, start=1):
        stopping.check()                  # SIGINT/SIGTERM: stop between runs, write nothing
        case = make_cell_case(kind, place, mult, seed, duration)
        js = case.session.joint_states
        t0 = time.perf_counter()
        res = run_discrepancy(case.given, js.t, js.position, js.velocity, js.effort, seed=seed)
        row = classify(case, res)
        row["discrepancy_s"] = time.perf_counter() - t0
        rows.append(row)
        log(f"[{i}/{len(plan)}] {kind}@{place} x{mult:g} seed {seed}: {row['class']} "
            f"(named {row['named']})")
    controls = [r for r in rows if r["kind"] == CONTROL]
    table = confusion([r for r in rows if r["kind"] != CONTROL])
    total = time.perf_counter() - start
    right = {cell: {m: c["right"] / max(sum(c.values()), 1) for m, c in by.items()}
             for cell, by in table.items()}
    summary = {"seeds": seeds, "first_seed": FIRST_SEED, "duration_s": duration,
               "multiples": list(multiples), "size_tolerance": SIZE_TOLERANCE,
               "cells": len(cells), "runs": len(rows),
               "cells_right_90pct": {f"{m:g}": sum(right[c].get(f"{m:g}", 0) >= 0.9 for c in right)
                                     for m in multiples},
               "controls": len(controls),
               "controls_named_something": sum(r["class"] != "right" for r in controls),
               "total_s": total, "machine": f"{platform.machine()}, {os.cpu_count()} cores"}
    data = {"summary": summary, "confusion": table, "right_rate": right, "runs": rows,
            PROVENANCE_KEY: provenance(run=meter)}
    (out / "effect-cells.json").write_text(json.dumps(data, indent=1, default=float) + "\n")
    (out / "effect-cells.md").write_text(cells_markdown(data, out))
    return data


def cells_markdown(data: dict[str, Any], out) -> str:
    """The confusion table of :func:`effect_cell_study`'s JSON as Markdown."""
    s = data["summary"]
    mults = [f"{m:g}" for m in s["multiples"]]
    lines = ["# Effect cells: every kind and place of an effect, in noise floors", "",
             f"Command: `OMP_NUM_THREADS=1 nice -n 10 wrenchd discrepancy-sweep --cells "
             f"--seeds {s['seeds']} --duration {s['duration_s']:g} --out {out}`", "",
             f"Each run simulates {s['duration_s']:g} s of free motion (the `free-space` "
             "scenario) with one effect added at one place, sized so that its torque RMS on "
             "the joint it shows most on is 2, 5 or 20 times that joint's effort noise, and "
             "gives `run_discrepancy` the model without it "
             "(`service/studies/effect_cells.py`). Seeds from "
             f"{s['first_seed']} on, none used to tune the workflow. A run is **right** when the "
             "first effect named is the right kind at the right place (payloads: the link; "
             "others: the joint its fitted torque is largest on), its size within "
             f"{100 * s['size_tolerance']:.0f} %.", "",
             "Cells named right on at least 90 % of their runs: "
             + ", ".join(f"{m}x: {s['cells_right_90pct'][m]} of {s['cells']}" for m in mults)
             + f". Controls (nothing added, seeds from {s['first_seed'] + 500}): "
             f"{s['controls_named_something']} of {s['controls']} named something.", "",
             "| cell | " + " | ".join(f"{m}x: right / size off / wrong place / wrong kind / "
                                      "not named" for m in mults) + " |",
             "|---|" + "---|" * len(mults)]
    for cell, by in data["confusion"].items():
        cols = []
        for m in mults:
            c = by.get(m)
            cols.append(" / ".join(str(c[k]) for k in CLASSES) if c else "-")
        lines.append(f"| {cell} | " + " | ".join(cols) + " |")
    wrong = [r for r in data["runs"] if r["class"] != "right"]
    if wrong:
        lines += ["", "## Runs not named right", "",
                  "| cell | size | seed | class | named | told apart | could also be |",
                  "|---|---|---|---|---|---|---|"]
        for r in wrong:
            lines.append(f"| {r['kind']}@{r['place']} | {r['multiple']:g}x | {r['seed']} | "
                         f"{r['class']} | {', '.join(r['named']) or '-'} | "
                         f"{r.get('told_apart', '-')} | {', '.join(r.get('alternatives', [])) or '-'} |")
    lines += ["", f"{s['runs']} runs, {s['total_s'] / 60:.1f} min on {s['machine']}.", ""]
    return "\n".join(lines)
