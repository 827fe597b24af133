"""The ``wrenchd`` command line.

Sub-commands:
  serve      the daemon: zenoh in, wrenches out, gated lifelong adaptation, MCAP log
  echo       print a daemon's live wrenches, events or status
  config     print the daemon's effective settings
  robot      stream the simulated PSM over zenoh and record its ground truth
  simulate   run a simulator scenario and write the session to MCAP
  inspect    summarise an MCAP session (topics, samples, truncation)
  effects    list the effect vocabulary of model files, with parameters and defaults
  bench      speed of the estimator, the daemon and the replay (``bench inference`` ...)
  train, reproduce, patient-gap, real-data, real-robot, identify, discrepancy, discrepancy-sweep, discrepancy-real,
  replay, compare, recovery, announce, excite, fit: see ``wrenchd <command> --help``
"""

from __future__ import annotations

import argparse
import importlib
import sys

from wrenchd.models.errors import WrenchdError

#: The verbs, in the order ``wrenchd --help`` lists them: one module each under
#: ``wrenchd.service.cli``, whose ``register(subparsers)`` adds a parser that sets
#: ``func(args) -> int``. A module imports nothing heavy (torch, scipy, river, pinocchio)
#: until its ``func`` runs.
VERBS: list[str] = ["simulate", "inspect", "effects", "serve", "config", "robot", "echo",
                    "bench", "train", "reproduce", "patient_gap", "real_data", "real_robot", "identify", "discrepancy",
                    "discrepancy_sweep", "discrepancy_real", "replay", "compare", "recovery",
                    "announce", "excite", "fit"]


def build_parser() -> argparse.ArgumentParser:
    """The parser of every verb in :data:`VERBS`."""
    parser = argparse.ArgumentParser(prog="wrenchd", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    for verb in VERBS:
        importlib.import_module(f"{__name__}.{verb}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one verb; a :class:`WrenchdError` becomes its message on stderr and exit code 2.

    SIGINT and SIGTERM are a stop request for the whole run
    (:mod:`wrenchd.service.runtime.stopping`): the daemon, the robot and the streaming verbs
    stop cleanly and exit 0; a verb that computes stops at its next unit of work with exit
    status 128 + the signal's number, writing no partial result."""
    from wrenchd.service import provenance  # noqa: F401  (its run meter starts with the process)
    from wrenchd.service.runtime.stopping import StopSignals, Stopped

    with StopSignals() as stop:
        args = build_parser().parse_args(argv)
        try:
            if stop.requested:
                raise Stopped(stop.first_signal())
            return int(args.func(args) or 0)
        except WrenchdError as exc:
            print(f"wrenchd: error: {exc}", file=sys.stderr)
            return 2
        except Stopped as exc:
            print(f"wrenchd: stopped by {exc}", file=sys.stderr)
            return 128 + exc.signum


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
