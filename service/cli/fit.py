"""``wrenchd fit``: from a lab's own free-motion recordings to a model bundle it can serve.

    wrenchd fit rosbag2_2026_11_24/ -o models/psm1-bundle
    wrenchd serve --config psm1.toml          # with model = "models/psm1-bundle"
"""

from __future__ import annotations

import argparse
import json


def fit(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from wrenchd.adapters.recordings import read_recording
    from wrenchd.models.estimator.hybrid import HybridConfig, ResidualNetConfig
    from wrenchd.service.runtime.scheduling import one_compute_thread
    from wrenchd.service.studies.fit import FitConfig, fit_recordings

    one_compute_thread()
    recordings = [read_recording(path, topic=args.topic, csv_format=args.csv_format,
                                 rate_hz=args.rate)
                  for path in tqdm(args.recordings, desc="reading", unit="recording",
                                   disable=args.quiet)]
    residual = ResidualNetConfig(epochs=args.epochs, seed=args.seed)
    config = FitConfig(holdout_fraction=args.holdout, hybrid=HybridConfig(residual=residual))
    bar = tqdm(total=args.epochs, desc="training the residual", unit="epoch",
               disable=args.quiet)
    try:
        report = fit_recordings(recordings, args.output, arm=args.arm, origin=args.origin,
                                config=config, progress=bar.write,
                                on_epoch=lambda _epoch, loss: (bar.update(),
                                                               bar.set_postfix(loss=f"{loss:.3g}")))
    finally:
        bar.close()
    s = report["held_out"]
    print(f"wrote {args.output} (digest {report['bundle_digest'][:12]}); fit in "
          f"{report['fit_seconds']:.1f} s on {report['train_samples']} samples")
    print("held-out torque RMSE per joint, least squares -> hybrid: " + ", ".join(
        f"{a:.4g} -> {b:.4g}" for a, b in zip(s["ls_rmse"], s["hybrid_rmse"])))
    print(f"held-out samples inside the training coverage: {s['inside_coverage']:.0%}")
    for warning in report["warnings"]:
        print(f"warning: {warning}")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(report, f, indent=1)
    return 0


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a step-1 model to a robot's own free-motion recordings",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recordings", nargs="+", metavar="RECORDING",
                   help="rosbag2 directory, .mcap (ROS 2 bag or wrenchd session/log), .db3 or "
                        "CSV (WPI or paper layout) of free motion")
    p.add_argument("-o", "--output", required=True, metavar="BUNDLE",
                   help="bundle directory to write (must not exist)")
    p.add_argument("--topic", default="/PSM1/measured_js",
                   help="joint-state topic of a ROS 2 bag (default %(default)s)")
    p.add_argument("--arm", default="PSM1", help="arm the recordings are of")
    p.add_argument("--origin", default="robot", choices=["robot", "simulator"],
                   help="what recorded them (default %(default)s)")
    p.add_argument("--holdout", type=float, default=0.2,
                   help="last share of each recording held out for the report")
    p.add_argument("--epochs", type=int, default=200, help="residual network epochs")
    p.add_argument("--seed", type=int, default=0, help="residual network seed")
    p.add_argument("--csv-format", default="auto", choices=["auto", "wpi", "paper"])
    p.add_argument("--rate", type=float, default=None,
                   help="sample rate of a WPI CSV [Hz] (default: inferred from its velocities)")
    p.add_argument("--json", help="also write the report as JSON here")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=fit)
