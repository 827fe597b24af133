"""``wrenchd identify`` and ``wrenchd discrepancy`` (plus the two studies that check them).

identify      fit base inertial parameters, Coulomb/viscous friction and offsets to free
              motion; write a model file
discrepancy   find where a model and a recording disagree, name the missing effects, add
              them, show the held-out gap shrink; JSON + Markdown report + updated model
discrepancy-sweep   the hidden-effect study (recall and false positives over many seeds)
discrepancy-real    identify on the WPI no-load recording, discrepancy on the loaded ones
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from wrenchd.models.errors import DataError
from wrenchd.models.series import JointStates

FORMATS = ("auto", "wpi", "paper", "mcap")


def read_measured(path: str, fmt: str = "auto", rate_hz: float = 200.0) -> JointStates:
    """Joint states of a recording: CSV (WPI or paper layout) or an MCAP session."""
    if fmt == "mcap" or (fmt == "auto" and str(path).endswith(".mcap")):
        from wrenchd.adapters.mcap_session import read_session
        return read_session(path).joint_states
    from wrenchd.adapters.csv_psm import read_psm_csv
    if fmt not in ("auto", "wpi", "paper"):
        raise DataError(f"--format must be one of {FORMATS}, got {fmt!r}")
    return read_psm_csv(path, fmt, rate_hz=rate_hz)


def _cmd_identify(args: argparse.Namespace) -> int:
    from wrenchd.models.identification.free_motion import identify_free_motion
    from wrenchd.models.physics.model import PhysicsModel

    js = read_measured(args.measured, args.format, args.rate)
    nominal = PhysicsModel.load(args.nominal) if args.nominal else None
    start = time.perf_counter()
    ident = identify_free_motion(js.t, js.position, js.velocity, js.effort, nominal,
                                 with_offset=not args.no_offset,
                                 description=f"identified by wrenchd identify from {Path(args.measured).name}")
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    ident.model.save(args.output)
    print(f"identified {len(ident.columns)} base inertial parameters + friction"
          f"{' + offsets' if not args.no_offset else ''} from {len(js)} samples in "
          f"{time.perf_counter() - start:.1f} s -> {args.output}")
    print("held-out RMS per joint: " + ", ".join(f"{v:.4g}" for v in ident.heldout_rms))
    if ident.unexcited:
        print(f"not excited by this recording (kept nominal): {ident.unexcited}")
    return 0


def _cmd_discrepancy(args: argparse.Namespace) -> int:
    from wrenchd.models.discrepancy.workflow import run_discrepancy
    from wrenchd.models.physics.model import PhysicsModel
    from wrenchd.service.studies.discrepancy_report import write_json, write_report

    model = PhysicsModel.load(args.model)
    js = read_measured(args.measured, args.format, args.rate)
    start = time.perf_counter()
    res = run_discrepancy(model, js.t, js.position, js.velocity, js.effort, seed=args.seed)
    seconds = time.perf_counter() - start
    report = Path(args.report)
    report.mkdir(parents=True, exist_ok=True)
    updated = report / "updated_model.json"
    res.updated_model.save(updated)
    out = res.to_json(str(updated))
    out["seconds"] = seconds
    write_json(out, Path(args.json))
    write_report(res, out, report, title=f"Discrepancy: {Path(args.model).name} vs "
                 f"{Path(args.measured).name}", measured=args.measured, model=args.model,
                 seconds=seconds)
    named = ", ".join(f"{e['label']} {e['joints']}" for e in out["effects"]) or "nothing"
    print(f"disagreeing joints: {[d['joint'] for d in out['disagreements']] or 'none'}; "
          f"named: {named}; held-out excess removed {100 * out['gap']['excess_shrink']:.0f} %; "
          f"{seconds:.1f} s")
    return 0


def _cmd_sweep(args: argparse.Namespace) -> int:
    from wrenchd.service.studies.discrepancy import hidden_effect_sweep

    return hidden_effect_sweep(Path(args.out), args.seeds, args.duration, args.pairs_seeds,
                               args.effects, args.none_seeds)


def _cmd_real(args: argparse.Namespace) -> int:
    from wrenchd.service.studies.discrepancy import real_data_study

    return real_data_study(Path(args.data), Path(args.out))


def register(subparsers) -> None:
    """Add ``identify``, ``discrepancy``, ``discrepancy-sweep`` and ``discrepancy-real``."""
    idf = subparsers.add_parser("identify", help="fit a physics model to free-motion data")
    idf.add_argument("--measured", required=True, help="CSV (WPI or paper layout) or .mcap")
    idf.add_argument("--format", default="auto", choices=FORMATS)
    idf.add_argument("--rate", type=float, default=200.0, help="sample rate of a WPI CSV [Hz]")
    idf.add_argument("--nominal", help="model file whose rigid body is the starting point")
    idf.add_argument("--no-offset", action="store_true", help="do not fit joint offsets")
    idf.add_argument("-o", "--output", required=True, help="model file to write (JSON)")
    idf.set_defaults(func=_cmd_identify)

    dis = subparsers.add_parser("discrepancy", help="find, name and add what a model misses")
    dis.add_argument("--model", required=True, help="physics model file (JSON)")
    dis.add_argument("--measured", required=True, help="CSV (WPI or paper layout) or .mcap")
    dis.add_argument("--format", default="auto", choices=FORMATS)
    dis.add_argument("--rate", type=float, default=200.0, help="sample rate of a WPI CSV [Hz]")
    dis.add_argument("--report", required=True, help="folder for report.md, figures, updated model")
    dis.add_argument("--json", required=True, help="machine-readable result (JSON contract)")
    dis.add_argument("--seed", type=int, default=0, help="bootstrap seed")
    dis.set_defaults(func=_cmd_discrepancy)

    sw = subparsers.add_parser("discrepancy-sweep",
                               help="hidden-effect study: recall and false positives over seeds")
    sw.add_argument("--out", default="reports/discrepancy", help="folder for hidden-effects.md/json")
    sw.add_argument("--seeds", type=int, default=20, help="seeds per single hidden effect and for none")
    sw.add_argument("--none-seeds", type=int, default=None,
                    help="seeds with nothing hidden (default: --seeds)")
    sw.add_argument("--pairs-seeds", type=int, default=5, help="seeds per pair of hidden effects")
    sw.add_argument("--duration", type=float, default=30.0, help="simulated recording [s]")
    sw.add_argument("--effects", nargs="*", help="only these hidden effects (default: all)")
    sw.set_defaults(func=_cmd_sweep)

    real = subparsers.add_parser("discrepancy-real",
                                 help="identify on WPI one_no_weight, discrepancy on the loaded runs")
    real.add_argument("--data", default="../shared/data/wpi-psm", help="WPI recordings folder")
    real.add_argument("--out", default="reports/discrepancy/real-data")
    real.set_defaults(func=_cmd_real)
