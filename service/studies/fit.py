"""From a lab's own free-motion recordings to a served model: the ``wrenchd fit`` workflow.

1. Read every recording (:func:`~wrenchd.adapters.recordings.read_recording`: ROS 2 bags,
   wrenchd's MCAP sessions and logs, CSV) and refuse one too still to identify the arm from
   (:func:`~wrenchd.models.identification.motion.check_motion`).
2. Hold out the last ``holdout_fraction`` of each recording; fit the hybrid step 1 (least
   squares rigid body + friction, a residual network trusted only where the data went:
   :mod:`wrenchd.models.estimator.hybrid`) on the rest.
3. Score it on the held-out part, per joint, beside least squares alone, and write a bundle
   (:mod:`wrenchd.adapters.bundle`): the model, the digests of the recordings, a report of
   the scores and of how much of each joint's range and speed the recordings covered.

The bundle serves the model fitted on the training part, the one the report scores.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.adapters.recordings import Recording
from wrenchd.models.errors import DataError
from wrenchd.models.estimator.features import segments
from wrenchd.models.estimator.hybrid import HybridConfig, HybridStep1, fit_hybrid
from wrenchd.models.identification.motion import JointCoverage, check_motion
from wrenchd.models.series import JOINT_NAMES, N_JOINTS, JointStates
from wrenchd.service.pipeline.step1 import HYBRID_KIND

class FitConfig(BaseModel):
    """What ``wrenchd fit`` holds out and fits."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    holdout_fraction: float = Field(default=0.2, gt=0.0, lt=0.9,
                                    description="last share of each recording held out")
    hybrid: HybridConfig = Field(default_factory=HybridConfig)


def split_holdout(js: JointStates, fraction: float) -> tuple[JointStates, JointStates]:
    """The first ``1 - fraction`` of a recording's samples and the rest."""
    cut = int(round(len(js) * (1.0 - fraction)))
    if cut < 2 or len(js) - cut < 2:
        raise DataError(f"{len(js)} samples cannot be split {1 - fraction:.0%} / {fraction:.0%}")
    return js.slice(0, cut), js.slice(cut, len(js))


def held_out_parts(step1: HybridStep1, js: JointStates) -> tuple[np.ndarray, ...]:
    """(N, 6) torques of the hybrid and of its physics part alone [N m; N], and the (N,)
    residual trust, in one pass over the gap-free segments."""
    hybrid, physics, trust = np.zeros((len(js), N_JOINTS)), np.zeros((len(js), N_JOINTS)), \
        np.zeros(len(js))
    x = np.concatenate([js.position, js.velocity], axis=1)
    for seg in segments(js.t, step1.config.max_gap_s):
        parts = step1.parts(x[seg])
        hybrid[seg], physics[seg], trust[seg] = parts.torque, parts.physics, parts.weight
    return hybrid, physics, trust


def rmse(pred: np.ndarray, target: np.ndarray) -> list[float]:
    return np.sqrt(np.mean((pred - target) ** 2, axis=0)).tolist()


def score(step1: HybridStep1, held_out: Sequence[JointStates]) -> dict:
    """Per joint, over the held-out parts: RMSE [N m; N] of least squares and of the hybrid,
    the torque's own spread, and the share of samples inside the training coverage."""
    measured = np.concatenate([js.effort for js in held_out])
    hybrid, ls, trust = (np.concatenate(a) for a in zip(*(held_out_parts(step1, js)
                                                           for js in held_out)))
    return {"ls_rmse": rmse(ls, measured), "hybrid_rmse": rmse(hybrid, measured),
            "torque_std": measured.std(axis=0).tolist(),
            "inside_coverage": float(np.mean(trust > 0.5)),
            "samples": int(len(measured))}


def report_markdown(report: dict) -> str:
    """The fit report a person reads (Markdown)."""
    s, lines = report["held_out"], []
    lines += [f"# wrenchd fit: {report['arm']}", "",
              f"Recordings: {', '.join(r['path'] for r in report['recordings'])}",
              f"Training samples: {report['train_samples']}; held out: {s['samples']} "
              f"(last {report['config']['holdout_fraction']:.0%} of each recording), "
              f"{s['inside_coverage']:.0%} of them inside the training coverage.",
              f"Fit time: {report['fit_seconds']:.1f} s.", "",
              "## Held-out torque RMSE per joint [N m; N on insertion]", "",
              "| joint | least squares | hybrid | change | torque std |",
              "| --- | --- | --- | --- | --- |"]
    for j, name in enumerate(JOINT_NAMES):
        ls, hy = s["ls_rmse"][j], s["hybrid_rmse"][j]
        lines.append(f"| {name} | {ls:.4f} | {hy:.4f} | {hy / ls - 1.0:+.1%} | "
                     f"{s['torque_std'][j]:.4f} |")
    lines += ["", "## Motion covered (share of the joint's span and speed cap)", "",
              "| joint | range | share | peak speed | share | |", "| --- | --- | --- | --- | --- | --- |"]
    for c in report["coverage"]:
        flag = "barely excited" if c["barely_excited"] else ""
        lines.append(f"| {c['joint']} | {c['range']:.3g} | {c['range_share']:.0%} | "
                     f"{c['max_speed']:.3g} | {c['speed_share']:.0%} | {flag} |")
    if report["warnings"]:
        lines += ["", "## Warnings", ""] + [f"- {w}" for w in report["warnings"]]
    return "\n".join(lines) + "\n"


def fit_recordings(recordings: Sequence[Recording], out: str | os.PathLike[str], *,
                   arm: str = "PSM1", origin: str = "robot", config: FitConfig | None = None,
                   progress: Callable[[str], None] | None = None,
                   on_epoch: Callable[[int, float], None] | None = None) -> dict:
    """Fit, score and write the bundle ``out`` (see the module docstring); returns the report.
    ``progress`` gets a line per stage, ``on_epoch(epoch, loss)`` follows the training.

    Raises:
        DataError: too little motion, or recordings too short to split.
        AdapterError: the bundle cannot be written (e.g. ``out`` exists).
    """
    from wrenchd.adapters.bundle import write_bundle

    config = config if config is not None else FitConfig()
    say = progress or (lambda _line: None)
    series = [r.joint_states for r in recordings]
    coverage: list[JointCoverage] = check_motion(series)
    if Path(out).exists():                                   # before minutes of fitting
        from wrenchd.models.errors import AdapterError
        raise AdapterError(f"{out} exists; a bundle is written to a new path")
    parts = [split_holdout(js, config.holdout_fraction) for js in series]
    train, held_out = [p[0] for p in parts], [p[1] for p in parts]
    say(f"fitting on {sum(len(js) for js in train)} samples "
        f"({len(recordings)} recording(s)), holding out {sum(len(js) for js in held_out)}")
    start = time.perf_counter()
    step1 = fit_hybrid(train, config.hybrid, on_epoch)
    fit_s = time.perf_counter() - start
    scores = score(step1, held_out)
    warnings = [f"{c.joint} barely excited: {c.range_share:.0%} of its range, "
                f"{c.speed_share:.0%} of its speed cap; the model is unidentified beyond"
                for c in coverage if c.barely_excited]
    for j, name in enumerate(JOINT_NAMES):
        if scores["hybrid_rmse"][j] > scores["ls_rmse"][j] * 1.02:
            warnings.append(f"{name}: the hybrid is worse than least squares on the held-out "
                            f"part ({scores['hybrid_rmse'][j]:.4f} vs {scores['ls_rmse'][j]:.4f})")
    report = {"arm": arm, "origin": origin, "config": config.model_dump(mode="json"),
              "recordings": [{"path": r.path, "kind": r.kind, "detail": r.detail,
                              "samples": len(r.joint_states),
                              "duration_s": float(r.joint_states.t[-1] - r.joint_states.t[0])}
                             for r in recordings],
              "train_samples": int(sum(len(js) for js in train)), "held_out": scores,
              "coverage": [c.to_json() for c in coverage], "warnings": warnings,
              "fit_seconds": fit_s, "model_info": step1.info}
    import torch

    weights = {k: torch.from_numpy(v) for k, v in step1.arrays().items()}
    description = step1.description()
    bundle = write_bundle(out, arm=arm, origin=origin, physics=description.pop("physics"),
                          report_md=report_markdown(report), report=report,
                          data_files=[r.path for r in recordings], weights=weights,
                          weights_config={"kind": HYBRID_KIND, **description})
    report["bundle_digest"] = bundle.digest
    return report
