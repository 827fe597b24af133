"""``wrenchd echo``: subscribe to a daemon's wrenches (and events) and print them; or query status."""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"


def echo(args: argparse.Namespace) -> int:
    from wrenchd.adapters.zenoh_io import open_session

    base = f"{args.prefix}/{args.arm}"
    session = open_session(client_zenoh(args))
    try:
        if args.status:
            return _status(session, f"{base}/wrenchd/status", args.timeout or 5.0)
        return _stream(session, base, args)
    finally:
        session.close()


def client_zenoh(args: argparse.Namespace):
    """The zenoh settings of a verb that joins a daemon: the ``--zenoh-config`` file, then the
    ``--connect`` endpoints; :data:`DEFAULT_CONNECT` when neither names an endpoint.

    Raises:
        ConfigError: the file is missing or zenoh refuses it, or an endpoint is malformed.
    """
    from wrenchd.adapters.zenoh_config import has_endpoints, zenoh_config

    zenoh = zenoh_config(config_file=args.zenoh_config, connect=args.connect or [])
    if not has_endpoints(zenoh, "connect"):
        zenoh = zenoh_config(config_file=args.zenoh_config, connect=[DEFAULT_CONNECT])
    return zenoh


def add_zenoh_options(p: argparse.ArgumentParser) -> None:
    """``--connect`` and ``--zenoh-config`` of a verb that joins a daemon."""
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"zenoh endpoint of the daemon (repeatable; default: the "
                        f"--zenoh-config file's, else {DEFAULT_CONNECT})")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="zenoh configuration file (.json5, as zenoh's own tools take it: TLS, "
                        "access, endpoints...); --connect applies over it")


def query_status(session, key: str, timeout: float) -> dict | None:
    """The first status a daemon answers on ``key`` within ``timeout`` [s], or None."""
    for reply in session.get(key, timeout=timeout):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return None


def _status(session, key: str, timeout: float) -> int:
    status = query_status(session, key, timeout)
    if status is None:
        print(f"wrenchd echo: no answer from '{key}' within {timeout:g} s")
        return 1
    print(json.dumps(status, indent=2))
    return 0


def _stream(session, base: str, args: argparse.Namespace) -> int:
    import numpy as np

    from wrenchd.service.runtime.stopping import StopSignals

    from wrenchd.adapters.messages import decode_wrench
    from wrenchd.models.errors import DataError

    done = threading.Event()
    seen = {"n": 0}
    lock = threading.RLock()       # counting and printing: one callback at a time

    def say(line: str) -> None:
        """One whole line at a time: zenoh calls the two subscribers on its own threads, and
        print() writes a line and its end separately (two callbacks' lines would mix)."""
        with lock:
            sys.stdout.write(line + "\n")
            sys.stdout.flush()

    def on_wrench(sample) -> None:
        with lock:       # a wrench is printed before the next is counted: --count N prints N
            _wrench(sample)

    def _wrench(sample) -> None:
        seen["n"] += 1
        n = seen["n"]
        if args.count is not None and n > args.count:
            done.set()
            return
        if n % max(args.every, 1) == 1 or args.every <= 1:
            try:
                stamp_ns, _frame, w, extra = decode_wrench(args.encoding,
                                                           sample.payload.to_bytes())
            except DataError as exc:
                say(f"undecodable wrench: {exc}")
                return
            flag = ("free" if extra.get("free") else "contact") if "free" in extra else ""
            say(f"t={stamp_ns / 1e9:9.3f} s  F=[{w[0]:6.2f} {w[1]:6.2f} {w[2]:6.2f}] N  "
                f"|F|={np.linalg.norm(w[:3]):5.2f} N  T=[{w[3]:6.3f} {w[4]:6.3f} {w[5]:6.3f}] N m"
                f"  {flag} {('v' + str(extra['model_version'])) if 'model_version' in extra else ''}")
        if args.count is not None and n >= args.count:
            done.set()

    def on_event(sample) -> None:
        say(f"event: {sample.payload.to_bytes().decode(errors='replace')}")

    subs = [session.declare_subscriber(f"{base}/wrenchd/measured_cf", on_wrench)]
    if args.events:
        subs.append(session.declare_subscriber(f"{base}/wrenchd/events", on_event))
    say(f"wrenchd echo: listening on '{base}/wrenchd/measured_cf' ({args.encoding})")
    deadline = None if args.timeout is None else time.monotonic() + args.timeout
    try:
        with StopSignals() as stop:       # SIGINT/SIGTERM end the wait; the count is printed
            while not done.is_set() and not stop.wait(0.1):
                if deadline is not None and time.monotonic() > deadline:
                    break
    finally:
        for sub in subs:
            sub.undeclare()
    print(f"wrenchd echo: {min(seen['n'], args.count or seen['n'])} wrenches", flush=True)
    return 0 if seen["n"] else 1


def register(sub) -> None:
    p = sub.add_parser("echo", help="subscribe to a daemon and print live estimates")
    p.add_argument("--arm", default="PSM1")
    p.add_argument("--prefix", default="dvrk")
    p.add_argument("--encoding", default="json", choices=["json", "cdr"])
    add_zenoh_options(p)
    p.add_argument("--count", type=int, default=None, help="stop after N wrenches")
    p.add_argument("--every", type=int, default=20, help="print one wrench in N")
    p.add_argument("--events", action="store_true", help="also print events")
    p.add_argument("--status", action="store_true", help="query the status once and exit")
    p.add_argument("--timeout", type=float, default=None, help="give up after [s]")
    p.set_defaults(func=echo)
