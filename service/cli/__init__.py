"""The ``wrenchd`` command line.

Sub-commands:
  serve      the daemon: zenoh in, wrenches out, gated lifelong adaptation, MCAP log
  echo       print a daemon's live wrenches, events or status
  config     print the daemon's effective settings
  robot      stream the simulated PSM over zenoh and record its ground truth
  simulate   run a simulator scenario and write the session to MCAP
  inspect    summarise an MCAP session (topics, samples, truncation)
  effects    list the effect vocabulary of model files, with parameters and defaults
  bench      speed of the estimator (``bench inference``)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from wrenchd.models.errors import WrenchdError

#: Loopback by default: nothing leaves the machine unless the user says so.
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


class LazyChoices:
    """An argparse ``choices`` whose names are loaded on first use.

    The scenario and policy registries live beside torch, pinocchio and scipy, which take
    seconds to import. With these, building the parser imports none of them: ``wrenchd
    announce`` and ``wrenchd echo`` start at once (an announcement's stamp is the arm's latest
    sample when it arrives), and a command that names a scenario loads the registry when
    argparse checks the name. Give the argument a ``metavar``: argparse formats one from the
    choices when the argument is added, and list them in its help with ``%(choices)s``.
    """

    def __init__(self, load) -> None:
        self._load = load
        self._names: list[str] | None = None

    def _get(self) -> list[str]:
        if self._names is None:
            self._names = list(self._load())
        return self._names

    def __contains__(self, name: object) -> bool:
        return name in self._get()

    def __iter__(self):
        return iter(self._get())


def _scenario_names() -> list[str]:
    from wrenchd.adapters.sim.scenarios import SCENARIOS

    return sorted(SCENARIOS)


SCENARIO_CHOICES = LazyChoices(_scenario_names)


def _cmd_simulate(args: argparse.Namespace) -> int:
    from wrenchd.adapters.mcap_session import write_session
    from wrenchd.adapters.sim.scenarios import run_scenario
    from wrenchd.adapters.sim.simulator import SimulatorConfig
    from wrenchd.models.physics.model import PhysicsModel

    model = PhysicsModel.load(args.model) if args.model else None
    config = SimulatorConfig(internal_rate_hz=args.internal_rate, publish_rate_hz=args.rate)
    start = time.perf_counter()
    session = run_scenario(args.scenario, args.duration, args.seed, model=model, config=config)
    simulated = time.perf_counter()
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    write_session(args.output, session)
    done = time.perf_counter()
    n = len(session.joint_states)
    print(f"{args.scenario}: {args.duration:g} s, seed {args.seed}, {n} samples at "
          f"{args.rate:g} Hz (internal {args.internal_rate:g} Hz) -> {args.output}")
    print(f"simulate {simulated - start:.1f} s, write {done - simulated:.1f} s, "
          f"total {done - start:.1f} s, {Path(args.output).stat().st_size / 1e6:.1f} MB")
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from wrenchd.adapters.mcap_session import read_session_report

    session, info = read_session_report(args.session)
    js = session.joint_states
    out = {
        "file": str(args.session),
        "samples": len(js),
        "duration_s": float(js.t[-1] - js.t[0]) if len(js) else 0.0,
        "rate_hz": js.rate_hz,
        "truncated": info.truncated,
        "messages": info.messages,
        "truth": session.truth is not None,
        "effects": sorted(session.truth.effects) if session.truth is not None else [],
        "scenario": (session.metadata.get("scenario") or {}).get("name"),
    }
    print(json.dumps(out, indent=2))
    return 0


def _cmd_effects(args: argparse.Namespace) -> int:
    from wrenchd.models.physics.effects import EFFECTS

    for name, cls in sorted(EFFECTS.items()):
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        print(f"{name}: {doc}")
        for field, info in cls.Params.model_fields.items():
            default = "required" if info.is_required() else repr(info.default)
            print(f"    {field} = {default}  # {info.description or ''}")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    from wrenchd.service.runtime.settings import load_settings
    from wrenchd.service.runtime.daemon import Daemon
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()

    overrides: dict = {}
    if args.log_dir:
        overrides["log"] = {"directory": args.log_dir}
    if args.scenario or args.seed is not None:
        sim = {"scenario": args.scenario or "trocar-contact", "seed": args.seed or 0}
        overrides["simulator"] = sim
    settings = load_settings(args.config, **overrides)
    duration = args.duration if args.duration is not None else settings.duration_s
    if duration is not None and settings.duration_s != duration:
        settings = settings.model_copy(update={"duration_s": duration})
    return Daemon(settings).run(duration)


def _cmd_robot(args: argparse.Namespace) -> int:
    from wrenchd.adapters.zenoh_io import ZenohConfig
    from wrenchd.service.runtime.robot import serve_simulated

    listen = args.listen if args.listen is not None else ([] if args.connect else [DEFAULT_LISTEN])
    zenoh = ZenohConfig(mode=args.mode, listen=listen, connect=args.connect or [])
    return serve_simulated(scenario=args.scenario, seed=args.seed, duration_s=args.duration,
                           out_dir=Path(args.out_dir), arm=args.arm, rate_hz=args.rate,
                           zenoh=zenoh, prefix=args.prefix, encoding=args.encoding,
                           quiet=args.quiet, announce_setup=not args.no_announce)


def _cmd_config(args: argparse.Namespace) -> int:
    from wrenchd.service.runtime.settings import load_settings

    print(json.dumps(load_settings(args.config).model_dump(mode="json"), indent=2))
    return 0


def _cmd_echo(args: argparse.Namespace) -> int:
    from wrenchd.service.cli.echo import echo

    return echo(args)


def _realtime_setting(text: str) -> int | str:
    if text in ("auto", "off"):
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not auto, off or a priority") from None


def _cmd_bench(args: argparse.Namespace) -> int:
    from wrenchd.service.bench.run import run
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()           # the bench process; the daemon and worker do it themselves

    if args.duration is None:
        # replay: a 10 min session (60x real time measured); a shorter one is mostly the
        # calibration minute, whose eager rounds the worker cannot keep up with (38-44x)
        args.duration = {"service": 20.0, "floor": 20.0, "arm": 20.0, "replay": 600.0,
                         "soak": 1800.0}.get(args.kind, 60.0)
    return run(args.kind, args.json, args.duration, args.arms, args.rate, args.pin,
               args.realtime)


#: Modules that add their own sub-commands: each has ``register(subparsers)``, which adds a
#: parser whose ``func(args) -> int`` runs it.
COMMAND_MODULES: list[str] = ["wrenchd.service.cli.train", "wrenchd.service.cli.reproduce", "wrenchd.service.cli.real_data",
                              "wrenchd.service.cli.discrepancy", "wrenchd.service.cli.replay",
                              "wrenchd.service.cli.recovery", "wrenchd.service.cli.announce"]


def build_parser() -> argparse.ArgumentParser:
    import importlib

    parser = argparse.ArgumentParser(prog="wrenchd", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)

    sim = sub.add_parser("simulate", help="simulate a scenario into an MCAP session")
    sim.add_argument("--scenario", required=True, choices=SCENARIO_CHOICES, metavar="NAME",
                     help="one of: %(choices)s")
    sim.add_argument("--duration", type=float, default=60.0, help="session length [s]")
    sim.add_argument("--seed", type=int, default=0)
    sim.add_argument("--model", help="physics model JSON replacing the scenario's physics")
    sim.add_argument("--rate", type=float, default=200.0, help="published rate [Hz]")
    sim.add_argument("--internal-rate", type=float, default=1000.0, help="internal step [Hz]")
    sim.add_argument("-o", "--output", required=True, help="output .mcap")
    sim.set_defaults(func=_cmd_simulate)

    ins = sub.add_parser("inspect", help="summarise an MCAP session")
    ins.add_argument("session")
    ins.set_defaults(func=_cmd_inspect)

    eff = sub.add_parser("effects", help="list the effects a model file can use")
    eff.set_defaults(func=_cmd_effects)

    srv = sub.add_parser("serve", help="run the daemon (embedded default: simulated PSM1)")
    srv.add_argument("--config", help="TOML settings (see deploy/config/); env WRENCHD_* overrides")
    srv.add_argument("--duration", type=float, default=None,
                     help="stop after this many seconds (default: until Ctrl-C)")
    srv.add_argument("--log-dir", help="MCAP log directory (default: sessions)")
    srv.add_argument("--scenario", choices=SCENARIO_CHOICES, default=None, metavar="NAME",
                     help="scenario of the simulated PSM (robot = simulated): %(choices)s")
    srv.add_argument("--seed", type=int, default=None, help="seed of the simulated PSM")
    srv.set_defaults(func=_cmd_serve)

    cfg = sub.add_parser("config", help="print the effective daemon settings as JSON")
    cfg.add_argument("--config", help="TOML settings file")
    cfg.set_defaults(func=_cmd_config)

    rob = sub.add_parser("robot", help="stream the simulated PSM over zenoh and record its truth")
    rob.add_argument("--scenario", default="trocar-contact", choices=SCENARIO_CHOICES,
                     metavar="NAME", help="one of: %(choices)s (default %(default)s)")
    rob.add_argument("--seed", type=int, default=0)
    rob.add_argument("--duration", type=float, default=None,
                     help="stop after this many seconds (default: until Ctrl-C)")
    rob.add_argument("--arm", default="PSM1")
    rob.add_argument("--prefix", default="dvrk", help="key prefix: {prefix}/{arm}/measured_js")
    rob.add_argument("--encoding", default="json", choices=["json", "cdr"])
    rob.add_argument("--rate", type=float, default=200.0, help="published rate [Hz]")
    rob.add_argument("--out-dir", default="sessions", help="where the MCAP session goes")
    rob.add_argument("--mode", default="peer", choices=["peer", "client", "router"],
                     help="zenoh mode")
    rob.add_argument("--listen", action="append", metavar="ENDPOINT",
                     help="zenoh endpoint to listen on (repeatable; default tcp/127.0.0.1:7447)")
    rob.add_argument("--connect", action="append", metavar="ENDPOINT",
                     help="zenoh endpoint to connect to (repeatable)")
    rob.add_argument("--quiet", action="store_true", help="no per-second progress lines")
    rob.add_argument("--no-announce", action="store_true",
                     help="do not announce the scenario's set-up changes on {prefix}/{arm}/setup")
    rob.set_defaults(func=_cmd_robot)

    ech = sub.add_parser("echo", help="subscribe to a daemon and print live estimates")
    ech.add_argument("--arm", default="PSM1")
    ech.add_argument("--prefix", default="dvrk")
    ech.add_argument("--encoding", default="json", choices=["json", "cdr"])
    ech.add_argument("--connect", action="append", metavar="ENDPOINT",
                     help="zenoh endpoint of the daemon (default tcp/127.0.0.1:7447)")
    ech.add_argument("--count", type=int, default=None, help="stop after N wrenches")
    ech.add_argument("--every", type=int, default=20, help="print one wrench in N")
    ech.add_argument("--events", action="store_true", help="also print events")
    ech.add_argument("--status", action="store_true", help="query the status once and exit")
    ech.add_argument("--timeout", type=float, default=None, help="give up after [s]")
    ech.set_defaults(func=_cmd_echo)

    bench = sub.add_parser("bench", help="measure speed (medians and percentiles, one run)")
    bench.add_argument("kind", choices=["inference", "arm", "service", "soak", "floor",
                                        "replay"],
                       help="inference: estimator step; arm: per-sample cost of the daemon's "
                            "work for one arm without zenoh; service: daemon end to end over loopback "
                            "zenoh; soak: the same for --duration (default 1800 s) with its "
                            "memory; floor: the service bench against the daemon's plumbing "
                            "without estimation (this machine's latency floor); replay: "
                            "replay throughput")
    bench.add_argument("--json", help="also write the result to this file")
    bench.add_argument("--duration", type=float, default=None,
                       help="inference: session length [s] (60); replay: session length "
                            "[s] (600); service: measured [s] (20)")
    bench.add_argument("--arms", type=int, default=1, help="service: arms at once (PSM1..)")
    bench.add_argument("--rate", type=float, default=1000.0, help="service: rate per arm [Hz]")
    bench.add_argument("--pin", action="store_true",
                       help="service/soak/floor: the daemon on the last CPU alone, its worker "
                            "and the bench on the others (the daemon's [cpus] settings)")
    bench.add_argument("--realtime", type=_realtime_setting, default="auto",
                       metavar="auto|off|PRIORITY",
                       help="service/soak: the daemon's [cpus] realtime_priority, which this "
                            "bench's publisher and subscriber take too (default auto: "
                            "SCHED_FIFO where permitted)")
    bench.set_defaults(func=_cmd_bench)
    for module in COMMAND_MODULES:
        importlib.import_module(module).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except WrenchdError as exc:
        print(f"wrenchd: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
