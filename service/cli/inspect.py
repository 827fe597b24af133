"""``wrenchd inspect``: summarise a session (topics, samples, truncation, set-up changes) as JSON.

SESSION takes every form replay takes (:mod:`wrenchd.service.replay.source`); an MCAP file that
wrenchd wrote is also checked for truncation and its messages counted per topic (``truncated``
and ``messages`` are null for the other forms).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def inspect_session(args: argparse.Namespace) -> int:
    from wrenchd.models.physics.effects.drift import drift_onsets
    from wrenchd.service.replay.source import load_session

    info = None
    path = Path(args.session)
    if path.suffix.lower() == ".mcap" and path.is_file():
        from wrenchd.adapters.mcap_session_reader import is_wrenchd_file, read_session_report

        if is_wrenchd_file(path):
            session, info = read_session_report(args.session)
    if info is None:
        session = load_session(args.session)
    js = session.joint_states
    injection = session.metadata.get("injection") or {}
    out = {
        "file": str(args.session),
        "samples": len(js),
        "duration_s": float(js.t[-1] - js.t[0]) if len(js) else 0.0,
        "rate_hz": js.rate_hz,
        "truncated": info.truncated if info is not None else None,
        "messages": info.messages if info is not None else None,
        "truth": session.truth is not None,
        "effects": sorted(session.truth.effects) if session.truth is not None else [],
        "scenario": (session.metadata.get("scenario") or {}).get("name"),
        "recordings": session.metadata.get("recordings"),
        "setup_changes": [{"id": name, "at_s": start, "end_s": end}
                          for name, start, end in drift_onsets(session)],
        "contact_episodes": len(injection.get("episodes", [])) if injection else None,
    }
    print(json.dumps(out, indent=2))
    return 0


def register(sub) -> None:
    p = sub.add_parser("inspect", help="summarise a session (any form replay takes)")
    p.add_argument("session", help="file.mcap, file.csv, a rosbag2 directory, "
                                   "sim:SCENARIO:DURATION[:SEED], concat:... or inject:SEED:SESSION")
    p.set_defaults(func=inspect_session)
