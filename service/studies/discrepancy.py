"""The two studies behind the discrepancy workflow's claims, written as committed reports.

* :func:`hidden_effect_sweep`: for every effect free motion can reveal, many seeds of a
  simulated recording with that effect hidden (random magnitude in its realistic range, see
  :mod:`wrenchd.service.studies.hidden_effects`); recall (named first, parameters within tolerance, held-out
  gap shrunk >= 50 %), false positives with nothing hidden, and pairs of hidden effects.
* :func:`real_data_study`: identify on the WPI ``one_no_weight.csv``, discrepancy against
  ``one_105g_parallel.csv`` and ``one_205g_parallel.csv``.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from wrenchd.models.discrepancy.workflow import run_discrepancy
from wrenchd.service.studies.hidden_effects import HIDDEN_EFFECTS, MIN_SHRINK, PAIRS, TOLERANCE, judge, make_case
from wrenchd.service.provenance import PROVENANCE_KEY, RunMeter, provenance
from wrenchd.service.replay.output import nan_to_none
from wrenchd.service.runtime import stopping


def _run_case(hidden: tuple[str, ...], seed: int, duration: float) -> dict[str, Any]:
    t0 = time.perf_counter()
    case = make_case(hidden, seed, duration)
    t1 = time.perf_counter()
    js = case.session.joint_states
    res = run_discrepancy(case.given, js.t, js.position, js.velocity, js.effort, seed=seed)
    t2 = time.perf_counter()
    row = judge(case, res)
    row.update({"simulate_s": t1 - t0, "discrepancy_s": t2 - t1,
                "specs": case.specs, "gap_shrink_all": res.to_json(None)["gap"]["excess_shrink"]})
    return row


def _rate(rows, key) -> float:
    return float(np.mean([bool(key(r)) for r in rows])) if rows else float("nan")


def hidden_effect_sweep(out: Path, seeds: int, duration: float, pair_seeds: int,
                        effects: list[str] | None = None, none_seeds: int | None = None) -> int:
    """Run the study and write ``hidden-effects.md`` and ``hidden-effects.json`` in ``out``."""
    meter = RunMeter()
    none_seeds = seeds if none_seeds is None else none_seeds
    effects = list(effects or HIDDEN_EFFECTS)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    plan = [((), s) for s in range(none_seeds)]
    plan += [((e,), s) for e in effects for s in range(seeds)]
    plan += [(p, 1000 + s) for p in PAIRS if set(p) <= set(effects) for s in range(pair_seeds)]
    start = time.perf_counter()
    for i, (hidden, seed) in enumerate(plan, start=1):
        stopping.check()                  # SIGINT/SIGTERM: stop between runs, write nothing
        row = _run_case(hidden, seed, duration)
        rows.append(row)
        print(f"[{i}/{len(plan)}] hidden={list(hidden) or 'none'} seed={seed} named={row['named']} "
              f"passed={row['passed']} ({row['discrepancy_s']:.1f} s)", flush=True)
    total = time.perf_counter() - start
    none = [r for r in rows if not r["hidden"]]
    single = [r for r in rows if len(r["hidden"]) == 1]
    pairs = [r for r in rows if len(r["hidden"]) == 2]
    summary = {
        "seeds": seeds, "none_seeds": none_seeds, "pair_seeds": pair_seeds, "duration_s": duration,
        "recall": _rate(single, lambda r: r["passed"]),
        "false_positive_rate": _rate(none, lambda r: r["named"]),
        "extra_named_rate_single": _rate(single, lambda r: r["extra"]),
        "pairs_both_named_first": _rate(pairs, lambda r: r["first"]),
        "pairs_passed": _rate(pairs, lambda r: r["passed"]),
        "median_discrepancy_s": float(np.median([r["discrepancy_s"] for r in rows])),
        "max_discrepancy_s": float(np.max([r["discrepancy_s"] for r in rows])),
        "total_s": total, "machine": f"{platform.machine()}, {os.cpu_count()} cores",
    }
    # strict JSON: a rate over no runs (no pairs asked for) is null, not NaN
    (out / "hidden-effects.json").write_text(json.dumps(nan_to_none({"summary": summary, "runs": rows,
                                                                    PROVENANCE_KEY: provenance(run=meter)}),
                                                        indent=1, default=float) + "\n")
    lines = ["# Hidden-effect study of `wrenchd discrepancy`", "",
             f"Command: `OMP_NUM_THREADS=1 nice -n 10 wrenchd discrepancy-sweep --seeds {seeds} "
             f"--none-seeds {none_seeds} --pairs-seeds {pair_seeds} --duration {duration:g} "
             f"--out {out}`", "",
             f"Each run simulates {duration:g} s of free motion at 200 Hz (the `free-space` "
             "scenario's workspace and physics: rigid body, Coulomb, viscous and Stribeck "
             "friction, wrist cable coupling; encoder quantisation, lagged velocity estimate, "
             "effort noise) with the hidden effect(s) switched on at a random magnitude in "
             "their realistic range (`service/studies/hidden_effects.py`), and gives "
             "`run_discrepancy` the model without them.", "",
             "A single-effect run **passes** when (1) the hidden effect is named first, "
             "(2) its checked parameters are within tolerance (relative; checked where their "
             "torque reaches 2 noise floors on that joint), (3) the held-out gap (residual RMS "
             "above the noise floor, quadrature over the joints where the hidden torque reaches "
             f"half a floor) shrank by at least {100 * MIN_SHRINK:.0f} %. Recall = passing runs / "
             "runs. A false positive is a run with nothing hidden in which anything is named.", "",
             "## Summary", "",
             "| measure | value | target |", "|---|---|---|",
             f"| recall, single hidden effects ({len(single)} runs) | {100 * summary['recall']:.1f} % | >= 95 % |",
             f"| false positives, nothing hidden ({len(none)} runs) | {100 * summary['false_positive_rate']:.1f} % | <= 5 % |",
             f"| single runs that also named another effect | {100 * summary['extra_named_rate_single']:.1f} % | (reported) |",
             f"| pairs: both named as the top two ({len(pairs)} runs) | {100 * summary['pairs_both_named_first']:.1f} % | (reported) |",
             f"| pairs: passed (both, params, gap) | {100 * summary['pairs_passed']:.1f} % | (reported) |",
             f"| discrepancy run time, median / max | {summary['median_discrepancy_s']:.1f} s / "
             f"{summary['max_discrepancy_s']:.1f} s | < 30 s |", "",
             "## Per hidden effect", "",
             "| hidden | runs | named | named first | params ok | gap >= 50 % | passed | also named (count) | median shrink | tolerance |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for e in effects:
        rs = [r for r in single if r["hidden"] == [e]]
        if not rs:
            continue
        pe = [r["per_effect"][0] for r in rs]
        extras: dict[str, int] = {}
        for r in rs:
            for x in r["extra"]:
                extras[x] = extras.get(x, 0) + 1
        lines.append(
            f"| {e} | {len(rs)} | {sum(p['named'] for p in pe)} | {sum(r['first'] for r in rs)} | "
            f"{sum(p['params_ok'] for p in pe)} | {sum(p['shrink'] >= MIN_SHRINK for p in pe)} | "
            f"{sum(r['passed'] for r in rs)} | {', '.join(f'{k} ({v})' for k, v in extras.items()) or '-'} | "
            f"{np.median([p['shrink'] for p in pe]):.2f} | {100 * TOLERANCE[e]:.0f} % |")
    if pairs:
        lines += ["", "## Pairs of hidden effects", "", "| hidden | runs | both top two | passed |",
                  "|---|---|---|---|"]
        for p in PAIRS:
            rs = [r for r in pairs if r["hidden"] == list(p)]
            if rs:
                lines.append(f"| {' + '.join(p)} | {len(rs)} | {sum(r['first'] for r in rs)} | "
                             f"{sum(r['passed'] for r in rs)} |")
    fails = [r for r in rows if not r["passed"]]
    if fails:
        lines += ["", "## Runs that did not pass", "", "| hidden | seed | named | why |", "|---|---|---|---|"]
        for r in fails:
            why = []
            if not r["first"]:
                why.append("not first" if r["hidden"] else "named something")
            for p in r["per_effect"]:
                bad = [f"{c['param']} {c['fitted']:.4g} vs {c['true']:.4g}" for c in p["checks"] if not c["ok"]]
                if bad:
                    why.append("params: " + "; ".join(bad))
                if p["shrink"] < MIN_SHRINK:
                    why.append(f"{p['effect']} shrink {p['shrink']:.2f}")
            lines.append(f"| {' + '.join(r['hidden']) or 'none'} | {r['seed']} | {r['named']} | {', '.join(why)} |")
    lines += ["", "Not tested: `external_contact` (a tip wrench during contact, not free motion) and "
              "`inertial_delta` (the identified rigid body itself, never a candidate).", "",
              f"Total wall time {total / 60:.1f} min on {summary['machine']} (shared).", ""]
    (out / "hidden-effects.md").write_text("\n".join(lines))
    print(f"recall {100 * summary['recall']:.1f} %, false positives "
          f"{100 * summary['false_positive_rate']:.1f} % -> {out / 'hidden-effects.md'}")
    return 0


# ---------------------------------------------------------------------------- real data
LOADS_G = {"one_105g_parallel.csv": 105.0, "one_205g_parallel.csv": 205.0}


def _per_joint_load(res, direction: np.ndarray) -> list[float]:
    """Load [kg] fitted on joints 1 and 2 separately: payload column along ``direction``
    (unit vector of ``m c`` in link 2, lever of the library default) plus a constant."""
    from wrenchd.models.physics.effects.payload import PayloadParams, point_mass_parameters

    lever = float(np.linalg.norm(PayloadParams().position_m))
    y = res.updated_model.robot.regressor(res.q, res.dq, res.ddq)[:, :, 10:20]
    per_kg = y @ point_mass_parameters(1.0, direction * lever)
    out = []
    for j in (0, 1):
        x = np.column_stack([per_kg[:, j], np.ones(len(res.t))])
        beta, *_ = np.linalg.lstsq(x, res.residual[:, j], rcond=None)
        out.append(float(beta[0]))
    return out


def real_data_study(data: Path, out: Path) -> int:
    """Identify on ``one_no_weight.csv``, discrepancy on the loaded recordings; summary.md."""
    from wrenchd.adapters.csv_psm import read_psm_csv
    from wrenchd.models.identification.free_motion import identify_free_motion
    from wrenchd.service.studies.discrepancy_report import write_json, write_report

    study = RunMeter()
    out.mkdir(parents=True, exist_ok=True)
    base = read_psm_csv(data / "one_no_weight.csv")
    t0 = time.perf_counter()
    ident = identify_free_motion(base.t, base.position, base.velocity, base.effort,
                                 description="identified by wrenchd from WPI one_no_weight.csv")
    t_ident = time.perf_counter() - t0
    model_path = out / "identified_model.json"
    ident.model.save(model_path)
    results = {}
    for name, grams in LOADS_G.items():
        js = read_psm_csv(data / name)
        meter = RunMeter()
        t0 = time.perf_counter()
        res = run_discrepancy(ident.model, js.t, js.position, js.velocity, js.effort)
        seconds = time.perf_counter() - t0
        folder = out / name.removesuffix(".csv")
        folder.mkdir(parents=True, exist_ok=True)
        res.updated_model.save(folder / "updated_model.json")
        j = res.to_json(str(folder / "updated_model.json"))
        j["seconds"] = seconds
        write_json(j, folder / "discrepancy.json", run=meter)
        write_report(res, j, folder, title=f"Discrepancy: identified model vs {name}",
                     measured=f"{data.name}/{name}", model=str(model_path), seconds=seconds)
        results[name] = (res, j, grams)
    payload = {}
    for name, (res, j, grams) in results.items():
        eff = next((e for e in j["effects"] if e["label"] == "payload_mass@link2"), None)
        payload[name] = eff
    ref = payload.get("one_205g_parallel.csv")
    direction = (np.asarray(ref["params"]["position_m"]) / np.linalg.norm(ref["params"]["position_m"])
                 if ref else np.array([0.0, 0.366, 0.930]))
    lines = ["# Real data: a model identified without load, tested on loaded runs", "",
             "Command: `OMP_NUM_THREADS=1 wrenchd discrepancy-real --data ../shared/data/wpi-psm "
             f"--out {out}` (the same as `wrenchd identify --measured .../one_no_weight.csv -o "
             "identified_model.json` then `wrenchd discrepancy --model identified_model.json "
             "--measured .../one_105g_parallel.csv ...`).", "",
             f"Identification on `one_no_weight.csv` ({len(base)} samples, {t_ident:.1f} s): "
             f"{len(ident.columns)} base inertial parameters, Coulomb and viscous friction and an "
             "offset per joint. Held-out RMS per joint (5 contiguous folds): "
             + ", ".join(f"{v:.4g}" for v in ident.heldout_rms)
             + " (N m; N on insertion). This is each joint's error floor below.", "",
             "| recording | disagreeing joints (RMS / floor) | named, in order of evidence | "
             "payload on link 2 [kg] | held-out RMS before -> after, joints 1, 2 | excess removed | run time |",
             "|---|---|---|---|---|---|---|"]
    for name, (res, j, grams) in results.items():
        dis = ", ".join(f"{d['joint']} ({d['rmse'] / d['noise_floor']:.2f})" for d in j["disagreements"]) or "none"
        named = ", ".join(f"`{e['label']}` {e['joints']}" for e in j["effects"]) or "nothing"
        mass = payload[name]["params"]["mass_kg"] if payload[name] else float("nan")
        g = j["gap"]
        lines.append(f"| `{name}` ({grams:.0f} g) | {dis} | {named} | {mass:.4f} | "
                     f"{g['before_rmse'][0]:.4f} -> {g['after_rmse'][0]:.4f}, "
                     f"{g['before_rmse'][1]:.4f} -> {g['after_rmse'][1]:.4f} | "
                     f"{100 * g['excess_shrink']:.0f} % | {j['seconds']:.1f} s |")
    m105 = payload["one_105g_parallel.csv"]["params"]["mass_kg"] if payload["one_105g_parallel.csv"] else float("nan")
    m205 = payload["one_205g_parallel.csv"]["params"]["mass_kg"] if payload["one_205g_parallel.csv"] else float("nan")
    per = {name: _per_joint_load(res, direction) for name, (res, _, _) in results.items()}
    a, b = per["one_105g_parallel.csv"], per["one_205g_parallel.csv"]
    # the loaded runs repeat trajectory "one": the raw effort change against the no-load run
    shift = {}
    for name in results:
        js = read_psm_csv(data / name)
        n = min(len(js), len(base))
        d = js.effort[:n] - base.effort[:n]
        shift[name] = (d.mean(axis=0), d.std(axis=0))
    lines += ["", "## The load", "",
              f"Fitted load ratio 205 g / 105 g: **{m205 / m105:.2f}** (expected {205 / 105:.2f}). "
              f"Fitted masses {1000 * m105:.0f} g and {1000 * m205:.0f} g: the mass is the fitted first "
              "moment `|m c|` over the nominal lever arm (the library's default position, 17.7 cm), "
              "so its absolute value depends on that assumed lever; the ratio does not.", "",
              "Per joint (payload column along the 205 g run's fitted direction, plus a constant, "
              "fitted on one joint's residual at a time):", "",
              "| recording | joint 1 (yaw) [kg] | joint 2 (pitch) [kg] |", "|---|---|---|",
              f"| 105 g | {a[0]:.4f} | {a[1]:.4f} |", f"| 205 g | {b[0]:.4f} | {b[1]:.4f} |",
              f"| ratio | {b[0] / a[0]:.2f} | {b[1] / a[1]:.2f} |", "",
              "Raw effort change against `one_no_weight.csv` (same trajectory, sample by sample): "
              "mean and standard deviation per joint, yaw and pitch [N m]:", "",
              "| recording | yaw mean | yaw std | pitch mean | pitch std |", "|---|---|---|---|---|",
              *[f"| {n} | {shift[n][0][0]:+.4f} | {shift[n][1][0]:.4f} | {shift[n][0][1]:+.4f} | "
                f"{shift[n][1][1]:.4f} |" for n in results], "",
              "A load on the parallelogram should change pitch torque in proportion to the mass. "
              "The mean pitch change is about the same for both loads, and the load-shaped part "
              "of the 105 g run's pitch change is small: part of the pitch change between the "
              "no-load and the loaded sessions does not scale with the load (a session-to-session "
              "offset or friction change). Yaw scales as expected; the combined fit inherits the "
              "pitch inconsistency, which is why its ratio is off.", "",
              "Reports: [105 g](one_105g_parallel/report.md), [205 g](one_205g_parallel/report.md).", ""]
    (out / "summary.md").write_text("\n".join(lines))
    (out / "summary.json").write_text(json.dumps({
        "identified_heldout_rms": ident.heldout_rms.tolist(),
        "mass_kg": {"105g": m105, "205g": m205}, "ratio": m205 / m105,
        "per_joint_mass_kg": per,
        "disagreeing_joints": {n: [d["joint"] for d in j["disagreements"]] for n, (_, j, _) in results.items()},
        "named": {n: [e["label"] for e in j["effects"]] for n, (_, j, _) in results.items()},
        "excess_shrink": {n: j["gap"]["excess_shrink"] for n, (_, j, _) in results.items()},
        PROVENANCE_KEY: provenance(run=study),
    }, indent=2) + "\n")
    print((out / "summary.md").read_text())
    return 0
