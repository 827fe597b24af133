"""``wrenchd real-data``: step 1 on real dVRK recordings (paper LSTM, least squares, hybrid).

    wrenchd real-data --train ../shared/data/wpi-psm/one_no_weight.csv \\
        --test ../shared/data/wpi-psm/two.csv \\
        --load ../shared/data/wpi-psm/one_105g_parallel.csv \\
        --load ../shared/data/wpi-psm/one_205g_parallel.csv --out reports/real-data-step1.md

    wrenchd real-data --models ls,hybrid --train ../shared/data/wpi-psm/one_no_weight.csv \\
        --train ../shared/data/wpi-psm/two.csv:0:18 --test ../shared/data/wpi-psm/two.csv:18:30 \\
        --out /tmp/split.md

    wrenchd real-data --models ls,hybrid --train ../shared/data/wpi-psm/one_no_weight.csv \\
        --test ../shared/data/wpi-psm/two.csv \\
        --known-load ../shared/data/wpi-psm/one_105g_parallel.csv:0.105:parallel_upper:0.165,-0.020,0 \\
        --out /tmp/loads.md

``--known-load FILE:MASS_KG:LINK:X,Y,Z`` (repeatable): a recording with that mass at that point
of that link's frame (frames: :mod:`wrenchd.models.physics.point_load`).
``--train`` may be given more than once; ``file:a:b`` takes the window from a to b seconds.
``--lookahead-ms 10,25`` adds the hybrid with an acceleration that reads that far past the
estimated sample: the accuracy an estimate published that much later would have (offline
only; the service's step 1 is causal).
The evaluation is :mod:`wrenchd.service.studies.real_data`; the report is Markdown with a JSON
copy of the numbers beside it.
"""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path

MODEL_NAMES = ("lstm", "ls", "hybrid", "lstm-residual")


def _models(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if text == "all":
        return MODEL_NAMES
    bad = [n for n in names if n not in MODEL_NAMES]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"unknown models {bad}; choose from "
                                         f"{', '.join(MODEL_NAMES)} or all")
    return names


def _milliseconds(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated milliseconds, got {text!r}"
                                         ) from None
    if not values or any(not v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"look-aheads must be positive, got {text!r}")
    return values


def _command(args: argparse.Namespace) -> str:
    parts = ["wrenchd", "real-data"]
    if args.models != MODEL_NAMES:
        parts += ["--models", ",".join(args.models)]
    parts += [a for t in args.train for a in ("--train", t)] + ["--test", args.test]
    parts += [a for t in args.load for a in ("--load", t)]
    parts += [a for t in args.known_load for a in ("--known-load", t)]
    if args.lookahead_ms:
        parts += ["--lookahead-ms", ",".join(f"{ms:g}" for ms in args.lookahead_ms)]
    for flag in ("seed", "epochs", "hybrid_epochs", "threads"):
        value = getattr(args, flag)
        if value:
            parts += [f"--{flag.replace('_', '-')}", str(value)]
    return " ".join(shlex.quote(p) for p in parts + ["--out", args.out])


def _cmd(args: argparse.Namespace) -> int:
    import torch
    from wrenchd.service.studies.newtons import KnownLoad
    from wrenchd.service.studies.real_data import Source, evaluate
    from wrenchd.service.studies.real_data_report import markdown

    if args.threads:
        torch.set_num_threads(args.threads)
    r = evaluate([Source.parse(t) for t in args.train], Source.parse(args.test), args.models,
                 args.seed, args.epochs, args.hybrid_epochs, [Source.parse(s) for s in args.load],
                 args.lookahead_ms, [KnownLoad.parse(k) for k in args.known_load])
    try:
        from wrenchd.service.provenance import PROVENANCE_KEY, provenance
    except ImportError:                       # pragma: no cover - older trees
        pass
    else:
        r[PROVENANCE_KEY] = provenance()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(markdown(r, _command(args))
                   + ("\n" + Path(args.notes).read_text() if args.notes else ""))
    out.with_suffix(".json").write_text(json.dumps(r, indent=1) + "\n")
    keys = [k for k in r["test_file"] if k.endswith("_rmse")]
    summary: dict = {"test_file": {k: [round(v, 4) for v in r["test_file"][k]] for k in keys}}
    summary["tip_force_rms_N"] = {k: round(v["rms"], 3)
                                  for k, v in r["test_file"]["tip_force_N"].items()}
    if r["test_file"]["tip_force_floor_N"]:
        summary["tip_force_rms_N"]["floor"] = round(r["test_file"]["tip_force_floor_N"]["rms"], 3)
    if "known_loads" in r:
        summary["known_loads"] = [{"file": k["file"], "mass_kg": k["mass_kg"],
                                   "fitted_mass_kg": round(k["fitted_mass_kg"], 4)}
                                  for k in r["known_loads"]]
        summary["known_load_pairs"] = [
            {"files": p["files"], "expected_difference_kg": round(p["expected_difference_kg"], 4),
             "fitted_difference_kg": round(p["fitted_difference_kg"][p["served"]], 4),
             "efforts_alone_kg": round(p["fitted_difference_kg"]["effort"], 4)}
            for p in r["known_load_pairs"]]
    print(json.dumps(summary, indent=1))
    return 0


def register(subparsers) -> None:
    """Add ``wrenchd real-data`` to the CLI."""
    p = subparsers.add_parser("real-data", help="step 1 models on WPI recordings",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--train", required=True, action="append",
                   help="WPI CSV to train on, or file:start_s:stop_s (repeatable)")
    p.add_argument("--test", required=True, help="WPI CSV to test on, or file:start_s:stop_s")
    p.add_argument("--load", action="append", default=[],
                   help="a recording with added load (repeatable; the first two give a ratio)")
    p.add_argument("--known-load", action="append", default=[],
                   metavar="FILE:MASS_KG:LINK:X,Y,Z",
                   help="a recording with a known mass at a known point of a link's frame "
                        "(repeatable), e.g. one_205g_parallel.csv:0.205:parallel_upper:"
                        "0.165,-0.023,0")
    p.add_argument("--models", type=_models, default=MODEL_NAMES,
                   help=f"comma-separated subset of {','.join(MODEL_NAMES)} (default all)")
    p.add_argument("--out", required=True, help="Markdown report (a .json beside it)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=int, default=None, help="replace the LSTM recipe's epochs")
    p.add_argument("--hybrid-epochs", type=int, default=None,
                   help="replace the hybrid residual net's epochs (200)")
    p.add_argument("--lookahead-ms", type=_milliseconds, default=(),
                   help="also the hybrid whose acceleration reads this far ahead, e.g. 10,25 "
                        "(offline: measures what that latency would buy)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--notes", default=None, help="Markdown appended to the report")
    p.set_defaults(func=_cmd)
