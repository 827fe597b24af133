"""``wrenchd identify``: fit base inertial parameters, Coulomb/viscous friction and offsets to
free motion; write a model file."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from wrenchd.service.cli.measured import add_measured_options, read_measured


def identify(args: argparse.Namespace) -> int:
    from wrenchd.models.identification.free_motion import identify_free_motion
    from wrenchd.models.physics.model import PhysicsModel

    js = read_measured(args.measured, args.format, args.rate, args.topic)
    nominal = PhysicsModel.load(args.nominal) if args.nominal else None
    start = time.perf_counter()
    ident = identify_free_motion(js.t, js.position, js.velocity, js.effort, nominal,
                                 with_offset=not args.no_offset,
                                 description=f"identified by wrenchd identify from "
                                             f"{Path(args.measured).name}")
    Path(args.output).parent.mkdir(parents=True, exist_ok=True)
    ident.model.save(args.output)
    print(f"identified {len(ident.columns)} base inertial parameters + friction"
          f"{' + offsets' if not args.no_offset else ''} from {len(js)} samples in "
          f"{time.perf_counter() - start:.1f} s -> {args.output}")
    print("held-out RMS per joint: " + ", ".join(f"{v:.4g}" for v in ident.heldout_rms))
    if ident.unexcited:
        print(f"not excited by this recording (kept nominal): {ident.unexcited}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("identify", help="fit a physics model to free-motion data")
    add_measured_options(p)
    p.add_argument("--nominal", help="model file whose rigid body is the starting point")
    p.add_argument("--no-offset", action="store_true", help="do not fit joint offsets")
    p.add_argument("-o", "--output", required=True, help="model file to write (JSON)")
    p.set_defaults(func=identify)
