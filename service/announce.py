"""``wrenchd announce``: tell a running daemon that an arm's set-up changed.

Publishes one set-up change notice on ``{prefix}/{arm}/setup`` (JSON, see
:func:`adapters.messages.encode_setup_change`) once zenoh reports a subscriber there (the
daemon), so the notice is not published into the void. Without ``--at`` the change is "now":
the daemon places it at the arm's latest sample. An insufflator bridge or the OR console
would publish the same message itself.

Example::

    wrenchd announce --arm PSM1 --pressure 20 --note "insufflation raised"
"""

from __future__ import annotations

import argparse
import math
import time

from models.errors import ConfigError
from service.echo import DEFAULT_CONNECT


def announce(args: argparse.Namespace) -> int:
    from adapters.messages import encode_setup_change, stamp_ns_of
    from adapters.zenoh_io import ZenohConfig, open_session, wait_for_subscriber

    if args.pressure is not None and not 0.0 <= args.pressure <= 100.0:
        raise ConfigError(f"--pressure must be in [0, 100] mmHg, got {args.pressure:g}")
    if args.at is not None and not (math.isfinite(args.at) and args.at >= 0):
        raise ConfigError(f"--at must be a sample time >= 0 [s], got {args.at:g}")
    payload = encode_setup_change(None if args.at is None else stamp_ns_of(args.at),
                                  args.pressure, args.note)
    key = f"{args.prefix}/{args.arm}/setup"
    session = open_session(ZenohConfig(connect=args.connect or [DEFAULT_CONNECT]))
    try:
        publisher = session.declare_publisher(key)
        if not wait_for_subscriber(publisher, args.timeout):
            publisher.undeclare()
            print(f"wrenchd announce: no daemon subscribed to '{key}' within "
                  f"{args.timeout:g} s; nothing sent")
            return 1
        publisher.put(payload)
        time.sleep(0.2)                 # let the put leave before the session closes
        publisher.undeclare()
    finally:
        session.close()
    print(f"wrenchd announce: sent {payload.decode()} on '{key}'")
    return 0


def register(sub) -> None:
    p = sub.add_parser("announce", help="tell a running daemon that an arm's set-up changed")
    p.add_argument("--arm", default="PSM1")
    p.add_argument("--prefix", default="dvrk")
    p.add_argument("--pressure", type=float, default=None,
                   help="insufflation pressure now [mmHg] (logged with the notice)")
    p.add_argument("--note", default=None, help="free text logged with the notice")
    p.add_argument("--at", type=float, default=None, metavar="SECONDS",
                   help="sample time of the change [s] (default: now, the arm's latest sample)")
    p.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"zenoh endpoint of the daemon (default {DEFAULT_CONNECT})")
    p.add_argument("--timeout", type=float, default=5.0,
                   help="how long to wait for the daemon's subscriber [s]")
    p.set_defaults(func=announce)
