"""``wrenchd bench fit``: the wall time of ``wrenchd fit`` from reading to a written bundle."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path


def bench_fit(recording: str | None = None, duration_s: float = 30.0, seed: int = 0) -> dict:
    """Time the whole ``wrenchd fit`` workflow on ``recording`` (default: ``duration_s`` of
    the simulator's ``free-space`` scenario at 200 Hz, written as a CSV first, untimed)."""
    from wrenchd.adapters.recordings import read_recording
    from wrenchd.service.studies.fit import fit_recordings

    with tempfile.TemporaryDirectory(prefix="wrenchd-bench-fit-") as tmp:
        if recording is None:
            from wrenchd.adapters.csv_psm import write_paper_csv
            from wrenchd.adapters.sim.scenarios import run_scenario

            recording = str(Path(tmp) / "free-space.csv")
            write_paper_csv(recording, run_scenario("free-space", duration_s, seed).joint_states)
            source = f"sim:free-space:{duration_s:g}:{seed}"
        else:
            source = recording
        start = time.perf_counter()
        rec = read_recording(recording)
        read_s = time.perf_counter() - start
        report = fit_recordings([rec], Path(tmp) / "bundle")
        wall_s = time.perf_counter() - start
    js = rec.joint_states
    return {"bench": "fit", "recording": source, "samples": len(js),
            "duration_s": round(float(js.t[-1] - js.t[0]), 3),
            "rate_hz": round((len(js) - 1) / float(js.t[-1] - js.t[0]), 1),
            "read_s": round(read_s, 3), "fit_s": round(report["fit_seconds"], 2),
            "wall_s": round(wall_s, 2), "epochs": report["config"]["hybrid"]["residual"]["epochs"],
            "held_out_ls_rmse": report["held_out"]["ls_rmse"],
            "held_out_hybrid_rmse": report["held_out"]["hybrid_rmse"]}
