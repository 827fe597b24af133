"""``wrenchd patient-gap``: how much of the paper-scale run's gap to the floor is the patient.

    wrenchd patient-gap --run reports/paper-scale --out reports/paper-scale/patient-gap
    wrenchd patient-gap --run reports/paper-scale --trials 2 --lengths 30 --out /tmp/gap

For each of the paper-scale run's contact trials (unseen patients), fresh free motion of that
trial's own patient trains a correction net with the run's Corr recipe (``own Corr``), and the
daemon's gated pipeline replays the same motion and then the trial (``wrenchd online``); the
run's own figures for the trials (read from ``RUN/cells``) stand beside them; and step 1
(``paper-base``, ``paper-seal``) on its in-domain trials with unseen patients, with its
training patients and with the fixed patient.
:mod:`wrenchd.service.studies.patient_gap` says how. Step 1 is the shipped ``paper-seal``
(the run's Seal, seed 0). Writes ``OUT/results.json`` and ``OUT/README.md``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def patient_gap(args: argparse.Namespace) -> int:
    import torch

    from wrenchd.models.errors import ConfigError
    from wrenchd.models.estimator.pretrained import load_pretrained
    from wrenchd.service.provenance import RunMeter, stamp
    from wrenchd.service.studies.patient_gap import PatientGapConfig, markdown, run_patient_gap
    from wrenchd.service.studies.reproduction_cells import CELLS
    from wrenchd.service.studies.reproduction_config import PAPER

    meter = RunMeter()
    if args.threads:
        torch.set_num_threads(args.threads)
    cells = Path(args.run) / CELLS
    if not cells.is_dir():
        raise ConfigError(f"{cells}: no cells of a paper-scale run (wrenchd reproduce --paper)")
    try:
        lengths = tuple(float(x) for x in args.lengths.split(","))
    except ValueError:
        raise ConfigError(f"--lengths: seconds separated by commas, got {args.lengths!r}") from None
    overrides = {"epochs": args.max_epochs} if args.max_epochs else None
    try:
        config = PatientGapConfig(lengths_s=lengths, trials=args.trials, seed=args.seed,
                                  online=not args.no_online, corr_overrides=overrides,
                                  step1_trials=args.step1_trials)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    start = time.perf_counter()
    results = run_patient_gap(PAPER, cells, load_pretrained("paper-seal"), config,
                              log=lambda m: print(m, file=sys.stderr, flush=True),
                              base=load_pretrained("paper-base"))
    command = "wrenchd patient-gap " + " ".join(sys.argv[2:])
    results["command"] = command
    results["wall_seconds"] = round(time.perf_counter() - start, 1)
    stamp(results, run=meter)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "README.md").write_text(markdown(results, command))
    print(json.dumps({"out": str(out), "wall_seconds": results["wall_seconds"]}))
    return 0


def register(subparsers) -> None:
    """Add ``wrenchd patient-gap`` to the CLI."""
    p = subparsers.add_parser("patient-gap", help="the paper-scale run's trials with step 2 "
                              "trained on each trial's own patient",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", default="reports/paper-scale",
                   help="the paper-scale run's report folder (its cells are read)")
    p.add_argument("--out", required=True, help="report directory")
    p.add_argument("--lengths", default="30,60,120,300",
                   help="seconds of the patient's own free motion, comma separated")
    p.add_argument("--trials", type=int, default=None, help="the first N contact trials only")
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--max-epochs", type=int, default=None,
                   help="the Corr recipe's epoch ceiling (default: the run's)")
    p.add_argument("--step1-trials", type=int, default=None,
                   help="the first N in-domain step-1 trials only (0: none; default all)")
    p.add_argument("--no-online", action="store_true",
                   help="skip the replays of the daemon's pipeline")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.set_defaults(func=patient_gap)
