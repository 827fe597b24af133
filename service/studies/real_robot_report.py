"""The Markdown report of :func:`wrenchd.service.studies.real_robot.run`."""

from __future__ import annotations

import re
from typing import Any

from wrenchd.service.replay.detector import detector_table
from wrenchd.service.studies.real_data_report import known_loads_section, tip_force_section


def _f(x: Any, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def _get(d: dict[str, Any], *keys: str) -> Any:
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _name(spec: str) -> str:
    """A session spec with its folders dropped, for tables."""
    return re.sub(r"[^,:*]*/", "", spec)


def served_section(rows: list[dict[str, Any]]) -> list[str]:
    lines = ["## The served estimate on unseen motion: step 1 and the correction net\n",
             (f"`{_name(rows[0]['session'])}` through the pipeline with the bundle: the "
              f"calibration minute ({rows[0]['calibration_s']:.0f} s) fits the correction net "
              "on this session's free motion (gated; frozen keeps step 1 alone). Free-motion "
              "tip force [N], the second after each seam left out. The motion after the "
              "calibration repeats the motion during it (the recording repeats every 6.5 s).\n"),
             "| policy | calibration minute RMS | p95 | after it RMS | p95 |",
             "| --- | --- | --- | --- | --- |"]
    for r in rows:
        c, a = r.get("calibration") or {}, r.get("after") or {}
        lines.append(f"| {r['policy']} | {_f(c.get('rms'))} | {_f(c.get('p95'))} | "
                     f"{_f(a.get('rms'))} | {_f(a.get('p95'))} |")
    return lines + [""]


def setup_change_section(rows: list[dict[str, Any]],
                         reference: dict[str, Any] | None = None) -> list[str]:
    lines = ["## A real set-up change: 205 g on the parallelogram, unannounced\n",
             ("`wrenchd compare` with the bundle fitted on `one_no_weight.csv`, on "
              f"`{_name(rows[0]['session'])}`: the load appears where the recording changes. "
              "Free-motion tip force RMS over the 30 s before the change and over the 30 s "
              "that start 60 s after it; the true force is zero throughout.\n"),
             "| policy | change at [s] | before [N] | after [N] | ratio | model versions |",
             "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        for c in r.get("setup_changes") or [{}]:
            lines.append(f"| {r['policy']} | {_f(c.get('at_s'), 1)} | {_f(c.get('before_N'))} "
                         f"| {_f(c.get('after_N'))} | {_f(c.get('ratio'))} | "
                         f"{r.get('final_model_version', '-')} |")
    lines += ["", "Free-motion force over time per policy: `setup-change/` (plots and "
              "`compare.md`).", ""]
    if reference:
        files = reference["files"]
        lines += [(f"What to hold `after` against: the bundle was fitted on all of "
                   f"`one_no_weight.csv`, so `before` is in-sample. A hybrid step 1 fitted on the "
                   f"first {reference['split_s']:g} s of a recording and scored on the rest of "
                   "the same run reads " + ", ".join(
                       f"`{name}` {v['rms']:.2f} N (p95 {v['p95']:.2f})"
                       for name, v in files.items())
                   + ": the level a model of that very run reaches on time it did not see."), ""]
    return lines


def injected_section(rows: list[dict[str, Any]]) -> list[str]:
    lines = ["## Real motion, simulated trocar and contacts\n",
             ("Gated, the same bundle. Contact force RMSE: tip force error while in contact; "
              "free-motion force: the estimate's mean and 95th percentile where the truth is "
              "free; contacts over 2 N found by the gate; contact samples offered to training "
              "(after the calibration minute; during it every sample is offered by design).\n"),
             "| session | contact force RMSE [N] | free-motion force mean / p95 [N] | contacts "
             "> 2 N found | gate precision | contact samples offered (after calibration) |",
             "| --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        found = r.get("contacts_found") or {}
        cont = r.get("contamination") or {}
        lines.append(
            f"| {_name(r['session'])} | {_f(_get(r, 'truth', 'force_rmse_N', 'contact'))} | "
            f"{_f(_get(r, 'false_force_N', 'mean'))} / {_f(_get(r, 'false_force_N', 'p95'))} | "
            f"{found.get('found', '-')} of {found.get('episodes', '-')} | "
            f"{_f(_get(r, 'gate', 'precision'))} | {cont.get('in_contact', '-')} "
            f"({cont.get('in_contact_after_calibration', '-')}) |")
    offered = [(r, e) for r in rows for e in (r.get("contamination") or {}).get(
        "episodes_after_calibration") or []]
    if offered:
        lines += ["", ("The contacts that reached training after the calibration: each one's "
                       "start, samples offered, true peak, and the free-motion force error over "
                       "the 10 s before it (a contact no stronger than that error cannot be "
                       "told from free motion by its size):\n"),
                  "| session | start [s] | samples offered | true peak [N] | free-motion error "
                  "before [N] |", "| --- | --- | --- | --- | --- |"]
        lines += [f"| {_name(r['session'])} | {e['start_s']:.1f} | {e['offered']} | "
                  f"{e['peak_N']:.2f} | {_f(e['free_error_before_N'])} |" for r, e in offered]
    lines += ["", "The gate as a detector on the same sessions (episodes peaking over 1 N; delay from "
              "the 0.3 N onset to the first flag; false alarms: flagged runs with no true contact "
              "within 0.5 s; `wrenchd compare`'s `gate_detector`):\n", detector_table(
                  [{**row, "session": _name(row["session"])} for row in rows])]
    return lines + [""]


def markdown(r: dict[str, Any]) -> str:
    step1 = r["step1"]
    lines = ["# The whole pipeline on a real dVRK PSM\n",
             f"Command: `{r.get('command', 'wrenchd real-robot')}` ({r['wall_s']:.0f} s).\n",
             (f"Recordings: `{r['data']}` (WPI free motion). Step 1 fitted on "
              "`one_no_weight.csv` alone; tested on `two.csv`, another trajectory.\n")]
    lines += tip_force_section(step1)
    lines += known_loads_section(step1["known_loads"], step1.get("known_load_pairs"))
    held = (r.get("bundle") or {}).get("held_out") or {}
    lines += [f"Bundle: `{r['bundle']['path']}/` (`wrenchd fit` on `one_no_weight.csv`, the "
              "last 20 % held out)" + ("; held-out RMSE per joint, hybrid: "
                                      + ", ".join(f"{v:.3f}" for v in held["hybrid_rmse"])
                                      if "hybrid_rmse" in held else "") + ".\n"]
    if r.get("served"):
        lines += served_section(r["served"])
    lines += setup_change_section(r["setup_change"], r.get("setup_change_reference"))
    lines += injected_section(r["injected"])
    return "\n".join(lines)
