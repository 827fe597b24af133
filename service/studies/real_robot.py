"""The whole pipeline on a real robot's recordings: ``wrenchd real-robot``.

One command, four parts, all on the WPI dVRK PSM recordings (free motion, so the true tip
force is zero except where contacts are injected):

1. **Newtons at the tip**: step 1 fitted on ``one_no_weight.csv``, the free-motion tip force
   of ``two.csv`` (never seen) and of the training recording per model
   (:func:`wrenchd.service.studies.real_data.evaluate`).
2. **Known loads**: the 105 g and 205 g parallelogram loads (full and half speed) at their
   photographed point, against the estimated external torques.
   The served estimate is step 1 and the correction net together: ``concat:two.csv*N``
   played through the pipeline (gated and frozen), its free-motion tip force after the
   calibration minute, which fits the correction net on this session's free motion
   (:func:`served_free_motion`).
3. **A real set-up change**: a bundle fitted by ``wrenchd fit`` on ``one_no_weight.csv``
   serves ``concat:one_no_weight.csv*N,one_205g_parallel.csv*N`` under each adaptation
   policy (the load appears at the change of recording, unannounced); the free-motion tip
   force before and after, and over time.
4. **Injected sessions**: ``inject:S:concat:two.csv*M,one_no_weight.csv*M`` (a simulated
   trocar and tip contacts drawn with seed S added to real efforts), gated: contact force
   RMSE, free-motion force, contacts found, contact samples offered to training.

Everything lands in one folder: ``report.md``, ``report.json``, the compare runs' own
tables and plots, and the bundle that served.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from wrenchd.models.errors import ConfigError

#: Where the WPI loads sat, in ``parallel_upper``'s frame [m]
#: (``shared/data/wpi-psm/README.md``: 16.5 cm along the link, 2.0 / 2.3 cm above it).
LOAD_POINTS = {0.105: (0.165, -0.020, 0.0), 0.205: (0.165, -0.023, 0.0)}
LOADED = (("one_105g_parallel.csv", 0.105), ("one_205g_parallel.csv", 0.205),
          ("one_slow_105g_parallel.csv", 0.105), ("one_slow_205g_parallel.csv", 0.205))


@dataclass(frozen=True)
class RealRobotConfig:
    """Sizes of the study; :meth:`quick` is the test suite's."""

    repeats: int = 6                   # each recording of the set-up change session
    inject_repeats: int = 4            # each recording of an injected session
    served_repeats: int = 4            # two.csv played through the pipeline
    seeds: tuple[int, ...] = (3, 4, 5)
    policies: tuple[str, ...] = ("gated", "frozen", "ungated")
    models: tuple[str, ...] = ("lstm", "ls", "hybrid")
    hybrid_epochs: int | None = None   # the residual net's (default of the hybrid)
    fit_epochs: int = 200              # the bundle's residual net

    @classmethod
    def quick(cls) -> RealRobotConfig:
        return cls(repeats=1, inject_repeats=1, served_repeats=3, seeds=(3,), policies=("gated", "frozen"),
                   models=("ls", "hybrid"), hybrid_epochs=20, fit_epochs=20)


def _path(data: Path, name: str) -> str:
    path = data / name
    if not path.is_file():
        raise ConfigError(f"{path}: missing; --data must be the WPI recordings folder "
                          "(shared/data/wpi-psm)")
    return str(path)


def newtons_and_loads(data: Path, config: RealRobotConfig) -> dict[str, Any]:
    """Parts 1 and 2: :func:`~wrenchd.service.studies.real_data.evaluate` with known loads."""
    from wrenchd.service.studies.newtons import KnownLoad
    from wrenchd.service.studies.real_data import Source, evaluate

    loads = [KnownLoad(Source(_path(data, name)), mass, "parallel_upper", LOAD_POINTS[mass])
             for name, mass in LOADED]
    return evaluate([Source(_path(data, "one_no_weight.csv"))],
                    Source(_path(data, "two.csv")), config.models,
                    hybrid_epochs=config.hybrid_epochs, known_loads=loads)


def fit_bundle(data: Path, out: Path, config: RealRobotConfig) -> dict[str, Any]:
    """A bundle fitted on ``one_no_weight.csv`` as ``wrenchd fit`` fits it."""
    from wrenchd.adapters.recordings import read_recording
    from wrenchd.models.estimator.hybrid import HybridConfig, ResidualNetConfig
    from wrenchd.service.studies.fit import FitConfig, fit_recordings

    residual = ResidualNetConfig(epochs=config.fit_epochs)
    return fit_recordings([read_recording(_path(data, "one_no_weight.csv"))], out,
                          config=FitConfig(hybrid=HybridConfig(residual=residual)),
                          progress=lambda *_: None)


#: The reference for the set-up change's ``after`` figure: step 1 fitted on a recording's
#: first ``REFERENCE_SPLIT_S`` seconds, scored on the rest of it (another stretch of the same
#: motion, the same run).
REFERENCE_SPLIT_S = 20.0


def in_recording_reference(data: Path, config: RealRobotConfig) -> dict[str, Any]:
    """Free-motion tip force [N] (RMS, p95) of the hybrid fitted on the first
    :data:`REFERENCE_SPLIT_S` seconds of each recording of the set-up change and scored on the
    rest: what a step 1 that knew that very run reads on time it did not see. The set-up
    change's ``before`` window is in-sample for the bundle (fitted on all of
    ``one_no_weight.csv``); its ``after`` window is not."""
    from wrenchd.service.studies.newtons import force_stats, tip_forces
    from wrenchd.service.studies.real_data import Source, Trained

    out: dict[str, Any] = {"split_s": REFERENCE_SPLIT_S, "files": {}}
    for name in ("one_no_weight.csv", "one_205g_parallel.csv"):
        path = _path(data, name)
        trained = Trained([Source(path, None, REFERENCE_SPLIT_S).load()], ["hybrid"], 0, None,
                          config.hybrid_epochs, f"{path}:0:{REFERENCE_SPLIT_S:g}")
        test = Source(path, REFERENCE_SPLIT_S, None).load()
        pred = trained.predict(test)["hybrid"]
        stats = force_stats(tip_forces(test.position, test.effort - pred))
        out["files"][name] = {"rms": stats["rms"], "p95": stats["p95"]}
    return out


def served_free_motion(spec: str, free_space, policies: Sequence[str]) -> list[dict[str, Any]]:
    """The free-motion tip force [N] the pipeline publishes on ``spec`` (a session without
    contact), over the calibration minute and after it, per policy; the second after each seam
    of a ``concat:`` left out (:data:`~wrenchd.service.replay.events_scored.SEAM_SKIP_S`)."""
    import numpy as np

    from wrenchd.service.pipeline import PipelineConfig
    from wrenchd.service.replay.events_scored import after_seam
    from wrenchd.service.replay.loop import replay
    from wrenchd.service.replay.policies import get_policy
    from wrenchd.service.replay.source import load_session

    session = load_session(spec)
    out = []
    for policy in policies:
        config = get_policy(policy).configure(PipelineConfig())
        r = replay(session, free_space, config, policy=policy)
        force = np.linalg.norm(r.wrench[:, :3], axis=1)
        keep = ~after_seam(r.t, session)
        calibrated = r.t - r.t[0] >= config.calibration_s
        row: dict[str, Any] = {"session": spec, "policy": policy,
                               "calibration_s": config.calibration_s}
        for name, mask in (("calibration", keep & ~calibrated), ("after", keep & calibrated)):
            f = force[mask]
            row[name] = ({"rms": float(np.sqrt(np.mean(f ** 2))),
                          "p95": float(np.quantile(f, 0.95)), "samples": int(mask.sum())}
                         if f.size else None)
        out.append(row)
    return out


def _rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """The figures of each compare row that the report shows."""
    keep = ("session", "policy", "samples", "wall_s", "setup_changes", "truth", "false_force_N",
            "gate", "gate_episodes", "gate_detector", "contacts_found", "contamination",
            "final_model_version",
            "estimated_force_mean_N", "events")
    return [{k: r[k] for k in keep if k in r} for r in rows]


def run(data: str | Path, out: str | Path, config: RealRobotConfig | None = None,
        log: Callable[[str], None] = print, command: str = "") -> dict[str, Any]:
    """The four parts; writes ``out`` and returns the JSON-ready results."""
    from wrenchd.service.pipeline.step1 import load_free_space
    from wrenchd.service.replay.compare import run_compare

    config = config if config is not None else RealRobotConfig()
    data, out = Path(data), Path(out)
    out.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    r: dict[str, Any] = {"command": command, "data": str(data), "config": config.__dict__ | {"seeds": list(
        config.seeds), "policies": list(config.policies), "models": list(config.models)}}
    log("newtons at the tip and known loads ...")
    r["step1"] = newtons_and_loads(data, config)
    log("fitting the bundle on one_no_weight.csv ...")
    bundle = out / "bundle"
    if bundle.exists():                        # this folder's own bundle, from a former run
        import shutil

        shutil.rmtree(bundle)
    fit = fit_bundle(data, bundle, config)
    r["bundle"] = {"path": bundle.name, "held_out": fit.get("held_out"),
                   "digest": fit.get("bundle_digest")}
    free_space = load_free_space(str(bundle))
    log("served pipeline on two.csv ...")
    r["served"] = served_free_motion(
        f"concat:{_path(data, 'two.csv')}*{config.served_repeats}", free_space, ("gated",
                                                                                 "frozen"))
    change = (f"concat:{_path(data, 'one_no_weight.csv')}*{config.repeats},"
              f"{_path(data, 'one_205g_parallel.csv')}*{config.repeats}")
    log(f"set-up change: {', '.join(config.policies)} ...")
    r["setup_change"] = _rows(run_compare(list(config.policies), [change], out / "setup-change",
                                          free_space, log=log))
    r["setup_change_reference"] = in_recording_reference(data, config)
    injected = [f"inject:{s}:concat:{_path(data, 'two.csv')}*{config.inject_repeats},"
                f"{_path(data, 'one_no_weight.csv')}*{config.inject_repeats}"
                for s in config.seeds]
    log("injected sessions ...")
    r["injected"] = _rows(run_compare(["gated"], injected, out / "injected", free_space,
                                      log=log))
    r["wall_s"] = round(time.monotonic() - started, 1)
    (out / "report.json").write_text(json.dumps(r, indent=1, default=str) + "\n")
    from wrenchd.service.studies.real_robot_report import markdown

    (out / "report.md").write_text(markdown(r))
    return r
