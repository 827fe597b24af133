"""``wrenchd discrepancy``: find where a model and a recording disagree, name the missing
effects, add them, show the held-out gap shrink; JSON (with provenance) + Markdown report +
updated model."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from wrenchd.service.cli.measured import add_measured_options, read_measured


def discrepancy(args: argparse.Namespace) -> int:
    from wrenchd.models.discrepancy.workflow import run_discrepancy
    from wrenchd.models.physics.model import PhysicsModel
    from wrenchd.service.provenance import RunMeter
    from wrenchd.service.studies.discrepancy_report import write_json, write_report

    meter = RunMeter()
    model = PhysicsModel.load(args.model)
    js = read_measured(args.measured, args.format, args.rate, args.topic)
    start = time.perf_counter()
    res = run_discrepancy(model, js.t, js.position, js.velocity, js.effort, seed=args.seed)
    seconds = time.perf_counter() - start
    payloads = [payload_at(spec, res) for spec in args.payload_at]
    report = Path(args.report)
    report.mkdir(parents=True, exist_ok=True)
    updated = report / "updated_model.json"
    res.updated_model.save(updated)
    out = res.to_json(str(updated))
    out["seconds"] = seconds
    if payloads:
        out["payload_at"] = payloads
    write_json(out, Path(args.json), run=meter)
    write_report(res, out, report, title=f"Discrepancy: {Path(args.model).name} vs "
                 f"{Path(args.measured).name}", measured=args.measured, model=args.model,
                 seconds=seconds)
    if payloads:
        with open(report / "report.md", "a") as f:
            f.write(payload_markdown(payloads))
    for p in payloads:
        print(f"payload at {p['link']} {p['point_m']}: {1000 * p['mass_kg']:.1f} g")
    named = ", ".join(f"{e['label']} {e['joints']}" + ("" if e["told_apart"] else " (cannot be told "
                      "from " + ", ".join(a["label"] for a in e["alternatives"]
                                          if a["indistinguishable"]) + ")")
                      for e in out["effects"]) or "nothing"
    print(f"disagreeing joints: {[d['joint'] for d in out['disagreements']] or 'none'}; "
          f"named: {named}; held-out excess removed {100 * out['gap']['excess_shrink']:.0f} %; "
          f"{seconds:.1f} s")
    return 0


def _link_point(text: str) -> str:
    """argparse type: a ``LINK:X,Y,Z`` checked before the run, kept as text."""
    from wrenchd.models.errors import DataError
    from wrenchd.models.physics.point_load import parse_link_point

    try:
        parse_link_point(text)
    except DataError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def payload_at(spec: str, res) -> dict:
    """A point mass at a given point (``LINK:X,Y,Z``, frames of
    :mod:`wrenchd.models.physics.point_load`) fitted to the discrepancy's residual (measured
    minus model torque): its mass with the point held, and the residual before and after."""
    import numpy as np

    from wrenchd.models.physics.point_load import fit_mass, parse_link_point, point_load_torque

    link, point = parse_link_point(spec)
    dt = float(np.median(np.diff(res.t)))
    fit = fit_mass(point_load_torque(res.q, link, point, dt), res.residual)
    return {"link": link, "point_m": point.tolist(), **fit}


def payload_markdown(payloads: list[dict]) -> str:
    lines = ["", "## Payloads at given points", "",
             "Mass of a point load at each given point fitted to the residual (measured minus "
             "model torque, gravity and inertia of the point, least squares over the joints it "
             "acts on); residual RMS on those joints before and after.", "",
             "| link | point [m] | mass | joints | RMS before | RMS after |",
             "| --- | --- | --- | --- | --- | --- |"]
    for p in payloads:
        lines.append(f"| {p['link']} | {', '.join(f'{v:g}' for v in p['point_m'])} | "
                     f"{1000 * p['mass_kg']:.1f} g | {p['joints']} | "
                     + ", ".join(f"{v:.4f}" for v in p["rmse_before"]) + " | "
                     + ", ".join(f"{v:.4f}" for v in p["rmse_after"]) + " |")
    return "\n".join(lines) + "\n"


def register(sub) -> None:
    p = sub.add_parser("discrepancy", help="find, name and add what a model misses")
    p.add_argument("--model", required=True, help="physics model file (JSON)")
    add_measured_options(p)
    p.add_argument("--report", required=True, help="folder for report.md, figures, updated model")
    p.add_argument("--json", required=True, help="machine-readable result (JSON contract)")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    p.add_argument("--payload-at", action="append", default=[], metavar="LINK:X,Y,Z",
                   type=_link_point,
                   help="also fit the mass of a point load at this point of a link's frame "
                        "(repeatable; links: the joints' names and parallel_back, "
                        "parallel_upper, parallel_top, parallel_bottom), e.g. "
                        "parallel_upper:0.165,-0.023,0")
    p.set_defaults(func=discrepancy)
