"""The Markdown report of :func:`wrenchd.service.studies.real_data.evaluate`'s results."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.studies.real_data import lookahead_key

UNITS = ("N m", "N m", "N", "N m", "N m", "N m")
#: Result keys, their column titles, in table order.
COLUMNS = (("lstm", "paper LSTM"), ("ls_plain", "LS first (sign, offline)"),
           ("ls", "LS (offline)"), ("ls_causal", "LS causal (hybrid's physics)"),
           ("hybrid", "hybrid"), ("hybrid_ungated", "hybrid, no trust gate"),
           ("lstm_residual", "physics + LSTM residual"))


def _f(x: float | None) -> str:
    return "-" if x is None else f"{x:.4f}"


def rmse_table(d: dict[str, Any], floor: list[float] | None = None,
               lookahead_ms: Sequence[float] = ()) -> list[str]:
    """Per-joint RMSE of every model present in ``d`` (the hybrids reading ``lookahead_ms``
    ahead too), with hybrid / LS and the floor."""
    cols = [(k, t) for k, t in COLUMNS if f"{k}_rmse" in d]
    cols += [(lookahead_key(ms), f"hybrid, {ms:g} ms ahead (offline)")
             for ms in sorted(lookahead_ms) if f"{lookahead_key(ms)}_rmse" in d]
    ratios = ([(k, "hybrid / LS" if k == "hybrid" else t.split(" (")[0] + " / LS")
               for k, t in cols if k.startswith("hybrid") and k != "hybrid_ungated"]
              if "ls_rmse" in d else [])
    head = ["joint", "unit", "torque std"] + [t for _, t in cols]
    head += [t for _, t in ratios]
    head += ["repeatability floor"] if floor else []
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for j, name in enumerate(JOINT_NAMES):
        row = [f"{j + 1} {name}", UNITS[j], _f(d["torque_std"][j])]
        row += [_f(d[f"{k}_rmse"][j]) for k, _ in cols]
        row += [f"{d[f'{k}_rmse'][j] / d['ls_rmse'][j]:.3f}" for k, _ in ratios]
        if floor:
            row.append(_f(floor[j]))
        lines.append("| " + " | ".join(row) + " |")
    return lines + [""]


def coverage_section(cov: dict[str, Any]) -> list[str]:
    q = cov["distance_quantiles"]
    lines = ["## Test samples inside the hybrid's training coverage\n",
             (f"Full trust (residual weight 1): {100 * cov['share_full']:.1f} % of the test samples "
              f"({cov['n_inside']}); some trust (weight > 0): {100 * cov['share_any']:.1f} %. "
              f"Normalised distance to the nearest training sample: 10 % {q['10']:.2f}, median "
              f"{q['50']:.2f}, 90 % {q['90']:.2f} (full trust up to {cov['inner_distance']:g}, "
              f"none from {cov['outer_distance']:g}).\n")]
    keys = [k for k in ("ls", "ls_causal", "hybrid") if f"{k}_rmse_inside" in cov]
    if cov["n_inside"] and keys:
        lines += ["| joint | " + " | ".join(f"{k} inside" for k in keys) + " |",
                  "|" + " --- |" * (len(keys) + 1)]
        for j, name in enumerate(JOINT_NAMES):
            lines.append(f"| {j + 1} {name} | "
                         + " | ".join(_f(cov[f"{k}_rmse_inside"][j]) for k in keys) + " |")
        lines.append("")
    return lines


def loads_section(loads: dict[str, Any]) -> list[str]:
    lines = ["## External torque on the loaded recordings (step 1 trained without load)\n",
             ("Per recording and model: mean and RMS of the external torque (measured minus "
             "predicted) on joints 1-3, and the norm of the first moment [kg m] of a point load "
             "on the pitch link fitted to the external torque of joints 1-2 through gravity "
             "(`moment`; `with offsets`: a constant torque per joint fitted beside it). "
             "`measured_difference` is the loaded minus the unloaded recording sample by sample "
             "(the same trajectory), no model at all.\n"),
             ("| recording | model | mean j1 | mean j2 | mean j3 | RMS j1 | RMS j2 | RMS j3 | "
              "moment | with offsets |"), "|" + " --- |" * 10]
    for label, rec in loads["recordings"].items():
        for key, s in rec.items():
            if key == "grams":
                continue
            lines.append(f"| {Path(label).name} | {key} | "
                         + " | ".join(f"{v:.4f}" for v in s["external_mean"] + s["external_rms"])
                         + f" | {s['moment_kgm']:.4f} | {s['moment_with_offsets_kgm']:.4f} |")
    lines.append("")
    ratios = loads.get("ratios")
    if ratios:
        truth = ratios["truth"]
        lines += [f"Load ratio {Path(ratios['of'][0]).name} / {Path(ratios['of'][1]).name}"
                  + (f" (truth {truth:.3f})" if truth else "") + ":\n",
                  "| model | moment | moment with offsets | RMS pitch |", "| --- | --- | --- | --- |"]
        for key, v in ratios.items():
            if isinstance(v, dict):
                lines.append(f"| {key} | {v['moment']:.3f} | {v['moment_with_offsets']:.3f} | "
                             f"{v['pitch_rms']:.3f} |")
        lines.append("")
    return lines


#: Tip-force rows in table order: result key, title.
FORCE_ROWS = (("measured_cf", "`measured_cf`: effort through J^-T (the dVRK's own)"),
              ("measured_cf_minus_gravity", "`measured_cf` less the identified gravity"),
              *COLUMNS)


def tip_force_section(r: dict[str, Any]) -> list[str]:
    """The free-motion tip force of the test (and a single training) recording, in newtons."""
    files = [("test_file", f"test `{Path(r['test']).name}`")]
    if "tip_force_N" in r.get("train_file", {}):
        files.append(("train_file", f"training `{Path(r['train'][0]).name}`"))
    rows = list(FORCE_ROWS) + [(lookahead_key(ms), f"hybrid, {ms:g} ms ahead (offline)")
                               for ms in sorted(r.get("lookahead_ms", ()))]
    lines = ["## Newtons at the tip: free motion, where every newton is error\n",
             ("The recordings are free motion: the true tip force is zero. Force part of the "
              "wrench each model's external torque (effort minus prediction) maps to through "
              "the served map (`WrenchMap`, base axes), norm per sample: RMS and 95th "
              "percentile [N]. The floor is the effort one period apart over sqrt 2 through "
              "the same map.\n"),
             "| model | " + " | ".join(f"{t} RMS | p95" for _, t in files) + " |",
             "|" + " --- |" * (1 + 2 * len(files))]
    for key, title in rows:
        if all(key in r[f]["tip_force_N"] for f, _ in files):
            lines.append(f"| {title} | " + " | ".join(
                f"{r[f]['tip_force_N'][key]['rms']:.2f} | {r[f]['tip_force_N'][key]['p95']:.2f}"
                for f, _ in files) + " |")
    floors = [r[f].get("tip_force_floor_N") for f, _ in files]
    if all(floors):
        lines.append("| repeatability floor | " + " | ".join(
            f"{fl['rms']:.2f} | {fl['p95']:.2f}" for fl in floors) + " |")
    return lines + [""]


def _moved_range(model: dict[str, Any]) -> str:
    """``lo-hi g`` of the fitted mass with the point moved (``-`` where not computed)."""
    moved = model.get("fitted_mass_point_moved_kg")
    if not moved:
        return "-"
    return f"{min(moved.values()) * 1000:.0f} to {max(moved.values()) * 1000:.0f} g"


def known_loads_section(loads: list[dict[str, Any]],
                        pairs: list[dict[str, Any]] | None = None) -> list[str]:
    """Expected against estimated external torques of each known load, and what two runs of
    the same path tell apart (``pairs``)."""
    models = [k for k, _ in COLUMNS if k in loads[0]["models"]]
    lines = ["## Known loads: a mass at a given point, against the estimated external torque\n",
             ("Expected external torques: the load's gravity and inertia at the given point "
              "(`wrenchd.models.physics.point_load`, gravity along the base frame's -z as in "
              "the rigid-body model); fitted mass: least squares of the estimated external "
              "torque on the expected one per kilogram, over the joints the load acts on, the "
              "point held. A recording at another rate than the hybrid's is interpolated to "
              "it. `+-5 deg`: the fitted mass with gravity turned 5 degrees about the yaw axis "
              "(how much the assumed gravity direction matters); `point +-1 cm`: the range of "
              "the fitted mass with the point moved 1 cm either way along the link's x or y "
              "(the photographs' positions are read off a tape to about a centimetre).\n"),
             "| recording | rate | mass | link, point [m] | model | fitted mass | -5 deg | +5 deg "
             "| point +-1 cm | torque RMSE yaw, pitch | force error RMS [N] |",
             "|" + " --- |" * 11]
    for rec in loads:
        for key in models:
            m = rec["models"][key]
            rot = m["fitted_mass_gravity_rotated_kg"]
            lines.append(
                f"| {Path(rec['file']).name} | {rec['rate_hz']:.0f} Hz | "
                f"{rec['mass_kg'] * 1000:.0f} g | {rec['link']} "
                f"({', '.join(f'{v:g}' for v in rec['point_m'])}) | {key} | "
                f"{m['fitted_mass_kg'] * 1000:.1f} g ({100 * (m['fitted_mass_kg'] / rec['mass_kg'] - 1):+.0f} %) | "
                f"{rot['-5'] * 1000:.1f} g | {rot['+5'] * 1000:.1f} g | "
                f"{_moved_range(m)} | "
                f"{m['torque_rmse'][0]:.3f}, {m['torque_rmse'][1]:.3f} | "
                f"{m['force_error_N']['rms']:.2f} |")
    return lines + [""] + (_pairs_lines(pairs) if pairs else [])


def _pairs_lines(pairs: list[dict[str, Any]]) -> list[str]:
    lines = [("Run to run: two runs of the same path with different loads on the same link. The "
              "difference of their external torques, sample by sample, fitted to the difference "
              "of the loads' expected torques: a model's error on the path cancels, and with "
              "the measured efforts alone no model enters. The error is how far the runs differ "
              "beyond the loads; over sqrt 2 it is one run's share, a limit on any single "
              "run's fitted mass whatever the model.\n"),
             "| runs | rate | path apart [mrad] | expected | efforts alone | served model | "
             "one run's share |", "|" + " --- |" * 7]
    for p in pairs:
        fit = p["fitted_difference_kg"]
        lines.append(
            f"| {' - '.join(Path(f).name for f in reversed(p['files']))} | {p['rate_hz']:.0f} Hz "
            f"| {p['path_difference_max'] * 1000:.1f} | {p['expected_difference_kg'] * 1000:.0f} g "
            f"| {fit['effort'] * 1000:.1f} g | {p['served']} {fit[p['served']] * 1000:.1f} g | "
            f"{p['per_run_kg'] * 1000:.1f} g ({100 * p['per_run_kg'] / min(p['masses_kg']):.0f} "
            f"% of {min(p['masses_kg']) * 1000:.0f} g) |")
    return lines + [""]


def markdown(r: dict[str, Any], command: str) -> str:
    """The report: setup, test table, coverage, repeatability, training table, loads."""
    train = ", ".join(f"`{Path(s).name}`" for s in r["train"])
    lines = [("# Step 1 on real dVRK data: paper LSTM, least squares and a physics-informed "
              "hybrid\n"), f"Command: `{command}`\n",
             (f"Trained on {train}, tested on `{Path(r['test']).name}` (WPI PSM free-motion "
             "recordings, jaw dropped; `file:a:b` is the window from a to b seconds). "
              f"Models: {', '.join(r['models'])}.")]
    if "lstm_train_seconds" in r:
        rc = r["recipe"]
        lines.append(f"Paper LSTM: {rc['epochs']} epochs max, lr {rc['lr']:g} halved every "
                     f"{rc['lr_halving_epochs']}, patience {rc['patience']}, the last 20 % of "
                     f"each training series picks the epoch; ran {r['lstm_epochs_run']} epochs in "
                     f"{r['lstm_train_seconds']} s.")
    if "ls_rank" in r:
        lines.append(f"LS: pinocchio regressor + armature + Coulomb + viscous + offset (first: "
                     f"`sign` Coulomb, rank {r['ls_plain_rank']}; improved: `tanh(dq / 0.02)` "
                     f"Coulomb and a spring per joint, rank {r['ls_rank']}), centred "
                     "Savitzky-Golay acceleration (reads 50 ms ahead: offline only).")
    if "hybrid_info" in r:
        i = r["hybrid_info"]
        cfg = r.get("hybrid_config", {})
        widths = (cfg.get("physics") or {}).get("hysteresis_width")
        weight = (cfg.get("coverage") or {}).get("acceleration_weight") or 0.0
        lines.append(f"Hybrid: the improved LS columns"
                     + (" and a presliding friction column per joint (play operator, widths "
                        + ", ".join(f"{w:g}" for w in widths) + ")" if widths else "")
                     + f" on a causal acceleration (48-tap filter fitted to the centred one), "
                     f"rank {i['physics_rank']}, plus a 2 x 128 tanh residual net on [q, dq, "
                     f"acceleration] ({i['residual_train_seconds']} s), behind a "
                     "nearest-neighbour trust gate in normalised (q, dq"
                     + (f", acceleration at weight {weight:g}" if weight else "") + ").")
    if r.get("lookahead_ms"):
        lines.append("Hybrid, N ms ahead (offline): the same hybrid fitted again with an "
                     "acceleration filter that reads N ms past the estimated sample; it cannot "
                     "stream: it shows what publishing each estimate N ms late would buy.")
    lines.append("")
    if "tip_force_N" in r["test_file"]:
        lines += tip_force_section(r)
    if "known_loads" in r:
        lines += known_loads_section(r["known_loads"], r.get("known_load_pairs"))
    rep = r["test_file"].get("repeatability")
    lines += ["## Test: torque RMSE per joint\n"]
    ahead = r.get("lookahead_ms", ())
    lines += rmse_table(r["test_file"], rep["floor_rmse"] if rep else None, ahead)
    if rep:
        lines += [f"Repeatability: the test trajectory repeats every {rep['period_s']:.2f} s "
                  f"(positions within {rep['position_rms'] * 1000:.1f} mrad RMS); the floor is "
                  "the RMS torque difference one period apart over sqrt 2. Predicting each "
                  "sample by the mean of the same phase in earlier periods of the test itself: "
                  + ", ".join(f"{v:.4f}" for v in rep["previous_periods_rmse"]) + ".\n"]
    if "coverage" in r["test_file"]:
        lines += coverage_section(r["test_file"]["coverage"])
    lines += ["## Training samples (fit): torque RMSE per joint\n"]
    lines += rmse_table(r["train_file"], lookahead_ms=ahead)
    if "loads" in r:
        lines += loads_section(r["loads"])
    return "\n".join(lines)
