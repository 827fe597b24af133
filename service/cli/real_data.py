"""``wrenchd real-data``: step 1 on real dVRK recordings beside a least-squares physics model.

    wrenchd real-data --train ../shared/data/wpi-psm/one_no_weight.csv \\
        --test ../shared/data/wpi-psm/two.csv --out reports/real-data-step1.md

Trains the step-1 networks
(:func:`wrenchd.models.estimator.free_space_training.fit_free_space`, a shortened recipe; the last
20 % of the training file selects the best epoch) on one WPI recording,
identifies a rigid-body + friction model by least squares on the same file
(:mod:`wrenchd.models.physics.least_squares`), and reports the per-joint torque RMSE of both on the
test recording (another trajectory), with a JSON copy of the numbers beside the Markdown.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from wrenchd.models.series import JOINT_NAMES

#: Shortened step-1 recipe for a 30 s recording (the paper trains 1000 epochs on far more).
REAL_RECIPE = {"epochs": 150, "lr": 3e-3, "lr_halving_epochs": 50, "window": 50,
               "lane_windows": 4, "batch_size": 8, "patience": 60}
UNITS = ("N m", "N m", "N", "N m", "N m", "N m")


def evaluate(train_csv: str, test_csv: str, seed: int = 0, epochs: int | None = None
             ) -> dict[str, Any]:
    """Train both models on ``train_csv``; RMSEs [N m; N] per joint on both files."""
    from wrenchd.adapters.csv_psm import read_wpi_csv
    from wrenchd.models.estimator.free_space_training import fit_free_space
    from wrenchd.models.estimator.training import recipe
    from wrenchd.models.physics.least_squares import RigidBodyFrictionModel, smoothed_acceleration

    train, _ = read_wpi_csv(train_csv)
    test, _ = read_wpi_csv(test_csv)
    overrides = {**REAL_RECIPE, "seed": seed, **({"epochs": epochs} if epochs else {})}
    start = time.perf_counter()
    result = fit_free_space([train], config=recipe("free-space", **overrides),
                            data={"source": "csv", "path": str(train_csv)})
    lstm_s = time.perf_counter() - start

    def accel(js):
        return smoothed_acceleration(js.velocity, float(np.median(np.diff(js.t))))

    start = time.perf_counter()
    ls = RigidBodyFrictionModel.fit(train.position, train.velocity, accel(train), train.effort)
    ls_s = time.perf_counter() - start
    out: dict[str, Any] = {"train": str(train_csv), "test": str(test_csv), "seed": seed,
                           "recipe": overrides, "lstm_train_seconds": round(lstm_s, 1),
                           "ls_fit_seconds": round(ls_s, 2), "ls_rank": ls.rank,
                           "lstm_epochs_run": result.validation["epochs_run"]}
    for label, js in (("train_file", train), ("test_file", test)):
        x = np.concatenate([js.position, js.velocity], axis=1)
        lstm = result.model.predict_sequence(x)
        phys = ls.predict(js.position, js.velocity, accel(js))
        out[label] = {"lstm_rmse": np.sqrt(np.mean((lstm - js.effort) ** 2, 0)).tolist(),
                      "ls_rmse": np.sqrt(np.mean((phys - js.effort) ** 2, 0)).tolist(),
                      "torque_std": js.effort.std(0).tolist()}
    return out


def markdown(r: dict[str, Any], command: str) -> str:
    """The report: per-joint RMSE table on the test file, and on the training file."""
    lines = ["# Step 1 on real dVRK data: LSTM beside rigid body + friction (least squares)\n",
             f"Command: `{command}`\n",
             f"Train on `{Path(r['train']).name}` (30 s, trajectory one), test on "
             f"`{Path(r['test']).name}` (30 s, another trajectory); WPI PSM free-motion "
             "recordings at 200 Hz, jaw (joint 7) dropped. Step 1: the paper's per-group "
             f"LSTMs with a shortened recipe ({r['recipe']['epochs']} epochs max, lr "
             f"{r['recipe']['lr']:g} halved every {r['recipe']['lr_halving_epochs']}, "
             f"patience {r['recipe']['patience']}, best epoch chosen on the last 20 % of the "
             f"training file; ran {r['lstm_epochs_run']} epochs in {r['lstm_train_seconds']} s). "
             "Least squares: pinocchio regressor (60 inertial parameters) + armature + Coulomb "
             "+ viscous + offset per joint, minimum-norm solution (rank "
             f"{r['ls_rank']} of 84), acceleration by a Savitzky-Golay derivative of the "
             f"measured velocity; fitted in {r['ls_fit_seconds']} s on the whole training file.\n"]
    for label, title in (("test_file", "Test file (held out)"),
                         ("train_file", "Training file (fit)")):
        d = r[label]
        lines += [f"## {title}: torque RMSE per joint\n",
                  "| joint | unit | torque std | LSTM step 1 | rigid body + friction (LS) |",
                  "| --- | --- | --- | --- | --- |"]
        for j, name in enumerate(JOINT_NAMES):
            lines.append(f"| {j + 1} {name} | {UNITS[j]} | {d['torque_std'][j]:.4f} | "
                         f"{d['lstm_rmse'][j]:.4f} | {d['ls_rmse'][j]:.4f} |")
        lines.append("")
    return "\n".join(lines)


def _cmd(args: argparse.Namespace) -> int:
    import torch

    if args.threads:
        torch.set_num_threads(args.threads)
    r = evaluate(args.train, args.test, args.seed, args.epochs)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    command = (f"wrenchd real-data --train {args.train} --test {args.test} --out {args.out}"
               + (f" --seed {args.seed}" if args.seed else "")
               + (f" --epochs {args.epochs}" if args.epochs else ""))
    out.write_text(markdown(r, command) + (Path(args.notes).read_text() if args.notes else ""))
    out.with_suffix(".json").write_text(json.dumps(r, indent=1) + "\n")
    print(json.dumps({k: r[k] for k in ("test_file", "lstm_train_seconds")}, indent=1))
    return 0


def register(subparsers) -> None:
    """Add ``wrenchd real-data`` to the CLI."""
    p = subparsers.add_parser("real-data", help="step 1 vs least squares on WPI recordings",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--train", required=True, help="WPI CSV to train on")
    p.add_argument("--test", required=True, help="WPI CSV to test on")
    p.add_argument("--out", required=True, help="Markdown report (a .json beside it)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--epochs", type=int, default=None, help="replace the recipe's epochs")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--notes", default=None, help="Markdown appended to the report")
    p.set_defaults(func=_cmd)
