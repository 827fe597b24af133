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
        ys = [results["contact"][name][str(float(L))]["force_rmse"] for L in lengths]
        style = "--" if name in ("Base", "Seal") else "-o"
        ax.plot(lengths, ys, style, label=name)
    ax.axhline(results["oracle"]["contact"]["force_rmse"], color="k", lw=0.8, ls=":",
               label="oracle floor (noise only)")
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
    fv = results.get("fast_vs_paper")
    if fv:
        out += [f"## Fast Corr recipe beside the paper's (Base+Corr, {fv['length_s']:g} s of "
                f"trocar data, {fv['threads']} threads, same data, same run)\n",
                _table(["recipe", "train time [s]", "CPU time [s]", "epochs run",
                        "contact force RMSE [N]",
                        *[f"{a}" for a in AXES]],
                       [[f"`{fv[k]['recipe']}`" + (f" {fv[k]['overrides']}" if fv[k]['overrides']
                                                   else ""),
                         _f(fv[k]["train_seconds"], 2), _f(fv[k].get("cpu_seconds", 0.0), 2),
                         str(fv[k]["epochs_run"]),
                         _f(fv[k]["force_rmse"]), *[_f(a) for a in fv[k]["rmse"]]]
                        for k in ("paper", "fast")]), ""]
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
