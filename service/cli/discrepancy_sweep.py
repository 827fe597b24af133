"""``wrenchd discrepancy-sweep``: the hidden-effect study (recall and false positives over
many seeds), :func:`wrenchd.service.studies.discrepancy.hidden_effect_sweep`; with
``--cells``, the effect-cell study (every kind and place of an effect at 2, 5 and 20 noise
floors, a confusion table), :func:`wrenchd.service.studies.effect_cells.effect_cell_study`."""

from __future__ import annotations

import argparse
from pathlib import Path


def discrepancy_sweep(args: argparse.Namespace) -> int:
    from wrenchd.service.studies.discrepancy import hidden_effect_sweep

    if args.cells:
        from wrenchd.service.studies.effect_cells import effect_cell_study

        data = effect_cell_study(Path(args.out), args.seeds, args.duration,
                                 log=lambda m: print(m, flush=True))
        s = data["summary"]
        print("cells named right on >= 90 % of runs: " + ", ".join(
            f"{m}x {n} of {s['cells']}" for m, n in s["cells_right_90pct"].items())
            + f"; controls named something {s['controls_named_something']} of "
            f"{s['controls']} -> {Path(args.out) / 'effect-cells.md'}")
        return 0
    return hidden_effect_sweep(Path(args.out), args.seeds, args.duration, args.pairs_seeds,
                               args.effects, args.none_seeds)


def register(sub) -> None:
    p = sub.add_parser("discrepancy-sweep",
                       help="hidden-effect study: recall and false positives over seeds")
    p.add_argument("--out", default="reports/discrepancy", help="folder for hidden-effects.md/json")
    p.add_argument("--seeds", type=int, default=20,
                   help="seeds per single hidden effect and for none")
    p.add_argument("--none-seeds", type=int, default=None,
                   help="seeds with nothing hidden (default: --seeds)")
    p.add_argument("--pairs-seeds", type=int, default=5, help="seeds per pair of hidden effects")
    p.add_argument("--duration", type=float, default=30.0, help="simulated recording [s]")
    p.add_argument("--effects", nargs="*", help="only these hidden effects (default: all)")
    p.add_argument("--cells", action="store_true",
                   help="the effect-cell study instead: every (kind, place) at 2, 5 and 20 "
                        "noise floors, --seeds seeds each (effect-cells.md/json)")
    p.set_defaults(func=discrepancy_sweep)
