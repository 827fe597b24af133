"""``wrenchd real-robot``: the whole pipeline on the WPI dVRK recordings, one report.

    wrenchd real-robot --data ../shared/data/wpi-psm --out reports/real-robot

Newtons at the tip on free motion, the known parallelogram loads, a real set-up change
(unloaded then loaded recordings) under each adaptation policy, and real motion with a
simulated trocar and contacts: :mod:`wrenchd.service.studies.real_robot`. ``--quick`` runs
every part at a size the test suite can afford (its figures are not the report's).
"""

from __future__ import annotations

import argparse
import shlex


def real_robot(args: argparse.Namespace) -> int:
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()
    from wrenchd.service.studies.real_robot import RealRobotConfig, run

    config = RealRobotConfig.quick() if args.quick else RealRobotConfig()
    if args.skip_lstm:
        config = RealRobotConfig(**{**config.__dict__, "models": tuple(
            m for m in config.models if m != "lstm")})
    command = " ".join(shlex.quote(a) for a in ["wrenchd", "real-robot", "--data", args.data,
                                                 "--out", args.out]
                       + (["--quick"] if args.quick else [])
                       + (["--skip-lstm"] if args.skip_lstm else []))
    r = run(args.data, args.out, config, command=command)
    tip = r["step1"]["test_file"]["tip_force_N"]
    print(f"two.csv free-motion tip force RMS: " + ", ".join(
        f"{k} {v['rms']:.2f} N" for k, v in tip.items()))
    for load in r["step1"]["known_loads"]:
        print(f"{load['file'].rsplit('/', 1)[-1]}: fitted {1000 * load['fitted_mass_kg']:.1f} g "
              f"of {1000 * load['mass_kg']:.0f} g")
    for pair in r["step1"].get("known_load_pairs", []):
        heavy, light = (f.rsplit("/", 1)[-1] for f in reversed(pair["files"]))
        print(f"{heavy} - {light}: the efforts alone fit "
              f"{1000 * pair['fitted_difference_kg']['effort']:.1f} g of "
              f"{1000 * pair['expected_difference_kg']:.0f} g; one run's share "
              f"{1000 * pair['per_run_kg']:.1f} g")
    print(f"wrote {args.out}/report.md and report.json in {r['wall_s']:.0f} s")
    return 0


def register(sub) -> None:
    p = sub.add_parser("real-robot", help="the whole pipeline on the WPI recordings: newtons, "
                       "known loads, a set-up change, injected contacts",
                       description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", default="../shared/data/wpi-psm", help="WPI recordings folder")
    p.add_argument("--out", default="reports/real-robot")
    p.add_argument("--quick", action="store_true", help="small sizes (tests)")
    p.add_argument("--skip-lstm", action="store_true", help="leave out the paper's LSTM")
    p.set_defaults(func=real_robot)
