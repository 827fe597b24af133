"""``wrenchd bench``: speed measured, not asserted (the benches are :mod:`wrenchd.service.bench`)."""

from __future__ import annotations

import argparse

#: Default ``--duration`` of each bench [s] (inference and arm when not named: 60).
#: replay: a 10 min session; a shorter one is mostly the calibration minute, whose eager
#: rounds the worker cannot keep up with, so its speed says little about the rest.
DEFAULT_DURATION_S = {"service": 20.0, "floor": 20.0, "arm": 20.0, "replay": 600.0,
                      "soak": 1800.0, "fit": 30.0, "ratio": 90.0}


def realtime_setting(text: str) -> int | str:
    """``--realtime``: ``auto``, ``off`` or a SCHED_FIFO priority."""
    if text in ("auto", "off"):
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not auto, off or a priority") from None


def bench(args: argparse.Namespace) -> int:
    from wrenchd.service.bench.run import run
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()           # the bench process; the daemon and worker do it themselves

    if args.duration is None:
        args.duration = DEFAULT_DURATION_S.get(args.kind, 60.0)
    return run(args.kind, args.json, args.duration, args.arms, args.rate, args.pin,
               args.realtime, args.recording, args.intake, args.pairs, args.stages,
               args.model, args.encoding)


def register(sub) -> None:
    p = sub.add_parser("bench", help="measure speed (medians and percentiles, one run)")
    p.add_argument("kind", choices=["inference", "arm", "service", "soak", "floor", "ratio",
                                    "replay", "fit"],
                   help="inference: estimator step; arm: per-sample cost of the daemon's "
                        "work for one arm without zenoh; service: daemon end to end over loopback "
                        "zenoh; soak: the same for --duration (default 1800 s) with its "
                        "memory; floor: the service bench against the daemon's plumbing "
                        "without estimation (this machine's latency floor); ratio: the "
                        "floor and the daemon alternately, --pairs times, their p99 and CPU "
                        "ratios (the calibration minute and after it apart); replay: "
                        "replay throughput; fit: wrenchd fit from reading to a bundle")
    p.add_argument("--json", help="also write the result to this file")
    p.add_argument("--recording", help="fit: the recording to fit (default: --duration s of "
                                       "the simulator's free-space scenario); arm, service, "
                                       "soak, floor, ratio: the joint states to run, played "
                                       "again from its start (default: the simulator's "
                                       "trocar scenario; give --rate its own rate)")
    p.add_argument("--model", default="seal",
                   help="arm, service, soak, ratio: every arm's step 1, a shipped name or a "
                        "bundle directory (default seal)")
    p.add_argument("--duration", type=float, default=None,
                   help="inference: session length [s] (60); replay: session length "
                        "[s] (600); service: measured [s] (20); ratio: each run [s] (90: "
                        "the calibration minute and 30 s after it); fit: simulated "
                        "recording [s] (30)")
    p.add_argument("--arms", type=int, default=1, help="service: arms at once (PSM1..)")
    p.add_argument("--pairs", type=int, default=2, help="ratio: floor and daemon pairs (2)")
    p.add_argument("--rate", type=float, default=1000.0, help="service: rate per arm [Hz]")
    p.add_argument("--pin", action="store_true",
                   help="service/soak/floor: the daemon on the last CPU alone, its worker "
                        "and the bench on the others (the daemon's [cpus] settings)")
    p.add_argument("--realtime", type=realtime_setting, default="auto",
                   metavar="auto|off|PRIORITY",
                   help="service/soak/floor/ratio: the daemon's [cpus] realtime_priority, "
                        "which the floor and this bench's publisher and subscriber take too "
                        "(default auto: SCHED_FIFO where permitted)")
    p.add_argument("--intake", choices=["channel", "callback"], default="channel",
                   help="service/soak/floor: how the daemon takes its joint states ([ring] "
                        "intake; default channel, the daemon's default)")
    p.add_argument("--encoding", choices=["json", "cdr"], default="json",
                   help="arm, service, soak, floor, ratio: the arms' wire encoding (default "
                        "json; cdr is what a ROS 2 robot publishes)")
    p.add_argument("--stages", action="store_true",
                   help="service/soak: also the daemon estimation thread's CPU time per stage "
                        "(decode, estimate, gate, publish...; a timer on every call makes the "
                        "daemon a little slower)")
    p.set_defaults(func=bench)
