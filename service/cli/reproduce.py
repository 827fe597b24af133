"""``wrenchd reproduce``: the paper's tables on the simulator, as Markdown + plot + JSON.

    wrenchd reproduce --full --out reports/paper-reproduction     # ~30 min on 2 CPU cores
    wrenchd reproduce --quick --out /tmp/repro                    # seconds (the test suite)
    wrenchd reproduce --paper --out reports/paper-scale           # the paper-scale run
    wrenchd reproduce --paper-quick --out /tmp/paper              # its pipeline, toy sizes

``--full`` is the shortened run of the committed report (one fixed patient, shipped step-1
weights, 6-epoch Troc and Xfer, one seed). ``--paper`` is the paper-scale run: patient
variation, the paper's 92 no-contact and 12 contact trials, three training seeds, Base and
Seal trained here on an hour of free motion each, every recurrent network to convergence
(the paper's recipes, 1000 epochs as the ceiling, early stopping on held-out sessions), the
paper's Corr recipe, the realistic handle, a 10 Hz causal output filter with both floors
(:data:`wrenchd.service.studies.reproduction.PAPER`); the options below change its sizes.

A run that trains step 1 (``--paper``, ``--paper-quick``) saves every recurrent network's
training under ``OUT/checkpoints/`` after each epoch, and each Corr once trained: the same
command started again after a stop goes on where it stopped (a file of another recipe or data
is refused; remove the folder to start afresh). It writes the trained step-1 models under
``OUT/weights/`` (``Base-seed0.pt``...: estimator checkpoints with their held-out scores,
usable as ``--model``). The checkpoints stay on the machine that wrote them (tens of MB, not
in version control); each finished (training seed, length) cell's scores go to
``OUT/cells/`` (a few kB each, committed with the report): a sitting on a fresh clone reads
those cells instead of training them again, and takes step 1 from ``OUT/weights/`` or, for
``--paper``'s seed 0, from the shipped ``paper-base`` and ``paper-seal`` when they were trained
on the same recipe and data size.

Writes ``results.json`` (every number), ``force-rmse-vs-length.png`` (matplotlib, Agg) and
``README.md`` (the three tables, the oracle ratios, the fast Corr recipe beside the paper's),
and writes them again after every (training seed, length) cell while the run goes on: until
it ends, their ``progress`` says which cells are done.
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

#: The folder under ``--out`` that holds the training checkpoints.
CHECKPOINTS = "checkpoints"
#: The folder under ``--out`` that holds the trained step-1 models.
WEIGHTS = "weights"


def finished_step1(out: Path, paper: bool):
    """Where a sitting looks for a finished step-1 training of ``name`` and ``seed``: this
    run's ``weights`` folder, then, for the paper-scale run as it is defined (``paper``: no
    option changed it), the shipped copy of its seed 0 (``paper-base``, ``paper-seal``;
    checked against the recipe, seed included, and the data size by
    :func:`~wrenchd.service.studies.reproduction_training.train_step1`)."""
    from wrenchd.models.estimator.pretrained import FILES, pretrained_path

    def candidates(name: str, seed: int) -> list[Path]:
        shipped = f"paper-{name.lower()}"
        return [out / WEIGHTS / f"{name}-seed{seed}.pt"] + (
            [pretrained_path(shipped)] if paper and shipped in FILES else [])
    return candidates


def reproduce(args: argparse.Namespace) -> int:
    import torch

    from wrenchd.models.estimator.pretrained import load_pretrained
    from wrenchd.service.provenance import RunMeter, stamp
    from wrenchd.service.studies.reproduction_cells import CELLS
    from wrenchd.service.studies.reproduction import (
        PAPER,
        PAPER_QUICK,
        QUICK,
        ReproductionConfig,
        ReproductionResult,
        run_reproduction,
    )
    from wrenchd.service.studies.reproduction_report import pretrained_info

    meter = RunMeter()
    if args.threads:
        torch.set_num_threads(args.threads)
    config = (QUICK if args.quick else PAPER if args.paper else PAPER_QUICK if args.paper_quick
              else ReproductionConfig())
    config = with_options(config, args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.render_only:                          # tables and plot again, no training
        results = ReproductionResult.read(out / "results.json")
        wall, command = results.wall_seconds, results.command
        write(out, results, command, wall, args.notes_text)
    else:
        start = time.perf_counter()
        command = "wrenchd reproduce " + " ".join(args.argv)

        def save(results: ReproductionResult) -> float:
            """results.json, the report and the plot of the run so far; the wall time."""
            wall = time.perf_counter() - start
            data = results.to_json()
            data["wall_seconds"], data["command"] = round(wall, 1), command
            stamp(data, run=meter)
            write(out, ReproductionResult.model_validate(data), command, wall, args.notes_text,
                  data)
            return wall

        shipped = config.step1 is None
        results = run_reproduction(config, load_pretrained("base") if shipped else None,
                                   load_pretrained("seal") if shipped else None,
                                   pretrained_info() if shipped else None,
                                   log=lambda m: print(m, file=sys.stderr, flush=True),
                                   device=args.device,
                                   checkpoints=(out / CHECKPOINTS if config.step1 is not None
                                                else None),
                                   weights=out / WEIGHTS if config.step1 is not None else None,
                                   progress=save,
                                   cells=out / CELLS if config.step1 is not None else None,
                                   finished=(finished_step1(out, config == PAPER)
                                             if config.step1 is not None else None))
        wall = save(results)
    print(json.dumps({"out": str(out), "wall_seconds": round(wall, 1)}))
    return 0


def write(out: Path, results, command: str, wall: float, notes: str,
          data: dict | None = None) -> None:
    """``OUT/results.json`` (when ``data``, the results' JSON, is given), ``README.md`` and the
    plot; the JSON is written to a temporary file and renamed, so that a run stopped while
    writing leaves the last complete one."""
    from wrenchd.service.studies.reproduction_report import PLOT, markdown, plot

    if data is not None:
        tmp = out / "results.json.tmp"
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        tmp.replace(out / "results.json")
    plot(results, out / PLOT)
    (out / "README.md").write_text(markdown(results, command, wall) + notes)


def with_options(config, args: argparse.Namespace):
    """``config`` with the command line's size options put in."""
    update: dict = {}
    if args.seeds:
        update["training_seeds"] = tuple(int(x) for x in args.seeds.split(","))
    if args.no_contact_trials:
        update["no_contact_trials"] = args.no_contact_trials
    if args.contact_trials:
        update["contact_trials"] = args.contact_trials
    if args.fixed_patient:
        update["patient_variation"] = False
    if args.max_epochs:
        update["recurrent_overrides"] = {**config.recurrent_overrides,
                                         "epochs": args.max_epochs}
        if config.step1 is not None:
            update["step1"] = config.step1.model_copy(update={"overrides": {
                **config.step1.overrides, "epochs": args.max_epochs}})
    if args.step1_hours is not None:
        if config.step1 is None:
            raise SystemExit("--step1-hours needs a run that trains step 1 (--paper)")
        update["step1"] = update.get("step1", config.step1).model_copy(
            update={"duration_s": args.step1_hours * 3600.0})
    # validate the combination as a whole
    return type(config)(**{**config.model_dump(), **update}) if update else config


def register(subparsers) -> None:
    """Add ``wrenchd reproduce`` to the CLI."""
    p = subparsers.add_parser("reproduce", help="regenerate the paper's tables on the simulator",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--full", action="store_true", help="the paper's lengths (~30 min)")
    mode.add_argument("--quick", action="store_true", help="tiny lengths and epochs (seconds)")
    mode.add_argument("--paper", action="store_true",
                      help="the paper-scale run (hours; a GPU trains the recurrent networks)")
    mode.add_argument("--paper-quick", action="store_true",
                      help="the paper-scale pipeline at toy sizes (under a minute)")
    p.add_argument("--seeds", default=None, help="training seeds, comma separated (e.g. 0,1,2)")
    p.add_argument("--no-contact-trials", type=int, default=None, help="no-contact test trials")
    p.add_argument("--contact-trials", type=int, default=None, help="contact test trials")
    p.add_argument("--max-epochs", type=int, default=None,
                   help="epoch ceiling of step 1, Troc and Xfer (early stopping still applies)")
    p.add_argument("--step1-hours", type=float, default=None,
                   help="free-motion training data per step-1 model [h] (--paper: 1)")
    p.add_argument("--fixed-patient", action="store_true",
                   help="one fixed patient in every session (no patient variation)")
    p.add_argument("--device", default="cpu",
                   help="where the recurrent networks train: cpu, cuda, or auto (CUDA when "
                        "present)")
    p.add_argument("--out", required=True, help="report directory")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--notes", default=None, help="Markdown file appended to the report")
    p.add_argument("--render-only", action="store_true",
                   help="rewrite README.md and the plot from the existing results.json")

    def run(args: argparse.Namespace) -> int:
        args.argv = [a for a in sys.argv[2:] if a != "--render-only"
                     ] if sys.argv[1:2] == ["reproduce"] else []
        args.notes_text = "\n" + Path(args.notes).read_text() if args.notes else ""
        if args.device == "auto":
            args.device = None
        return reproduce(args)

    p.set_defaults(func=run)
