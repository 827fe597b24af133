"""``wrenchd recovery``: the insufflation-recovery measure per seed and per pipeline setting.

The measure, its rows and its options are described in :mod:`wrenchd.service.studies.recovery`.

Example::

    wrenchd recovery --seeds 3,4,5 --set '{}' --set '{"adaptation": {"refit_shrink": 0}}'
    wrenchd recovery --seeds 3,4 --settled --bins 20 --duration 600 --json recovery.json
    wrenchd recovery --model BUNDLE --session 'concat:one_no_weight.csv*6,one_205g_parallel.csv*6'
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from wrenchd.models.errors import ConfigError


def recovery(args: argparse.Namespace) -> int:
    from wrenchd.service.provenance import RunMeter, stamp
    from wrenchd.service.studies.recovery import TARGET_RATIO, run_recovery

    meter = RunMeter()
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        raise ConfigError(f"--seeds must be comma-separated integers, got {args.seeds!r}")
    if not seeds:
        raise ConfigError("--seeds names no seed")
    result = run_recovery(seeds, args.set, args.duration, args.model, settled=args.settled,
                          bin_s=args.bins, announce=args.announce,
                          sessions_given=args.session or None)
    for s in result["summary"]:
        line = (f"{s['set']}: mean ratio {s['mean_ratio']:.3f}, {s['within_target']} of "
                f"{s['seeds']} {'sessions' if args.session else 'seeds'} within {TARGET_RATIO}, worst {s['worst_ratio']:.3f}, "
                f"contact samples offered {s['contact_offered']}")
        if args.settled:
            line += f"; excess over settled: mean {s['mean_excess']:.3f}, worst " \
                    f"{s['worst_excess']:.3f}"
        print(line)
    if args.json:
        Path(args.json).write_text(json.dumps(stamp(result, run=meter), indent=2) + "\n")
    return 0


def register(sub) -> None:
    p = sub.add_parser("recovery", help="insufflation-change recovery per seed and per "
                                        "pipeline setting")
    p.add_argument("--seeds", default="3,4,5,6", help="scenario seeds, comma-separated")
    p.add_argument("--set", action="append", default=[],
                   help="JSON PipelineConfig overrides (repeatable; none: the defaults)")
    p.add_argument("--duration", type=float, default=220.0, help="session length [s]")
    p.add_argument("--model", default="seal", help="step-1 model (shipped name or checkpoint)")
    p.add_argument("--settled", action="store_true",
                   help="also replay each seed at the new pressure from the start and report "
                        "post / that level (excess; module docstring)")
    p.add_argument("--bins", type=float, metavar="SECONDS",
                   help="also give the free-motion error per bin of this length from the "
                        "change to the end (with --settled: over the settled replay's)")
    p.add_argument("--announce", action="store_true",
                   help="announce the pressure step to the pipeline, as the daemon's setup "
                        "key would (the adapter then carries its buffer over)")
    p.add_argument("--session", action="append", default=[], metavar="SESSION",
                   help="measure on this session instead of the simulated seeds (repeatable; "
                        "any form replay takes, e.g. concat:a.csv*6,b.csv*6), around its "
                        "first set-up change")
    p.add_argument("--json", help="also write the rows and summary to this file")
    p.set_defaults(func=recovery)
