"""The paper-reproduction report: Markdown tables, the force plot and the verdict.

Renders what :func:`wrenchd.service.studies.reproduction.run_reproduction` measured
(``wrenchd reproduce``), a :class:`~wrenchd.service.studies.reproduction_results.
ReproductionResult` or the JSON object of its ``results.json``: ``README.md`` text from
:func:`markdown` and ``force-rmse-vs-length.png`` from :func:`plot`.
"""

from __future__ import annotations

import math
import platform
from pathlib import Path
from typing import Any

from wrenchd.service.studies.reproduction_config import AXES, CONFIGS, TRAINED, TWO_STEP
from wrenchd.service.studies.reproduction_results import (
    Cell,
    Interval,
    Pretrained,
    ReproductionResult,
)

PLOT = "force-rmse-vs-length.png"


def _row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def _table(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join([_row(header), _row(["---"] * len(header)), *map(_row, rows)])


def _f(x: float, digits: int = 3) -> str:
    return "-" if math.isnan(x) else f"{x:.{digits}f}"        # NaN: not measured


def _result(results: ReproductionResult | dict[str, Any]) -> ReproductionResult:
    """The typed result (a ``results.json`` object is checked against its layout)."""
    return ReproductionResult.model_validate(results)


def _pretrained_seconds(results: ReproductionResult, name: str) -> float | None:
    p: Pretrained | None = results.pretrained.get(name.lower())
    return None if p is None else p.train_seconds


def plot(results: ReproductionResult | dict[str, Any], path: Path) -> None:
    """Mean force RMSE against trocar training length, one line per configuration."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    results = _result(results)
    lengths = results.lengths
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    for name in CONFIGS:
        cells = [results.contact[name][float(L)] for L in lengths]
        ys = [c.force_rmse for c in cells]
        style = "--" if name in ("Base", "Seal") else "-o"
        (line,) = ax.plot(lengths, ys, style, label=name)
        if all(c.scores is not None for c in cells):      # the 95 % intervals as a band
            ci = [c.scores["truth"]["rmse"].force_ci95 for c in cells]
            ax.fill_between(lengths, [a for a, _ in ci], [b for _, b in ci],
                            color=line.get_color(), alpha=0.15, lw=0)
    ax.axhline(results.oracle["contact"].force_rmse, color="k", lw=0.8, ls=":",
               label="oracle floor (noise only)")
    if results.output_filter:
        ax.axhline(results.oracle_filtered["contact"].force_rmse, color="k", lw=0.8,
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


def markdown(results: ReproductionResult | dict[str, Any], command: str, wall_s: float) -> str:
    """The report text (tables from ``results``; prose around them)."""
    results = _result(results)
    if results.scored:
        return scored_markdown(results, command, wall_s)
    cfg = results.config
    lengths = results.lengths
    lhead = [f"{L:g} s" for L in lengths]
    rec = results.recipes
    out = ["# Paper reproduction on the simulator\n",
           f"Command: `{command}` ({wall_s / 60:.1f} min wall, {results.torch_threads} torch "
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
           f"- Troc and Xfer: {rec['troc'].epochs} epochs (paper: 1000), lr "
           f"{rec['troc'].lr:g} halved every {rec['troc'].lr_halving_epochs} epochs, "
           f"truncated BPTT {rec['troc'].window} x {rec['troc'].lane_windows} samples.",
           f"- Corr in the tables: recipe `{cfg.corr_recipe}` ({rec['corr'].epochs} "
           f"epochs, batch {rec['corr'].batch_size}, lr {rec['corr'].lr:g}); the paper's "
           "400-epoch recipe is run once, side by side, at the shortest length (below).",
           "- Base and Seal are the shipped step-1 weights (`models/estimator/weights/`), "
           "themselves a shortened recipe: " + "; ".join(
               f"{k}: {v.epochs_run} epochs, {v.train_seconds} s"
               for k, v in results.pretrained.items()) + ".",
           f"- Trials: {cfg.no_contact_trials} no-contact trials of "
           f"{cfg.no_contact_trial_s:g} s, {cfg.contact_trials} contact trials of "
           f"{cfg.contact_trial_s:g} s; training sets are {cfg.segment_s:g} s sessions.\n",
           "## Table 1: training time [s] against trocar training length\n"]
    rows = []
    for name in CONFIGS:
        if name in TRAINED:
            rows.append([name] + [_f(results.train_seconds[name][k], 1) for k in lengths])
        else:
            rows.append([name] + [f"pretrained ({_pretrained_seconds(results, name)} s, "
                                  "free motion)"] * len(lengths))
    out += [_table(["config"] + lhead, rows), ""]
    out += [f"## Table 2: no-contact RMSE per axis (trained on {lhead[-1]}) [N, N m]\n"]
    rows = []
    nc = results.no_contact
    for name in CONFIGS:
        r = nc[name]
        rows.append([name] + [f"{_f(a)} ({_f(b, 1)})" for a, b in zip(r.rmse, r.ratio)]
                    + [f"{_f(r.force_rmse)} +- {_f(r.force_rmse_std)}"])
    o = results.oracle["no_contact"]
    rows.append(["oracle"] + [_f(a) for a in o.rmse] + [_f(o.force_rmse)])
    out += [_table(["config", *AXES, "mean force"], rows), ""]
    out += ["## Table 3: contact RMSE per axis against training length [N, N m]\n"]
    rows = []
    for name in CONFIGS:
        for k, lh in zip(lengths, lhead):
            r = results.contact[name][k]
            rows.append([name, lh] + [f"{_f(a)} ({_f(b, 1)})" for a, b in zip(r.rmse, r.ratio)]
                        + [f"{_f(r.force_rmse)} ({_f(r.force_ratio, 1)})"])
    o = results.oracle["contact"]
    rows.append(["oracle", "-"] + [_f(a) for a in o.rmse] + [_f(o.force_rmse)])
    out += [_table(["config", "length", *AXES, "mean force"], rows), ""]
    out += [f"![mean force RMSE against training length]({PLOT})\n"]
    out += _fast_vs_paper(results)
    out += [verdict(results), ""]
    return "\n".join(out)


def _troc_wins(results: ReproductionResult) -> list[str]:
    """Does Troc still win? Troc minus each two-step configuration on the same contact
    trials, per length, with its interval."""
    pairs = results.troc_minus_two_step
    if not pairs:
        return []
    rows, verdicts = [], []
    for L in results.lengths:
        by = pairs.get(L, {})
        if not by:
            continue
        rows.append([f"{L:g} s"] + [
            f"{by[n].mean:+.3f} [{by[n].ci95[0]:+.3f}, {by[n].ci95[1]:+.3f}]" if n in by else "-"
            for n in TWO_STEP])
        for n, d in by.items():
            if d.ci95[1] < 0:
                verdicts.append(f"Troc below {n} at {L:g} s")
            elif d.ci95[0] > 0:
                verdicts.append(f"{n} below Troc at {L:g} s")
    told = "; ".join(verdicts) if verdicts else "none"
    return ["## Does Troc still win?\n",
            "Troc's force RMSE on the contact trials minus each two-step configuration's "
            "[N], trial by trial on the same trials and seed by seed, with the 95 % bootstrap "
            "interval over seeds and trials (below zero: Troc is better). Pairing by trial "
            "takes out the spread of the trials' difficulty, which the cells' own intervals "
            "above keep.\n",
            _table(["length"] + [f"Troc - {n}" for n in TWO_STEP], rows), "",
            f"Differences whose interval excludes zero: {told}.", ""]


def _fast_vs_paper(results: ReproductionResult) -> list[str]:
    fv = results.fast_vs_paper
    if not fv:
        return []
    runs = (fv.paper, fv.fast)
    return [f"## Fast Corr recipe beside the paper's (Base+Corr, {fv.length_s:g} s of "
            f"trocar data, {fv.threads} threads, same data, same run)\n",
            _table(["recipe", "train time [s]", "CPU time [s]", "epochs run",
                    "contact force RMSE [N]",
                    *[f"{a}" for a in AXES]],
                   [[f"`{r.recipe}`" + (f" {r.overrides}" if r.overrides else ""),
                     _f(r.train_seconds, 2), _f(r.cpu_seconds or 0.0, 2), str(r.epochs_run),
                     _f(r.force_rmse), *[_f(a) for a in r.rmse]] for r in runs]), ""]


def _ci(mean: float, ci: list[float], digits: int = 3) -> str:
    return f"{_f(mean, digits)} [{_f(ci[0], digits)}, {_f(ci[1], digits)}]"


def _force(cell: Interval | None, digits: int = 3) -> str:
    return "-" if cell is None else _ci(cell.force, cell.force_ci95, digits)


def _axes(cell: Interval | None) -> list[str]:
    if cell is None:
        return ["-"] * 6
    return [_ci(m, c, 3 if k < 3 else 4) for k, (m, c) in enumerate(zip(cell.mean, cell.ci95))]


def _ratio_cells(c: Cell, filtered_floor: float, filt: bool) -> list[str]:
    """A cell's ratio to the raw floor, to the filtered floor and, with an output filter,
    its RMSE before the filter with that ratio to the raw floor."""
    return [_f(c.force_ratio_raw_floor, 2), _f(c.force_rmse / filtered_floor, 2)] + (
        [f"{_f(c.unfiltered_force_rmse)} ({_f(c.unfiltered_force_ratio_raw_floor, 2)})"]
        if filt else [])


def _setup(results: ReproductionResult) -> list[str]:
    """The Setup section of a scored report."""
    cfg, rec, filt = results.config, results.recipes, results.output_filter
    seeds = results.seeds.training
    trials = results.trials
    return [
        "## Setup\n",
        "- Patients: " + ("each session draws its own seal, body wall, incision and "
                          "insufflation pressure (`adapters/sim/patients.py`: ranges and "
                          "sources); test patients are unseen, their draws disjoint from "
                          f"the training draws: {results.patient_draws_disjoint}."
                          if results.patient_variation else
                          "one fixed patient in every session (training and test share "
                          "seal, body wall, incision and pressure)."),
        f"- Handle torsional stiffness: {cfg.handle_nm_per_rad or 'the default'} N m/rad.",
        f"- Trials: {trials.no_contact} no-contact of {cfg.no_contact_trial_s:g} s, "
        f"{trials.contact} contact of {cfg.contact_trial_s:g} s; training seeds "
        f"{', '.join(map(str, seeds))} (every trained network once per seed).",
        f"- Troc and Xfer: recipes `{cfg.troc_recipe}` / `{cfg.xfer_recipe}`, up to "
        f"{rec['troc'].epochs} epochs, early stopping after {rec['troc'].patience} "
        "epochs without improvement on " + (
            f"{cfg.validation_sessions} held-out trocar sessions."
            if cfg.validation_sessions else "the last part of each training series."),
        f"- Corr: recipe `{cfg.corr_recipe}` (up to {rec['corr'].epochs} epochs).",
        ("- Base and Seal: trained here "
         + ("once, with the first seed, and served under every seed (step 1 is most of the "
            "run's compute; their cells are intervals over trials), on "
            if cfg.step1 is not None and cfg.step1.one_seed else "per seed on ")
         + ", ".join(f"{k} {v:g} s" for k, v in results.step1.data_s.items())
         + f" of free motion, early-stopped on {results.step1.held_out_sessions} "
         f"held-out sessions (up to {results.step1.recipe.epochs} epochs)."
         if results.step1 else
         "- Base and Seal: the shipped step-1 weights (`models/estimator/weights/`)."),
        "- Output filter: " + (f"{filt.kind} at {filt.cutoff_hz:g} Hz on every wrench "
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
        "like floor is the raw one.\n"]


def _differs(results: ReproductionResult) -> list[str]:
    """What a run that trains its own step 1 (the paper-scale run) does otherwise than the
    paper, and why."""
    if not results.step1:
        return []
    cfg, rec = results.config, results.recipes
    return [
        "## What differs from the paper, and why\n",
        "- **Data**: the simulated PSM (rigid-body dynamics, joint friction, the cannula seal, "
        "the body wall and insufflation, a patient drawn per session) instead of recordings "
        "of a real arm. The simulator knows the true tip wrench and the noise-free internal "
        "torque, so every error is read against the truth and against an oracle floor; the "
        "force sensor, the paper's reference, is simulated beside them (`sensor`).",
        f"- **Training length**: the paper's recipes with {rec['troc'].epochs} epochs as a "
        f"ceiling, ended by early stopping ({rec['troc'].patience} epochs without improvement "
        "on held-out sessions): an epoch of step 1 on its hour of data takes tens of seconds "
        "on a 2-core CPU (docs/estimator-and-training.md, the paper-scale run), so 1000 epochs "
        "of every network would take days; the epochs each network ran are in Table 1.",
        "- **Step 1 once**: Base and Seal are trained with the first seed and served under "
        "every seed, since step 1 is most of the run's compute; their cells' intervals are "
        "over trials only." if cfg.step1 is not None and cfg.step1.one_seed else
        "- **Step 1 per seed**: Base and Seal are trained once per training seed.",
        f"- **Seeds and intervals**: {len(results.seeds.training)} training seeds and a 95 % "
        "interval on every cell, so that a difference between configurations can be told "
        "from the spread of seeds and trials.",
        "- **Filtering**: every estimate is scored raw and through a causal "
        f"{results.output_filter.cutoff_hz:g} Hz low-pass, each against its own floor (the "
        "daemon publishes raw estimates)."
        if results.output_filter else "- **Filtering**: none; estimates are scored raw.",
        ""]


def _training_rows(results: ReproductionResult, lengths: list[float]) -> list[list[str]]:
    """Table 1 of a scored report: training time (and epochs) per configuration."""
    rows = []
    for name in CONFIGS:
        if name in TRAINED:
            rows.append([name] + [
                f"{_f(results.train_seconds[name][k], 1)} "
                f"({results.validation[name][k].epochs_run} epochs)" for k in lengths])
        elif results.step1:
            per = [p[name] for p in results.step1.per_seed]
            secs = sum(p.train_seconds for p in per) / len(per)
            ep = max(p.epochs_run for p in per)
            rows.append([name] + [f"trained on free motion ({_f(secs, 1)} s, {ep} epochs)"]
                        * len(lengths))
        else:
            rows.append([name] + [f"pretrained ({_pretrained_seconds(results, name)} s, "
                                  "free motion)"] * len(lengths))
    return rows


def _summary_rows(cells: dict[str, Cell], floors: tuple[Cell, Cell], with_contact: bool,
                  filt: bool) -> list[list[str]]:
    """Rows of a table 2 or 3 block: each configuration, then the two floors."""
    def tail(sc: dict[str, dict[str, Interval | None]]) -> list[str]:
        """The contact-only RMSE (with contact), peak and sensor cells of a row."""
        out = [_force(sc["truth"]["contact_rmse"])] if with_contact else []
        out.append(_force(sc["truth"]["peak"]))
        if "sensor" in sc:
            out.append(_force(sc["sensor"]["rmse"]))
        return out

    rows = [[label, _force(c.scores["truth"]["rmse"])]
            + _ratio_cells(c, floors[1].force_rmse, filt) + tail(c.scores)
            for label, c in cells.items()]
    for label, f in (("oracle (raw)", floors[0]), ("oracle (filtered)", floors[1])):
        row = [label, _force(f.scores["truth"]["rmse"]),
               "1.00" if label.endswith("(raw)") else _f(f.force_rmse / floors[0].force_rmse, 2),
               "1.00" if label.endswith("(filtered)") else
               _f(f.force_rmse / floors[1].force_rmse, 2)]
        if filt:
            row.append("-")
        rows.append(row + tail(f.scores))
    return rows


def _per_axis(cells: dict[str, Cell], floors: tuple[Cell, Cell]) -> str:
    """The per-axis truth RMSE of each configuration and of the two floors."""
    return _table(["config", *AXES],
                  [[n] + _axes(c.scores["truth"]["rmse"]) for n, c in cells.items()]
                  + [["oracle (raw)"] + _axes(floors[0].scores["truth"]["rmse"]),
                     ["oracle (filtered)"] + _axes(floors[1].scores["truth"]["rmse"])])


def _in_domain(results: ReproductionResult, filt: bool) -> list[str]:
    s1 = results.step1_in_domain
    if not s1:
        return []
    return ["## Step 1 in domain: free motion of unseen patients, no contact\n",
            "Base on the `free-space` scenario, Seal on `free-space-seal`: the false force "
            "of each step-1 model on the motion it was trained for.\n",
            _table(["model", "force RMSE [N]", "/ raw floor", "/ filtered floor"]
                   + (["before the filter [N] (/ raw floor)"] if filt else [])
                   + ["peak force error [N]", "raw floor [N]", "filtered floor [N]"],
                   [[n, _force(c.scores["truth"]["rmse"])]
                    + _ratio_cells(c, c.oracle_filtered.force_rmse, filt)
                    + [_force(c.scores["truth"]["peak"]), _f(c.oracle.force_rmse),
                       _f(c.oracle_filtered.force_rmse)] for n, c in s1.items()]),
            ""]


def _untimed(results: ReproductionResult) -> list[str]:
    """A note under table 1 when a time is missing: a network trained before its checkpoint
    kept the training time (its file is reused as it is)."""
    times = [v for by_length in results.train_seconds.values() for v in by_length.values()]
    if results.step1:
        times += [p.train_seconds for per in results.step1.per_seed for p in per.values()]
    if not any(math.isnan(v) for v in times):
        return []
    return ["`-`: trained in an earlier sitting whose checkpoint did not keep the training "
            "time (a training time is the wall time of the epochs, every sitting's).\n"]


def _partial(results: ReproductionResult) -> list[str]:
    """A partial run's banner: what is done, what the tables hold."""
    p = results.progress
    if p is None:
        return []
    done = ", ".join(f"seed {seed} at {length:g} s" for seed, length in p.done)
    longest = f"{float(results.config.lengths_s[-1]):g} s"
    return [f"**Partial run: {len(p.done)} of {p.planned} (training seed, length) cells "
            f"done** ({done}). The tables hold the lengths every configuration has reached, "
            f"each cell over the seeds done there; Table 2 lists a trained configuration once "
            f"a seed has trained it at the longest length ({longest}). The same command goes "
            "on from the finished cells (`cells/`) and, on the machine that ran it, the "
            "checkpoints.\n"]


def _targets(results: ReproductionResult, last: str) -> list[str]:
    crit = results.criteria
    if not crit:
        return []

    def pairs(r: dict[str, float]) -> str:
        text = f"estimate / raw floor {r['raw']:.2f}x"
        if "filtered" in r:
            text += f", filtered estimate / filtered floor {r['filtered']:.2f}x"
        return text

    out = ["## Targets\n"]
    if crit.step1_in_domain:
        c = crit.step1_in_domain
        out.append("- In-domain step-1 false force within 2x the raw oracle floor: "
                   f"{'yes' if c.within_2x else 'no'} ("
                   + "; ".join(f"{k}: {pairs(r)}" for k, r in c.ratios.items()) + ").")
    b = crit.best_two_step
    out.append(f"- Best two-step configuration at {last} ({b.config}) within 1.5x "
               f"the raw oracle floor on contact trials"
               f"{' of unseen patients' if b.unseen_patients else ''}: "
               f"{'yes' if b.within_1_5x else 'no'} ({pairs(b.ratios)}).")
    out.append("")
    return out


def scored_markdown(results: ReproductionResult | dict[str, Any], command: str,
                    wall_s: float) -> str:
    """The report of a run with per-trial scores: every cell a mean over training seeds and
    trials with its 95 % interval, floors raw and filtered, contact-only RMSE, peak error and
    the sensor channel beside the truth."""
    results = _result(results)
    lengths = results.lengths
    lhead = [f"{L:g} s" for L in lengths]
    filt = bool(results.output_filter)
    out = ["# Paper reproduction on the simulator\n",
           f"Command: `{command}` ({wall_s / 60:.1f} min wall in the sitting that wrote this "
           f"report, which goes on from the cells earlier sittings finished: Table 1 holds "
           f"the training times; "
           f"{results.torch_threads} torch threads, {platform.processor() or platform.machine()}"
           f").\n",
           *_partial(results),
           "Wu, Yilmaz, Kazanzides, Tumerdem, *Estimation of Trocar and Tool Interaction Forces "
           "on the da Vinci Research Kit with Two-Step Deep Learning*: the three tables and the "
           "force plot regenerated on simulated data (`service/studies/reproduction.py` says "
           "how).\n",
           *_setup(results),
           *_differs(results),
           "## Table 1: training time [s] against trocar training length\n",
           _table(["config"] + lhead, _training_rows(results, lengths)), "",
           *_untimed(results)]

    def header(with_contact: bool, sensor: bool) -> list[str]:
        return (["config", "force RMSE [N]", "/ raw floor", "/ filtered floor"]
                + (["before the filter [N] (/ raw floor)"] if filt else [])
                + (["contact force RMSE [N]"] if with_contact else [])
                + ["peak force error [N]"] + (["sensor: force RMSE [N]"] if sensor else []))

    nc = {n: results.no_contact[n] for n in CONFIGS if n in results.no_contact}
    floors_nc = (results.oracle["no_contact"], results.oracle_filtered["no_contact"])
    sensor_nc = "sensor" in nc["Base"].scores
    longest = f"{float(results.config.lengths_s[-1]):g} s"
    out += [f"## Table 2: no-contact RMSE (trained on {longest})\n",
            "False force on trocar motion without contact, unseen patients:\n",
            _table(header(False, sensor_nc), _summary_rows(nc, floors_nc, False, filt)), "",
            "Per axis (truth) [N, N m]:\n", _per_axis(nc, floors_nc), ""]
    floors_c = (results.oracle["contact"], results.oracle_filtered["contact"])
    sensor_c = "sensor" in results.contact["Base"][lengths[0]].scores
    out += ["## Table 3: contact RMSE against training length\n"]
    for k, lh in zip(lengths, lhead):
        cells = {n: results.contact[n][k] for n in CONFIGS}
        out += [f"### {lh} of trocar training data\n",
                _table(header(True, sensor_c), _summary_rows(cells, floors_c, True, filt)), "",
                "Per axis (truth) [N, N m]:\n", _per_axis(cells, floors_c), ""]
    out += [f"![mean force RMSE against training length]({PLOT})\n"]
    out += _in_domain(results, filt)
    out += _targets(results, lhead[-1])
    out += _fast_vs_paper(results)
    out += [verdict(results), ""]
    out += _troc_wins(results)
    return "\n".join(out)


def verdict(results: ReproductionResult | dict[str, Any]) -> str:
    """Do the two-step configurations beat Base and Seal on contact force RMSE?"""
    results = _result(results)
    lengths = results.lengths
    c = results.contact
    best_one = min(c["Base"][lengths[0]].force_rmse, c["Seal"][lengths[0]].force_rmse)
    lines = ["## Do the two-step configurations beat Base and Seal?\n"]
    for name in ("Base+Corr", "Seal+Corr", "Seal+Xfer"):
        wins = [k for k in lengths if c[name][k].force_rmse < best_one]
        lines.append(f"- {name}: below the better of Base and Seal ({best_one:.3f} N) at "
                     f"{len(wins)} of {len(lengths)} lengths "
                     f"({', '.join(f'{k:g} s' for k in wins) or 'none'}).")
    return "\n".join(lines)


def pretrained_info() -> dict[str, Pretrained]:
    """Training time, epochs and number of series of the shipped step-1 weights."""
    from wrenchd.models.estimator.checkpoint import load_checkpoint
    from wrenchd.models.estimator.pretrained import pretrained_path

    info = {}
    for name in ("base", "seal"):
        ck = load_checkpoint(pretrained_path(name))
        info[name] = Pretrained(train_seconds=ck.data.get("train_seconds"),
                                epochs_run=ck.validation.get("epochs_run"),
                                series=len(ck.data.get("series", [])))
    return info
