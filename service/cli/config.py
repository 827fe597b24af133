"""``wrenchd config``: print the daemon's effective settings as JSON."""

from __future__ import annotations

import argparse
import json


def print_config(args: argparse.Namespace) -> int:
    from wrenchd.service.runtime.settings import load_settings

    print(json.dumps(load_settings(args.config).model_dump(mode="json"), indent=2))
    return 0


def register(sub) -> None:
    p = sub.add_parser("config", help="print the effective daemon settings as JSON")
    p.add_argument("--config", help="TOML settings file")
    p.set_defaults(func=print_config)
