"""``wrenchd excite``: an optimised excitation trajectory for identifying a real PSM.

Optimises a periodic Fourier trajectory of the chosen joints (default 1-3, the arm without
the instrument's wrist) within the arm's position, velocity and acceleration limits for a
small condition number of the identification regressor
(:mod:`wrenchd.models.identification.excitation`), and writes it in ``--out``:

* ``excitation.csv``: joint set-points at ``--rate`` Hz, columns ``t, q1..q6, dq1..dq6``
  [s, rad, m, rad/s, m/s], ``--periods`` periods, at rest at both ends;
* ``setpoints/``: the same set-points as a ROS 2 bag (rosbag2 directory, MCAP) of
  ``sensor_msgs/msg/JointState`` on ``--topic`` (default ``/PSM1/servo_jp``, the CRTK
  position command), for ``ros2 bag play`` once the arm stands at the first set-point;
* ``excitation.json``: the Fourier coefficients, the configuration and the condition numbers.

Example::

    wrenchd excite --out runs/excite --periods 3
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from wrenchd.models.errors import ConfigError

QUICK = {"iterations": 10, "samples": 50}


def _joints(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(j) for j in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected joint numbers like 1,2,3, got {text!r}")


def excite(args: argparse.Namespace) -> int:
    import numpy as np

    from wrenchd.adapters.rosbag import write_joint_states_bag
    from wrenchd.models.identification.excitation import excitation_config, optimise_excitation
    from wrenchd.models.series import JointStates

    out = Path(args.out)
    csv_path, bag_path, json_path = (out / "excitation.csv", out / "setpoints",
                                     out / "excitation.json")
    taken = [str(p) for p in (csv_path, bag_path, json_path) if p.exists()]
    if taken:
        raise ConfigError(f"--out {out} already holds {', '.join(taken)}; choose a new folder")
    if args.periods < 1:
        raise ConfigError(f"--periods must be >= 1, got {args.periods}")
    values = {"joints": (1, 2, 3, 4, 5, 6) if args.all_joints else args.joints,
              "base_frequency_hz": args.base_frequency, "harmonics": args.harmonics,
              "rate_hz": args.rate, "seed": args.seed, "iterations": args.iterations}
    if args.quick:
        values.update(QUICK)
    config = excitation_config(**values)
    start = time.perf_counter()
    result = optimise_excitation(config)
    seconds = time.perf_counter() - start
    t, q, dq, ddq = result.set_points(args.periods)

    out.mkdir(parents=True, exist_ok=True)
    header = ",".join(["t"] + [f"q{j}" for j in range(1, 7)] + [f"dq{j}" for j in range(1, 7)])
    np.savetxt(csv_path, np.column_stack([t, q, dq]), fmt="%.17g", delimiter=",",
               header=header, comments="")
    setpoints = JointStates(t, q, dq, np.zeros_like(q))
    write_joint_states_bag(bag_path, setpoints, topic=args.topic, with_effort=False)
    traj = result.trajectory
    json_path.write_text(json.dumps({
        "format": "wrenchd.excitation/1",
        "model": "q_j(t) = q0_j + sum_k a_jk/(w k) sin(w k t) - b_jk/(w k) cos(w k t), "
                 "w = 2 pi base_frequency_hz",
        "config": config.model_dump(mode="json"),
        "base_frequency_hz": traj.base_frequency_hz, "a": traj.a.tolist(),
        "b": traj.b.tolist(), "q0": traj.q0.tolist(),
        "condition_number": {"initial": result.cond_initial, "optimised": result.cond_final},
        "regressor_parameters": result.parameters, "optimiser": result.info,
        "periods": args.periods, "samples": int(t.size), "topic": args.topic,
    }, indent=2) + "\n")

    moving = config.index
    print(f"wrenchd excite: joints {','.join(str(j + 1) for j in moving)}, "
          f"{config.base_frequency_hz:g} Hz base, {config.harmonics} harmonics, "
          f"{args.periods} x {config.period_s:g} s at {config.rate_hz:g} Hz "
          f"({t.size} set-points)")
    print(f"regressor condition number: {result.cond_initial:.1f} initial (seed {config.seed}) "
          f"-> {result.cond_final:.1f} optimised ({result.parameters} parameters, "
          f"{result.info['iterations']} iterations, {result.info['evaluations']} evaluations, "
          f"{seconds:.1f} s)")
    for j in moving:
        unit = "m" if j == 2 else "rad"
        print(f"  joint {j + 1}: q {q[:, j].min():+.3f}..{q[:, j].max():+.3f} {unit} "
              f"(box {config.lower[j]:+.3f}..{config.upper[j]:+.3f}), "
              f"|dq| <= {np.abs(dq[:, j]).max():.3f} of {config.max_velocity[j]:g} {unit}/s, "
              f"|ddq| <= {np.abs(ddq[:, j]).max():.3f} of {config.max_acceleration[j]:g} "
              f"{unit}/s^2")
    print(f"start (move the arm here first, at rest): q = "
          f"[{', '.join(f'{v:.4f}' for v in q[0])}]")
    print(f"wrote {csv_path}, {bag_path}/ ({args.topic}), {json_path}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("excite", help="an optimised excitation trajectory for identifying "
                                      "a real PSM (CSV and ROS 2 bag of set-points)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for excitation.csv, setpoints/ and excitation.json")
    p.add_argument("--joints", type=_joints, default=(1, 2, 3), metavar="J,J,...",
                   help="joints to excite, 1-based (default 1,2,3; the others hold still)")
    p.add_argument("--all-joints", action="store_true", help="excite all six joints")
    p.add_argument("--base-frequency", type=float, default=0.1, metavar="HZ",
                   help="base frequency = 1 / period [Hz] (default 0.1)")
    p.add_argument("--harmonics", type=int, default=5, help="harmonics per joint (default 5)")
    p.add_argument("--periods", type=int, default=3,
                   help="periods written (default 3, 30 s at 0.1 Hz)")
    p.add_argument("--rate", type=float, default=200.0, metavar="HZ",
                   help="set-point rate [Hz] (default 200)")
    p.add_argument("--iterations", type=int, default=100,
                   help="optimiser iterations (default 100; 0 keeps the seeded start)")
    p.add_argument("--seed", type=int, default=0, help="seed of the starting coefficients")
    p.add_argument("--quick", action="store_true",
                   help=f"a short optimisation ({QUICK['iterations']} iterations, "
                        f"{QUICK['samples']} regressor samples per period)")
    p.add_argument("--topic", default="/PSM1/servo_jp",
                   help="topic of the set-point bag (default /PSM1/servo_jp)")
    p.set_defaults(func=excite)
