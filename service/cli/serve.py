"""``wrenchd serve``: the daemon (zenoh in, wrenches out, gated lifelong adaptation, MCAP log)."""

from __future__ import annotations

import argparse
import os

from wrenchd.service.cli.choices import SCENARIO_CHOICES


def serve(args: argparse.Namespace) -> int:
    from wrenchd.service.runtime.daemon import Daemon
    from wrenchd.service.runtime.scheduling import one_compute_thread
    from wrenchd.service.runtime.settings import load_settings

    from wrenchd.service.bench import stages

    one_compute_thread()
    if os.environ.get(stages.ENV):      # ``bench service --stages``: CPU time per stage
        stages.install(os.environ[stages.ENV])

    overrides: dict = {}
    if args.log_dir:
        overrides["log"] = {"directory": args.log_dir}
    if args.scenario or args.seed is not None:
        sim = {"scenario": args.scenario or "trocar-contact", "seed": args.seed or 0}
        overrides["simulator"] = sim
    live = {k: v for k, v in (("port", args.foxglove_port), ("host", args.foxglove_host))
            if v is not None}
    if live:
        overrides["foxglove"] = live
    settings = load_settings(args.config, **overrides)
    duration = args.duration if args.duration is not None else settings.duration_s
    if duration is not None and settings.duration_s != duration:
        settings = settings.model_copy(update={"duration_s": duration})
    return Daemon(settings).run(duration)


def register(sub) -> None:
    p = sub.add_parser("serve", help="run the daemon (embedded default: simulated PSM1)")
    p.add_argument("--config", help="TOML settings (see deploy/config/); env WRENCHD_* overrides")
    p.add_argument("--duration", type=float, default=None,
                   help="stop after this many seconds (default: until Ctrl-C)")
    p.add_argument("--log-dir", help="MCAP log directory (default: sessions)")
    p.add_argument("--scenario", choices=SCENARIO_CHOICES, default=None, metavar="NAME",
                   help="scenario of the simulated PSM (robot = simulated): %(choices)s")
    p.add_argument("--seed", type=int, default=None, help="seed of the simulated PSM")
    p.add_argument("--foxglove-port", type=int, default=None, metavar="PORT",
                   help="serve a live view to Foxglove on this WebSocket port (0: any free "
                        "one): wrench, external joint torques, gate, status, events")
    p.add_argument("--foxglove-host", default=None, metavar="HOST",
                   help="address of the Foxglove server (default 127.0.0.1: this machine only)")
    p.set_defaults(func=serve)
