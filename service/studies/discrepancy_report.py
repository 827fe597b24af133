"""The discrepancy report a person reads: Markdown plus matplotlib (Agg) figures.

Figures (PNG, in the report folder):
* ``gap.png``: held-out residual RMS per joint before and after, with the noise floor.
* ``effect-<k>-<label>.png``: for each named effect, residual before and after (out of fold)
  against the variable that shows it best (velocity for friction and seals: a hysteresis
  loop; position for payloads, springs, offsets and the body wall; time for drift), on the
  joints it acts on, with the fitted effect torque.
* ``residual-time.png``: residual before and after over time on the disagreeing joints.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from wrenchd.models.discrepancy.candidates import FIRST_MOMENT_SITES, FREE_POSITION_SITES
from wrenchd.models.discrepancy.workflow import DiscrepancyResult
from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.provenance import RunMeter, stamp

UNITS = ("N m", "N m", "N", "N m", "N m", "N m")
AGAINST = {"coulomb_friction": "velocity", "viscous_friction": "velocity",
           "stribeck_friction": "velocity", "seal_friction": "velocity",
           "cable_coupling": "velocity", "payload_mass": "position", "spring": "position",
           "joint_offset": "position", "body_wall": "position", "drift": "time"}


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _gap_figure(res: DiscrepancyResult, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.2))
    x = np.arange(6)
    ratio_b, ratio_a = res.before_rmse / res.floor, res.after_rmse / res.floor
    ax.bar(x - 0.2, ratio_b, 0.4, label="before (model)", color="0.6")
    ax.bar(x + 0.2, ratio_a, 0.4, label="after (model + named, held out)", color="tab:blue")
    ax.axhline(1.0, color="k", lw=0.8, ls="--", label="noise floor")
    ax.set_xticks(x, [f"{j + 1}\n{JOINT_NAMES[j].replace('outer_', '')}" for j in range(6)])
    ax.set_ylabel("residual RMS / noise floor")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _effect_figure(res: DiscrepancyResult, k: int, effect: dict[str, Any], path: Path) -> None:
    plt = _plt()
    joints = [j - 1 for j in effect["joints"]] or [int(np.argmax(effect["rms_torque"]))]
    joints = joints[:3]
    against = AGAINST.get(effect["name"], "velocity")
    tau = res.effect_torque[effect["label"]]
    after = res.residual - res.heldout_prediction
    fig, axes = plt.subplots(1, len(joints), figsize=(4.2 * len(joints), 3.4), squeeze=False)
    for ax, j in zip(axes[0], joints):
        x = {"velocity": res.dq[:, j], "position": res.q[:, j], "time": res.t}[against]
        ax.plot(x, res.residual[:, j], ".", ms=1.5, color="0.6", label="residual before")
        ax.plot(x, after[:, j], ".", ms=1.5, color="tab:blue", alpha=0.6, label="after (held out)")
        if against == "time":
            ax.plot(x, tau[:, j], "-", color="tab:red", lw=1, label="fitted effect")
        else:
            ax.plot(x, tau[:, j], ".", ms=1, color="tab:red", label="fitted effect")
        unit = "rad" if j != 2 else "m"
        xlabel = {"velocity": f"velocity [{unit}/s]", "position": f"position [{unit}]",
                  "time": "time [s]"}[against]
        ax.set_xlabel(f"joint {j + 1} {xlabel}")
        ax.set_ylabel(f"torque [{UNITS[j]}]")
        ax.set_title(f"joint {j + 1}", fontsize=9)
    axes[0][0].legend(fontsize=7, markerscale=5)
    fig.suptitle(f"{k}. {effect['label']}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _time_figure(res: DiscrepancyResult, path: Path) -> None:
    plt = _plt()
    joints = [f["joint"] - 1 for f in res.findings if f["disagrees"]] or [0]
    after = res.residual - res.heldout_prediction
    fig, axes = plt.subplots(len(joints), 1, figsize=(8, 2.2 * len(joints)), squeeze=False)
    for ax, j in zip(axes[:, 0], joints):
        ax.plot(res.t, res.residual[:, j], lw=0.6, color="0.5", label="before")
        ax.plot(res.t, after[:, j], lw=0.6, color="tab:blue", label="after (held out)")
        ax.axhspan(-res.floor[j], res.floor[j], color="tab:green", alpha=0.15, label="+- floor")
        ax.set_ylabel(f"j{j + 1} [{UNITS[j]}]")
    axes[0, 0].legend(fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


#: Distances from the RCM [m] at which a parallelogram payload's mass is read out.
LEVERS_M = (0.10, 0.15, 0.20, 0.25)


def _trade_off(effect: dict[str, Any]) -> list[str]:
    """How mass and place trade off for a payload whose position was free: on the
    parallelogram (turning about the RCM) the data fix only the first moment, so the
    mass goes as one over the distance from the RCM; on the insertion stage mass and point are
    both fitted, and the mass's standard error says how well."""
    if effect["name"] != "payload_mass":
        return []
    p, c = effect["params"], effect["coefficients"]
    if p["link"] in FIRST_MOMENT_SITES:
        moment = float(np.linalg.norm([c["m_cx"], c["m_cy"], c["m_cz"]]))
        at = ", ".join(f"{100 * r:.0f} cm: {1000 * moment / r:.0f} g" for r in LEVERS_M)
        return [f"- mass and place: the data fix the first moment |m c| = {1000 * moment:.1f} "
                f"g m, not the mass; at a distance r from the RCM the mass is |m c| / r ({at}; "
                f"the reported mass is at the nominal {100 * np.linalg.norm(p['position_m']):.1f} "
                "cm). With the point known, `--payload-at` gives the mass."]
    if p["link"] in FREE_POSITION_SITES and "mass_kg" in effect["std_errors"]:
        return [f"- mass and place: both fitted; mass {1000 * p['mass_kg']:.1f} g +- "
                f"{1000 * effect['std_errors']['mass_kg']:.1f} g (1 standard error, "
                "residuals taken as white)"]
    return []


def write_report(res: DiscrepancyResult, out: dict[str, Any], folder: Path, *, title: str,
                 measured: str, model: str, seconds: float | None = None) -> Path:
    """Write ``report.md`` and the figures into ``folder``; returns the Markdown path."""
    folder.mkdir(parents=True, exist_ok=True)
    _gap_figure(res, folder / "gap.png")
    _time_figure(res, folder / "residual-time.png")
    lines = [f"# {title}", "",
             f"- measured: `{measured}` ({out['samples']} samples)",
             f"- model: `{model}`",
             f"- updated model: `{out['updated_model']}`"]
    if seconds is not None:
        lines.append(f"- run time: {seconds:.1f} s")
    lines += ["", "## Find: where the model disagrees", "",
              "| joint | residual RMS | noise floor | ratio | disagrees | where | lag-1 autocorr. | Ljung-Box p | corr. velocity | corr. position |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for f in res.findings:
        j = f["joint"] - 1
        lines.append(f"| {f['joint']} | {f['rmse']:.4g} {UNITS[j]} | {f['noise_floor']:.4g} | "
                     f"{f['ratio']:.2f} | {'**yes**' if f['disagrees'] else 'no'} | {f['where']} | "
                     f"{f['whiteness']['lag1_autocorrelation']:.2f} | {f['whiteness']['ljung_box_p']:.2g} | "
                     f"{f['correlation']['velocity']:+.2f} | {f['correlation']['position']:+.2f} |")
    lines += ["", "![residual over time](residual-time.png)", "",
              "## Name: effects with real support", ""]
    if not out["effects"]:
        lines.append("No candidate effect has real support (held-out BIC, bootstrap stability "
                     "and size); nothing was added.")
    for k, e in enumerate(out["effects"], start=1):
        fig = f"effect-{k}-{e['label'].replace(':', '_').replace('@', '_')}.png"
        _effect_figure(res, k, e, folder / fig)
        ev = e["evidence"]
        lines += [f"### {k}. `{e['label']}` on joints {e['joints']}", "",
                  f"- evidence: held-out delta BIC {ev['delta_bic']:.1f} (given the other named "
                  f"effects; {ev['folds_in_favour']}/5 folds in favour), entry delta BIC "
                  f"{ev['entry_delta_bic']:.1f}, bootstrap stability {ev['stability']:.2f}, "
                  f"size {ev['size_noise_floors']:.2f} noise floors",
                  "- parameters: " + ", ".join(f"`{k2}` = {_fmt(v)}" for k2, v in e["params"].items()),
                  "- fitted torque RMS per joint: " + _fmt(e["rms_torque"]),
                  *_trade_off(e),
                  "- could also be: " + (", ".join(
                      f"`{a['label']}` (R^2 {a['r2']:.3f}, leaves {a['misfit_noise_floors']:.2f} "
                      f"noise floors{': cannot be told apart here' if a['indistinguishable'] else ''})"
                      for a in e["alternatives"]) or "nothing else (no other candidate reproduces "
                      "its torque with R^2 >= 0.9)"), "",
                  f"![{e['label']}]({fig})", ""]
    gap = out["gap"]
    lines += ["", "## The gap (held out: five contiguous folds, each predicted by a fit on the others)", "",
              "| joint | before RMS | after RMS | noise floor | excess before | excess after |",
              "|---|---|---|---|---|---|"]
    for j in range(6):
        lines.append(f"| {j + 1} | {gap['before_rmse'][j]:.4g} | {gap['after_rmse'][j]:.4g} | "
                     f"{gap['noise_floor'][j]:.4g} | {gap['before_excess'][j]:.4g} | "
                     f"{gap['after_excess'][j]:.4g} |")
    lines += ["", f"Excess over the noise floor removed: {100 * gap['excess_shrink']:.0f} % "
              "(quadrature sum over joints, in noise floors).", "", "![gap](gap.png)", "",
              "## Candidates tested", "", "| step | candidate | delta BIC | folds | note |",
              "|---|---|---|---|---|"]
    for row in out["candidates"]:
        dbic = "" if row.get("delta_bic") is None else f"{row['delta_bic']:.1f}"
        lines.append(f"| {row['step']} | {row['candidate']} | {dbic} | {row.get('folds_in_favour', '')} | "
                     f"{row.get('note', '')} |")
    lines += ["", "Not candidates: " + "; ".join(f"`{k}`: {v}" for k, v in out["not_candidates"].items()), ""]
    if out["notes"]:
        lines += ["## Notes", ""] + [f"- {n}" for n in out["notes"]] + [""]
    path = folder / "report.md"
    path.write_text("\n".join(lines))
    return path


def write_json(out: dict[str, Any], path: Path, run: RunMeter | None = None) -> None:
    """Write the machine-readable result ``out`` to ``path``, with its provenance (stolen CPU
    time measured by ``run``, default: over the process)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(stamp(dict(out), run=run), indent=2) + "\n")
