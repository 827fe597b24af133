"""``wrenchd announce``: tell a running daemon that an arm's set-up changed.

Publishes one set-up change notice on ``{prefix}/{arm}/setup`` (JSON, see
:func:`wrenchd.adapters.messages.encode_setup_change`) once zenoh reports a subscriber there (the
daemon), so the notice is not published into the void. Without ``--at`` the change is "now":
the daemon places it at the arm's latest sample. An insufflator bridge or the OR console
would publish the same message itself.

Then it waits for the daemon's answer on ``{prefix}/{arm}/wrenchd/events``: a
``setup_change`` event (accepted; exit 0) or an ``error`` event of kind ``setup`` (refused, with
the daemon's reason; exit 1). Its subscriber is declared before the notice is put, on the same
zenoh link, so the daemon knows it before it answers. Should no event come (an older daemon,
a lost event), the daemon's status counters say whether the notice was taken.

Example::

    wrenchd announce --arm PSM1 --pressure 20 --note "insufflation raised"
    wrenchd announce --arm PSM1 --instrument "large needle driver"

A ``pressure`` change (the default kind) carries the adapter's buffer over to the new set-up;
an ``instrument`` change (``--instrument NAME`` or ``--kind instrument``) restarts its training
data and the calibration on the new instrument.
"""

from __future__ import annotations

import argparse
import json
import math
import threading

from wrenchd.models.errors import ConfigError
from wrenchd.service.cli.echo import add_zenoh_options, client_zenoh, query_status


def announce(args: argparse.Namespace) -> int:
    from wrenchd.adapters.messages import encode_setup_change, stamp_ns_of
    from wrenchd.adapters.zenoh_io import open_session, wait_for_subscriber

    if args.pressure is not None and not 0.0 <= args.pressure <= 100.0:
        raise ConfigError(f"--pressure must be in [0, 100] mmHg, got {args.pressure:g}")
    if args.at is not None and not (math.isfinite(args.at) and args.at >= 0):
        raise ConfigError(f"--at must be a sample time >= 0 [s], got {args.at:g}")
    kind = args.kind or ("instrument" if args.instrument is not None else None)
    if args.instrument is not None and kind != "instrument":
        raise ConfigError(f"--instrument names a new instrument: it needs --kind instrument, "
                          f"got --kind {kind}")
    if args.instrument is not None and not 0 < len(args.instrument) <= 100:
        raise ConfigError("--instrument must be a name of 1 to 100 characters")
    payload = encode_setup_change(None if args.at is None else stamp_ns_of(args.at),
                                  args.pressure, args.note, kind, args.instrument)
    base = f"{args.prefix}/{args.arm}"
    key = f"{base}/setup"
    answers: list[dict] = []
    answered = threading.Event()

    def on_event(sample) -> None:
        try:
            event = json.loads(sample.payload.to_bytes())
        except ValueError:
            return
        if event.get("kind") == "setup_change" or (event.get("kind") == "error"
                                                   and event.get("error") == "setup"):
            answers.append(event)
            answered.set()

    session = open_session(client_zenoh(args))
    try:
        events = session.declare_subscriber(f"{base}/wrenchd/events", on_event)
        try:
            publisher = session.declare_publisher(key)
            if not wait_for_subscriber(publisher, args.timeout):
                publisher.undeclare()
                print(f"wrenchd announce: no daemon subscribed to '{key}' within "
                      f"{args.timeout:g} s; nothing sent")
                return 1
            before = _counts(session, base)
            publisher.put(payload)
            print(f"wrenchd announce: sent {payload.decode()} on '{key}'", flush=True)
            answered.wait(args.timeout)
            publisher.undeclare()
        finally:
            events.undeclare()
        if answers:
            return _report(answers[0])
        after = _counts(session, base)
    finally:
        session.close()
    if before is not None and after is not None:
        if after[0] > before[0]:
            print("wrenchd announce: accepted (the daemon's status counts it; its event did "
                  "not reach this command)")
            return 0
        if after[1] > before[1]:
            print("wrenchd announce: refused (the daemon's status counts a set-up error; its "
                  "event, with the reason, did not reach this command)")
            return 1
    print(f"wrenchd announce: no answer from the daemon within {args.timeout:g} s")
    return 1


def _counts(session, base: str) -> tuple[int, int] | None:
    """The daemon's (set-up changes taken, set-up notices refused), or None without an
    answer."""
    status = query_status(session, f"{base}/wrenchd/status", 2.0)
    if status is None:
        return None
    c = status["counters"]
    return c.get("setup_changes", 0), c.get("error_kinds", {}).get("setup", 0)


def _report(event: dict) -> int:
    if event["kind"] == "setup_change":
        print(f"wrenchd announce: accepted: the change is at t = {event['t']:.3f} s of the "
              f"arm's clock (carry-over {'on' if event.get('carry_over') else 'off'})")
        return 0
    print(f"wrenchd announce: refused: {event.get('reason', '(no reason given)')}")
    return 1


def register(sub) -> None:
    p = sub.add_parser("announce", help="tell a running daemon that an arm's set-up changed")
    p.add_argument("--arm", default="PSM1")
    p.add_argument("--prefix", default="dvrk")
    p.add_argument("--pressure", type=float, default=None,
                   help="insufflation pressure now [mmHg] (logged with the notice)")
    p.add_argument("--kind", choices=("pressure", "instrument"), default=None,
                   help="what changed (default: instrument with --instrument, else pressure)")
    p.add_argument("--instrument", default=None, metavar="NAME",
                   help="an instrument was swapped: the new one's name (kind instrument)")
    p.add_argument("--note", default=None, help="free text logged with the notice")
    p.add_argument("--at", type=float, default=None, metavar="SECONDS",
                   help="sample time of the change [s] (default: now, the arm's latest sample)")
    add_zenoh_options(p)
    p.add_argument("--timeout", type=float, default=5.0,
                   help="how long to wait for the daemon's subscriber, and then for its "
                        "answer [s]")
    p.set_defaults(func=announce)
