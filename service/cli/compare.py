"""``wrenchd compare``: several policies over several sessions, a table and plots.

The work is :func:`wrenchd.service.replay.compare.run_compare`; ``--config`` and ``--seed``
as in :mod:`wrenchd.service.cli.pipeline_config`.
"""

from __future__ import annotations

import argparse

from wrenchd.service.cli.pipeline_config import common_options, load_pipeline_config


def compare(args: argparse.Namespace) -> int:
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()
    from wrenchd.service.replay.compare import run_compare
    from wrenchd.service.pipeline.step1 import load_free_space

    policies = [p for p in args.policies.split(",") if p]
    sessions = [s for part in args.sessions for s in part.split(",") if s]
    run_compare(policies, sessions, args.out, load_free_space(args.model),
                load_pipeline_config(args.config, args.seed))
    print(f"wrote {args.out}/compare.md, compare.json and plots")
    return 0


def register(sub) -> None:
    p = sub.add_parser("compare", parents=[common_options()],
                       help="several policies over several sessions: table and plots")
    p.add_argument("--policies", default="gated,frozen,ungated",
                   help="comma-separated policy names")
    p.add_argument("--sessions", nargs="+", required=True,
                   help="sessions (space- or comma-separated)")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=compare)
