"""The paper-reproduction report: Markdown tables, the force plot and the verdict.

Renders what :func:`wrenchd.service.studies.reproduction.run_reproduction` measured
(``wrenchd reproduce``): ``README.md`` text from :func:`markdown` and
``force-rmse-vs-length.png`` from :func:`plot`.
"""

from __future__ import annotations

import platform
from pathlib import Path
from typing import Any

PLOT = "force-rmse-vs-length.png"
AXES_ = ("Fx", "Fy", "Fz", "tau_x", "tau_y", "tau_z")


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _table(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join([_row(header), _row(["---"] * len(header)), *map(_row, rows)])


def _f(x: float, digits: int = 3) -> str:
    return f"{x:.{digits}f}"


def plot(results: dict[str, Any], path: Path) -> None:
    """Mean force RMSE against trocar training length, one line per configuration."""
    import matplotlib

    from wrenchd.service.studies.reproduction import CONFIGS

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lengths = results["config"]["lengths_s"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    for name in CONFIGS:
        cells = [results["contact"][name][str(float(L))] for L in lengths]
        ys = [c["force_rmse"] for c in cells]
        style = "--" if name in ("Base", "Seal") else "-o"
        (line,) = ax.plot(lengths, ys, style, label=name)
        if all("scores" in c for c in cells):             # the 95 % intervals as a band
            ci = [c["scores"]["truth"]["rmse"]["force_ci95"] for c in cells]
            ax.fill_between(lengths, [a for a, _ in ci], [b for _, b in ci],
                            color=line.get_color(), alpha=0.15, lw=0)
    ax.axhline(results["oracle"]["contact"]["force_rmse"], color="k", lw=0.8, ls=":",
               label="oracle floor (noise only)")
    if results.get("output_filter"):
        ax.axhline(results["oracle_filtered"]["contact"]["force_rmse"], color="k", lw=0.8,
                   ls="-.", label="oracle through the output filter")
    ax.set_xlabel("trocar training length [s]")
    ax.set_ylabel("mean force RMSE, contact trials [N]")
    ax.set_title("Simulated dVRK PSM: contact force RMSE")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def markdown(results: dict[str, Any], command: str, wall_s: float) -> str:
    """The report text (tables from ``results``; prose around them)."""
    from wrenchd.service.studies.reproduction import AXES, CONFIGS, TRAINED

    if "scores" in results["no_contact"].get("Base", {}):
        return scored_markdown(results, command, wall_s)
    cfg = results["config"]
    lengths = [str(float(L)) for L in cfg["lengths_s"]]
    lhead = [f"{float(L):g} s" for L in cfg["lengths_s"]]
    rec = results["recipes"]
    out = ["# Paper reproduction on the simulator\n",
           f"Command: `{command}` ({wall_s / 60:.1f} min wall, {results['torch_threads']} torch "
           f"threads, {platform.processor() or platform.machine()}).\n",
           "Wu, Yilmaz, Kazanzides, Tumerdem, *Estimation of Trocar and Tool Interaction Forces "
           "on the da Vinci Research Kit with Two-Step Deep Learning*: the three tables and the "
           "force plot regenerated on simulated data (`service/studies/reproduction.py` says how). "
           "RMSEs are of the estimated tip wrench against the simulator's true tip wrench, per "
           "axis, over every sample of a trial, averaged over trials; `x (r)` is the RMSE and "
           "its ratio to the **oracle floor** (the same estimate made with the simulator's "
           "noise-free internal torque: effort noise through the damped `J^-T`, nothing "
           "else).\n",
           "## What was shortened\n",
           f"- Troc and Xfer: {rec['troc']['epochs']} epochs (paper: 1000), lr "
           f"{rec['troc']['lr']:g} halved every {rec['troc']['lr_halving_epochs']} epochs, "
           f"truncated BPTT {rec['troc']['window']} x {rec['troc']['lane_windows']} samples.",
           f"- Corr in the tables: recipe `{cfg['corr_recipe']}` ({rec['corr']['epochs']} "
           f"epochs, batch {rec['corr']['batch_size']}, lr {rec['corr']['lr']:g}); the paper's "
           "400-epoch recipe is run once, side by side, at the shortest length (below).",
           "- Base and Seal are the shipped step-1 weights (`models/estimator/weights/`), "
           "themselves a shortened recipe: " + "; ".join(
               f"{k}: {v.get('epochs_run')} epochs, {v.get('train_seconds')} s"
               for k, v in results["pretrained"].items()) + ".",
           f"- Trials: {cfg['no_contact_trials']} no-contact trials of "
           f"{cfg['no_contact_trial_s']:g} s, {cfg['contact_trials']} contact trials of "
           f"{cfg['contact_trial_s']:g} s; training sets are {cfg['segment_s']:g} s sessions.\n",
           "## Table 1: training time [s] against trocar training length\n"]
    rows = []
    for name in CONFIGS:
        if name in TRAINED:
            rows.append([name] + [_f(results["train_seconds"][name][k], 1) for k in lengths])
        else:
            secs = results["pretrained"].get(name.lower(), {}).get("train_seconds")
            rows.append([name] + [f"pretrained ({secs} s, free motion)"] * len(lengths))
    out += [_table(["config"] + lhead, rows), ""]
    out += [f"## Table 2: no-contact RMSE per axis (trained on {lhead[-1]}) [N, N m]\n"]
    rows = []
    nc = results["no_contact"]
    for name in CONFIGS:
        r = nc[name]
        rows.append([name] + [f"{_f(a)} ({_f(b, 1)})" for a, b in zip(r["rmse"], r["ratio"])]
                    + [f"{_f(r['force_rmse'])} +- {_f(r['force_rmse_std'])}"])
    o = results["oracle"]["no_contact"]
    rows.append(["oracle"] + [_f(a) for a in o["rmse"]] + [_f(o["force_rmse"])])
    out += [_table(["config", *AXES, "mean force"], rows), ""]
    out += ["## Table 3: contact RMSE per axis against training length [N, N m]\n"]
    rows = []
    for name in CONFIGS:
        for k, lh in zip(lengths, lhead):
            r = results["contact"][name][k]
            rows.append([name, lh] + [f"{_f(a)} ({_f(b, 1)})"
                                      for a, b in zip(r["rmse"], r["ratio"])]
                        + [f"{_f(r['force_rmse'])} ({_f(r['force_ratio'], 1)})"])
    o = results["oracle"]["contact"]
    rows.append(["oracle", "-"] + [_f(a) for a in o["rmse"]] + [_f(o["force_rmse"])])
    out += [_table(["config", "length", *AXES, "mean force"], rows), ""]
    out += [f"![mean force RMSE against training length]({PLOT})\n"]
    out += _fast_vs_paper(results)
    out += [verdict(results), ""]
    return "\n".join(out)


def _fast_vs_paper(results: dict[str, Any]) -> list[str]:
    fv = results.get("fast_vs_paper")
    if not fv:
        return []
    return [f"## Fast Corr recipe beside the paper's (Base+Corr, {fv['length_s']:g} s of "
            f"trocar data, {fv['threads']} threads, same data, same run)\n",
            _table(["recipe", "train time [s]", "CPU time [s]", "epochs run",
                    "contact force RMSE [N]",
                    *[f"{a}" for a in AXES_]],
                   [[f"`{fv[k]['recipe']}`" + (f" {fv[k]['overrides']}" if fv[k]['overrides']
                                               else ""),
                     _f(fv[k]["train_seconds"], 2), _f(fv[k].get("cpu_seconds", 0.0), 2),
                     str(fv[k]["epochs_run"]),
                     _f(fv[k]["force_rmse"]), *[_f(a) for a in fv[k]["rmse"]]]
                    for k in ("paper", "fast")]), ""]


def _ci(mean: float, ci: list[float], digits: int = 3) -> str:
    return f"{_f(mean, digits)} [{_f(ci[0], digits)}, {_f(ci[1], digits)}]"


def _force(cell: dict[str, Any] | None, digits: int = 3) -> str:
    return "-" if cell is None else _ci(cell["force"], cell["force_ci95"], digits)


def _axes(cell: dict[str, Any] | None) -> list[str]:
    if cell is None:
        return ["-"] * 6
    return [_ci(m, c, 3 if k < 3 else 4) for k, (m, c) in enumerate(zip(cell["mean"],
                                                                       cell["ci95"]))]


def scored_markdown(results: dict[str, Any], command: str, wall_s: float) -> str:
    """The report of a run with per-trial scores: every cell a mean over training seeds and
    trials with its 95 % interval, floors raw and filtered, contact-only RMSE, peak error and
    the sensor channel beside the truth."""
    from wrenchd.service.studies.reproduction import CONFIGS, TRAINED

    cfg = results["config"]
    lengths = [str(float(L)) for L in cfg["lengths_s"]]
    lhead = [f"{float(L):g} s" for L in cfg["lengths_s"]]
    rec = results["recipes"]
    filt = results.get("output_filter")
    seeds = results["seeds"]["training"]
    trials = results["trials"]
    out = ["# Paper reproduction on the simulator\n",
           f"Command: `{command}` ({wall_s / 60:.1f} min wall, {results['torch_threads']} torch "
           f"threads, {platform.processor() or platform.machine()}).\n",
           "Wu, Yilmaz, Kazanzides, Tumerdem, *Estimation of Trocar and Tool Interaction Forces "
           "on the da Vinci Research Kit with Two-Step Deep Learning*: the three tables and the "
           "force plot regenerated on simulated data (`service/studies/reproduction.py` says "
           "how).\n",
           "## Setup\n",
           "- Patients: " + ("each session draws its own seal, body wall, incision and "
                             "insufflation pressure (`adapters/sim/patients.py`: ranges and "
                             "sources); test patients are unseen, their draws disjoint from "
                             f"the training draws: {results.get('patient_draws_disjoint')}."
                             if results.get("patient_variation") else
                             "one fixed patient in every session (training and test share "
                             "seal, body wall, incision and pressure)."),
           f"- Handle torsional stiffness: {cfg.get('handle_nm_per_rad') or 'the default'} "
           "N m/rad.",
           f"- Trials: {trials['no_contact']} no-contact of {cfg['no_contact_trial_s']:g} s, "
           f"{trials['contact']} contact of {cfg['contact_trial_s']:g} s; training seeds "
           f"{', '.join(map(str, seeds))} (every trained network once per seed).",
           f"- Troc and Xfer: recipes `{cfg['troc_recipe']}` / `{cfg['xfer_recipe']}`, up to "
           f"{rec['troc']['epochs']} epochs, early stopping after {rec['troc']['patience']} "
           "epochs without improvement on " + (
               f"{cfg['validation_sessions']} held-out trocar sessions."
               if cfg.get("validation_sessions") else "the last part of each training series."),
           f"- Corr: recipe `{cfg['corr_recipe']}` (up to {rec['corr']['epochs']} epochs).",
           ("- Base and Seal: trained here per seed on "
            + ", ".join(f"{k} {v:g} s" for k, v in results["step1"]["data_s"].items())
            + f" of free motion, early-stopped on {results['step1']['held_out_sessions']} "
            f"held-out sessions (up to {results['step1']['recipe']['epochs']} epochs)."
            if "step1" in results else
            "- Base and Seal: the shipped step-1 weights (`models/estimator/weights/`)."),
           "- Output filter: " + (f"{filt['kind']} at {filt['cutoff_hz']:g} Hz on every wrench "
                                  "estimate (the floors: the oracle raw, and through the same "
                                  "filter)." if filt else "none (raw estimates)."),
           "",
           "Cells: mean over seeds and trials [95 % interval: percentile bootstrap over seeds "
           "and trials]. `force`: the mean of Fx, Fy, Fz. RMSE over every sample; `contact "
           "RMSE` over contact samples only; `peak`: the largest absolute error of a trial. "
           "`truth`: against the simulator's true tip wrench; `sensor`: against the simulated "
           "force sensor's channel, noise included. Ratios: against the raw oracle floor "
           "(the estimate from the noise-free internal torque) and the filtered one; with an "
           "output filter, `before the filter` is the same estimate unfiltered, whose like-for-"
           "like floor is the raw one.\n",
           "## Table 1: training time [s] against trocar training length\n"]
    rows = []
    for name in CONFIGS:
        if name in TRAINED:
            rows.append([name] + [
                f"{_f(results['train_seconds'][name][k], 1)} "
                f"({results['validation'][name][k]['epochs_run']} epochs)" for k in lengths])
        elif "step1" in results:
            per = [p[name] for p in results["step1"]["per_seed"]]
            secs = sum(p["train_seconds"] for p in per) / len(per)
            ep = max(p["epochs_run"] for p in per)
            rows.append([name] + [f"trained on free motion ({secs:.1f} s, {ep} epochs)"]
                        * len(lengths))
        else:
            secs = results["pretrained"].get(name.lower(), {}).get("train_seconds")
            rows.append([name] + [f"pretrained ({secs} s, free motion)"] * len(lengths))
    out += [_table(["config"] + lhead, rows), ""]

    def summary_rows(cells: dict[str, dict[str, Any]], floors: tuple[dict, dict],
                     with_contact: bool) -> list[list[str]]:
        def tail(sc: dict[str, Any]) -> list[str]:
            """The contact-only RMSE (with contact), peak and sensor cells of a row."""
            out = [_force(sc["truth"]["contact_rmse"])] if with_contact else []
            out.append(_force(sc["truth"]["peak"]))
            if "sensor" in sc:
                out.append(_force(sc["sensor"]["rmse"]))
            return out

        rows = []
        for label, c in cells.items():
            sc = c["scores"]
            row = [label, _force(sc["truth"]["rmse"]), _f(c["force_ratio_raw_floor"], 2),
                   _f(c["force_rmse"] / floors[1]["force_rmse"], 2)]
            if filt:
                row.append(f"{_f(c['unfiltered_force_rmse'])} "
                           f"({_f(c['unfiltered_force_ratio_raw_floor'], 2)})")
            rows.append(row + tail(sc))
        for label, f in (("oracle (raw)", floors[0]), ("oracle (filtered)", floors[1])):
            sc = f["scores"]
            row = [label, _force(sc["truth"]["rmse"]), "1.00" if label.endswith("(raw)") else
                   _f(f["force_rmse"] / floors[0]["force_rmse"], 2),
                   "1.00" if label.endswith("(filtered)") else
                   _f(f["force_rmse"] / floors[1]["force_rmse"], 2)]
            if filt:
                row.append("-")
            rows.append(row + tail(sc))
        return rows

    def header(with_contact: bool, sensor: bool) -> list[str]:
        return (["config", "force RMSE [N]", "/ raw floor", "/ filtered floor"]
                + (["before the filter [N] (/ raw floor)"] if filt else [])
                + (["contact force RMSE [N]"] if with_contact else [])
                + ["peak force error [N]"] + (["sensor: force RMSE [N]"] if sensor else []))

    nc = results["no_contact"]
    floors_nc = (results["oracle"]["no_contact"], results["oracle_filtered"]["no_contact"])
    sensor_nc = "sensor" in nc["Base"]["scores"]
    out += [f"## Table 2: no-contact RMSE (trained on {lhead[-1]})\n",
            "False force on trocar motion without contact, unseen patients:\n",
            _table(header(False, sensor_nc),
                   summary_rows({n: nc[n] for n in CONFIGS}, floors_nc, False)), "",
            "Per axis (truth) [N, N m]:\n",
            _table(["config", *AXES_], [[n] + _axes(nc[n]["scores"]["truth"]["rmse"])
                                        for n in CONFIGS]
                   + [["oracle (raw)"] + _axes(floors_nc[0]["scores"]["truth"]["rmse"]),
                      ["oracle (filtered)"] + _axes(floors_nc[1]["scores"]["truth"]["rmse"])]),
            ""]
    floors_c = (results["oracle"]["contact"], results["oracle_filtered"]["contact"])
    sensor_c = "sensor" in results["contact"]["Base"][lengths[0]]["scores"]
    out += ["## Table 3: contact RMSE against training length\n"]
    for k, lh in zip(lengths, lhead):
        cells = {n: results["contact"][n][k] for n in CONFIGS}
        out += [f"### {lh} of trocar training data\n",
                _table(header(True, sensor_c), summary_rows(cells, floors_c, True)), "",
                "Per axis (truth) [N, N m]:\n",
                _table(["config", *AXES_],
                       [[n] + _axes(cells[n]["scores"]["truth"]["rmse"]) for n in CONFIGS]
                       + [["oracle (raw)"] + _axes(floors_c[0]["scores"]["truth"]["rmse"]),
                          ["oracle (filtered)"]
                          + _axes(floors_c[1]["scores"]["truth"]["rmse"])]), ""]
    out += [f"![mean force RMSE against training length]({PLOT})\n"]
    s1 = results.get("step1_in_domain")
    if s1:
        out += ["## Step 1 in domain: free motion of unseen patients, no contact\n",
                "Base on the `free-space` scenario, Seal on `free-space-seal`: the false force "
                "of each step-1 model on the motion it was trained for.\n",
                _table(["model", "force RMSE [N]", "/ raw floor", "/ filtered floor"]
                       + (["before the filter [N] (/ raw floor)"] if filt else [])
                       + ["peak force error [N]", "raw floor [N]", "filtered floor [N]"],
                       [[n, _force(c["scores"]["truth"]["rmse"]),
                         _f(c["force_ratio_raw_floor"], 2),
                         _f(c["force_rmse"] / c["oracle_filtered"]["force_rmse"], 2)]
                        + ([f"{_f(c['unfiltered_force_rmse'])} "
                            f"({_f(c['unfiltered_force_ratio_raw_floor'], 2)})"] if filt else [])
                        + [_force(c["scores"]["truth"]["peak"]), _f(c["oracle"]["force_rmse"]),
                           _f(c["oracle_filtered"]["force_rmse"])] for n, c in s1.items()]),
                ""]
    crit = results.get("criteria") or {}
    if crit:
        out += ["## Targets\n"]
        def pairs(r: dict[str, float]) -> str:
            text = f"estimate / raw floor {r['raw']:.2f}x"
            if "filtered" in r:
                text += f", filtered estimate / filtered floor {r['filtered']:.2f}x"
            return text

        if "step1_in_domain" in crit:
            c = crit["step1_in_domain"]
            out.append("- In-domain step-1 false force within 2x the raw oracle floor: "
                       f"{'yes' if c['within_2x'] else 'no'} ("
                       + "; ".join(f"{k}: {pairs(r)}" for k, r in c["ratios"].items()) + ").")
        b = crit["best_two_step"]
        out.append(f"- Best two-step configuration at {lhead[-1]} ({b['config']}) within 1.5x "
                   f"the raw oracle floor on contact trials"
                   f"{' of unseen patients' if b['unseen_patients'] else ''}: "
                   f"{'yes' if b['within_1_5x'] else 'no'} ({pairs(b['ratios'])}).")
        out.append("")
    out += _fast_vs_paper(results)
    out += [verdict(results), ""]
    return "\n".join(out)


def verdict(results: dict[str, Any]) -> str:
    """Do the two-step configurations beat Base and Seal on contact force RMSE?"""
    lengths = [str(float(L)) for L in results["config"]["lengths_s"]]
    c = results["contact"]
    best_one = min(c["Base"][lengths[0]]["force_rmse"], c["Seal"][lengths[0]]["force_rmse"])
    lines = ["## Do the two-step configurations beat Base and Seal?\n"]
    for name in ("Base+Corr", "Seal+Corr", "Seal+Xfer"):
        wins = [k for k in lengths if c[name][k]["force_rmse"] < best_one]
        lines.append(f"- {name}: below the better of Base and Seal ({best_one:.3f} N) at "
                     f"{len(wins)} of {len(lengths)} lengths "
                     f"({', '.join(f'{float(k):g} s' for k in wins) or 'none'}).")
    return "\n".join(lines)


def pretrained_info() -> dict[str, Any]:
    """Training time, epochs and number of series of the shipped step-1 weights."""
    from wrenchd.models.estimator.checkpoint import load_checkpoint
    from wrenchd.models.estimator.pretrained import pretrained_path

    info = {}
    for name in ("base", "seal"):
        ck = load_checkpoint(pretrained_path(name))
        info[name] = {"train_seconds": ck.data.get("train_seconds"),
                      "epochs_run": ck.validation.get("epochs_run"),
                      "series": len(ck.data.get("series", []))}
    return info
