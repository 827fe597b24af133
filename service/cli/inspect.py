"""``wrenchd inspect``: summarise an MCAP session (topics, samples, truncation) as JSON."""

from __future__ import annotations

import argparse
import json


def inspect_session(args: argparse.Namespace) -> int:
    from wrenchd.adapters.mcap_session_reader import read_session_report

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


def register(sub) -> None:
    p = sub.add_parser("inspect", help="summarise an MCAP session")
    p.add_argument("session")
    p.set_defaults(func=inspect_session)
