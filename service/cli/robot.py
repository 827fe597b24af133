"""``wrenchd robot``: stream the simulated PSM over zenoh and record its ground truth."""

from __future__ import annotations

import argparse
from pathlib import Path

from wrenchd.service.cli.choices import SCENARIO_CHOICES

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
"""Loopback by default: nothing leaves the machine unless the user says so."""


def robot(args: argparse.Namespace) -> int:
    from wrenchd.adapters.zenoh_config import has_endpoints, zenoh_config
    from wrenchd.service.runtime.robot import serve_simulated

    zenoh = zenoh_config(config_file=args.zenoh_config, mode=args.mode,
                         listen=args.listen or [], connect=args.connect or [])
    if not (args.listen or has_endpoints(zenoh, "connect") or has_endpoints(zenoh, "listen")):
        zenoh = zenoh_config(config_file=args.zenoh_config, mode=args.mode,
                             listen=[DEFAULT_LISTEN], connect=args.connect or [])
    return serve_simulated(scenario=args.scenario, seed=args.seed, duration_s=args.duration,
                           out_dir=Path(args.out_dir), arm=args.arm, rate_hz=args.rate,
                           zenoh=zenoh, prefix=args.prefix, encoding=args.encoding,
                           quiet=args.quiet, announce_setup=not args.no_announce)


def register(sub) -> None:
    p = sub.add_parser("robot", help="stream the simulated PSM over zenoh and record its truth")
    p.add_argument("--scenario", default="trocar-contact", choices=SCENARIO_CHOICES,
                   metavar="NAME", help="one of: %(choices)s (default %(default)s)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--arm", default="PSM1")
    p.add_argument("--prefix", default="dvrk", help="key prefix: {prefix}/{arm}/measured_js")
    p.add_argument("--encoding", default="json", choices=["json", "cdr"])
    p.add_argument("--rate", type=float, default=200.0, help="published rate [Hz]")
    p.add_argument("--out-dir", default="sessions", help="where the MCAP session goes")
    p.add_argument("--mode", default=None, choices=["peer", "client", "router"],
                   help="zenoh mode (default: the --zenoh-config file's, else peer)")
    p.add_argument("--listen", action="append", metavar="ENDPOINT",
                   help=f"zenoh endpoint to listen on (repeatable; default {DEFAULT_LISTEN} "
                        f"unless --connect or the --zenoh-config file names endpoints)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help="zenoh endpoint to connect to (repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="zenoh configuration file (.json5, as zenoh's own tools take it: TLS, "
                        "access, endpoints...); --mode, --listen and --connect apply over it")
    p.add_argument("--quiet", action="store_true", help="no per-second progress lines")
    p.add_argument("--no-announce", action="store_true",
                   help="do not announce the scenario's set-up changes on {prefix}/{arm}/setup")
    p.set_defaults(func=robot)
