"""``wrenchd replay``: a session through the daemon's pipeline, with metrics.

SESSION is an ``.mcap`` (simulated or a daemon log), a real ``.csv``, a rosbag2 directory,
``sim:SCENARIO:DURATION[:SEED]``, ``concat:PATH[*N][,PATH[*N]...]`` or ``inject:SEED:SESSION``
(see :mod:`wrenchd.service.replay.source`); ``--config`` and ``--seed`` as in
:mod:`wrenchd.service.cli.pipeline_config`. ``--report`` writes ``metrics.json`` (with its
provenance) and ``metrics.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from wrenchd.service.cli.choices import POLICY_CHOICES
from wrenchd.service.cli.pipeline_config import common_options, load_pipeline_config


def replay_session(args: argparse.Namespace) -> int:
    from wrenchd.service.provenance import RunMeter, stamp
    from wrenchd.service.runtime.scheduling import one_compute_thread

    meter = RunMeter()
    one_compute_thread()
    from wrenchd.service.replay.loop import replay
    from wrenchd.service.replay.metrics import metrics_markdown, replay_metrics
    from wrenchd.service.replay.output import nan_to_none, write_replay_mcap
    from wrenchd.service.replay.policies import get_policy
    from wrenchd.service.replay.source import announced_changes, load_session
    from wrenchd.service.pipeline.step1 import load_free_space

    config = get_policy(args.policy).configure(load_pipeline_config(args.config, args.seed))
    session = load_session(args.session)
    n = len(session.joint_states.t)

    def estimating(_pipeline) -> None:      # the session is loaded: say so before the long part
        print(f"wrenchd replay: estimating {n} samples of {args.session} "
              f"(Ctrl-C stops between batches)", file=sys.stderr, flush=True)

    r = replay(session, load_free_space(args.model), config, policy=args.policy,
               batched=not args.streaming, adaptation=args.adaptation,
               result_delay_s=args.result_delay, pipeline_hook=estimating,
               setup_changes=announced_changes(session) if args.announce else ())
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        write_replay_mcap(args.output, r, {"model": args.model})
    m = replay_metrics(r, session)
    if args.report:
        out = Path(args.report)
        out.mkdir(parents=True, exist_ok=True)
        stamped = stamp(nan_to_none(m), run=meter)
        (out / "metrics.json").write_text(json.dumps(stamped, indent=1, default=str) + "\n")
        (out / "metrics.md").write_text(metrics_markdown(m))
    print(metrics_markdown(m))
    return 0


def register(sub) -> None:
    p = sub.add_parser("replay", parents=[common_options()],
                       help="replay a session through the daemon's pipeline, with metrics")
    p.add_argument("session", help="file.mcap, file.csv, a rosbag2 directory, "
                                   "sim:SCENARIO:DURATION[:SEED], concat:PATH[*N][,PATH[*N]...] "
                                   "or inject:SEED:SESSION")
    p.add_argument("--policy", default="gated", choices=POLICY_CHOICES,
                   metavar="NAME", help="adaptation policy: %(choices)s (default %(default)s)")
    p.add_argument("--announce", action="store_true",
                   help="announce the session's set-up changes to the pipeline as the "
                        "daemon's setup key would: a scenario's (its drift steps), a concat: "
                        "session's (each change of recording) or, for a daemon log, the "
                        "notices it logged")
    p.add_argument("-o", "--output", help="write estimates and events to this MCAP")
    p.add_argument("--report", help="directory for metrics.json and metrics.md")
    p.add_argument("--streaming", action="store_true",
                   help="estimate sample by sample (slow; the batched path gives the same)")
    p.add_argument("--adaptation", choices=["worker", "inline"], default="worker",
                   help="rounds in a forked worker (default; their nets serve "
                        "--result-delay s later) or inline at their sample")
    p.add_argument("--result-delay", type=float, default=1.0,
                   help="worker: sample time from a round falling due to its net serving [s]")
    p.set_defaults(func=replay_session)
