"""``wrenchd compare``: several policies over several sessions, a table and plots.

The work is :func:`wrenchd.service.replay.compare.run_compare`; ``--config``, ``--seed`` and
``--model`` (a shipped name, a checkpoint or a ``wrenchd fit`` bundle) as in
:mod:`wrenchd.service.cli.pipeline_config`; the session forms in
:mod:`wrenchd.service.replay.source`.
"""

from __future__ import annotations

import argparse

from wrenchd.models.errors import ConfigError
from wrenchd.service.cli.pipeline_config import common_options, load_pipeline_config


def compare(args: argparse.Namespace) -> int:
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()
    from wrenchd.service.replay.compare import run_compare
    from wrenchd.service.pipeline.step1 import load_free_space

    from wrenchd.service.replay.source import split_sessions

    policies = [p for p in args.policies.split(",") if p]
    if not policies:
        raise ConfigError("--policies names no policy")
    sessions = split_sessions(args.sessions)
    run_compare(policies, sessions, args.out, load_free_space(args.model),
                load_pipeline_config(args.config, args.seed), announce=args.announce)
    print(f"wrote {args.out}/compare.md, compare.json and plots")
    return 0


def register(sub) -> None:
    p = sub.add_parser("compare", parents=[common_options()],
                       help="several policies over several sessions: table and plots")
    p.add_argument("--policies", default="gated,frozen,ungated",
                   help="comma-separated policy names")
    p.add_argument("--sessions", nargs="+", required=True,
                   help="sessions (space- or comma-separated): .mcap, .csv, rosbag2 "
                        "directory, sim:SCENARIO:DURATION[:SEED], concat:PATH[*N][,PATH[*N]...]"
                        " (runs to the end of its argument), inject:SEED:SESSION")
    p.add_argument("--announce", action="store_true",
                   help="announce each session's set-up changes to the pipeline, as in "
                        "wrenchd replay --announce")
    p.add_argument("--out", required=True, help="output directory")
    p.set_defaults(func=compare)
