"""``wrenchd discrepancy-sweep``: the hidden-effect study (recall and false positives over
many seeds), :func:`wrenchd.service.studies.discrepancy.hidden_effect_sweep`."""

from __future__ import annotations

import argparse
from pathlib import Path


def discrepancy_sweep(args: argparse.Namespace) -> int:
    from wrenchd.service.studies.discrepancy import hidden_effect_sweep

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
    p.set_defaults(func=discrepancy_sweep)
