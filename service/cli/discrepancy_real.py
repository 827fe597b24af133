"""``wrenchd discrepancy-real``: identify on the WPI no-load recording, discrepancy on the
loaded ones, :func:`wrenchd.service.studies.discrepancy.real_data_study`."""

from __future__ import annotations

import argparse
from pathlib import Path


def discrepancy_real(args: argparse.Namespace) -> int:
    from wrenchd.service.studies.discrepancy import real_data_study

    return real_data_study(Path(args.data), Path(args.out))


def register(sub) -> None:
    p = sub.add_parser("discrepancy-real",
                       help="identify on WPI one_no_weight, discrepancy on the loaded runs")
    p.add_argument("--data", default="../shared/data/wpi-psm", help="WPI recordings folder")
    p.add_argument("--out", default="reports/discrepancy/real-data")
    p.set_defaults(func=discrepancy_real)
