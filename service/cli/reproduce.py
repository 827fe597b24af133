"""``wrenchd reproduce``: the paper's tables on the simulator, as Markdown + plot + JSON.

    wrenchd reproduce --full --out reports/paper-reproduction     # ~30 min on 2 CPU cores
    wrenchd reproduce --quick --out /tmp/repro                    # seconds (the test suite)

Writes ``results.json`` (every number), ``force-rmse-vs-length.png`` (matplotlib, Agg) and
``README.md`` (the three tables, the oracle ratios, the fast Corr recipe beside the paper's).
The experiment itself is :mod:`wrenchd.service.studies.reproduction`, the report
:mod:`wrenchd.service.studies.reproduction_report`; ``results.json`` carries the provenance
of the run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def reproduce(args: argparse.Namespace) -> int:
    import torch

    from wrenchd.models.estimator.pretrained import load_pretrained
    from wrenchd.service.provenance import RunMeter, stamp
    from wrenchd.service.studies.reproduction import QUICK, ReproductionConfig, run_reproduction
    from wrenchd.service.studies.reproduction_report import PLOT, markdown, plot, pretrained_info

    meter = RunMeter()
    if args.threads:
        torch.set_num_threads(args.threads)
    config = QUICK if args.quick else ReproductionConfig()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.render_only:                          # tables and plot again, no training
        results = json.loads((out / "results.json").read_text())
        wall, command = results["wall_seconds"], results["command"]
    else:
        start = time.perf_counter()
        results = run_reproduction(config, load_pretrained("base"), load_pretrained("seal"),
                                   pretrained_info(),
                                   log=lambda m: print(m, file=sys.stderr, flush=True))
        wall = time.perf_counter() - start
        command = "wrenchd reproduce " + " ".join(args.argv)
        results["wall_seconds"], results["command"] = round(wall, 1), command
        stamp(results, run=meter)
        (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    plot(results, out / PLOT)
    (out / "README.md").write_text(markdown(results, command, wall) + args.notes_text)
    print(json.dumps({"out": str(out), "wall_seconds": round(wall, 1)}))
    return 0


def register(subparsers) -> None:
    """Add ``wrenchd reproduce`` to the CLI."""
    p = subparsers.add_parser("reproduce", help="regenerate the paper's tables on the simulator",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--full", action="store_true", help="the paper's lengths (~30 min)")
    mode.add_argument("--quick", action="store_true", help="tiny lengths and epochs (seconds)")
    p.add_argument("--out", required=True, help="report directory")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--notes", default=None, help="Markdown file appended to the report")
    p.add_argument("--render-only", action="store_true",
                   help="rewrite README.md and the plot from the existing results.json")

    def run(args: argparse.Namespace) -> int:
        args.argv = [a for a in sys.argv[2:] if a != "--render-only"
                     ] if sys.argv[1:2] == ["reproduce"] else []
        args.notes_text = "\n" + Path(args.notes).read_text() if args.notes else ""
        return reproduce(args)

    p.set_defaults(func=run)
