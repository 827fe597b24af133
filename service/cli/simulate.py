"""``wrenchd simulate``: run a simulator scenario and write the session to MCAP."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from wrenchd.service.cli.choices import SCENARIO_CHOICES


def simulate(args: argparse.Namespace) -> int:
    from wrenchd.adapters.mcap_session_writer import write_session
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


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate a scenario into an MCAP session")
    p.add_argument("--scenario", required=True, choices=SCENARIO_CHOICES, metavar="NAME",
                   help="one of: %(choices)s")
    p.add_argument("--duration", type=float, default=60.0, help="session length [s]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--model", help="physics model JSON replacing the scenario's physics")
    p.add_argument("--rate", type=float, default=200.0, help="published rate [Hz]")
    p.add_argument("--internal-rate", type=float, default=1000.0, help="internal step [Hz]")
    p.add_argument("-o", "--output", required=True, help="output .mcap")
    p.set_defaults(func=simulate)
