"""The daemon against its plumbing floor, measured in the same run (``wrenchd bench ratio``).

Latency and CPU on a shared machine drift from minute to minute, so a target is a ratio to
the floor (:mod:`wrenchd.service.bench.floor`: the daemon's intake and publishing without
estimation) measured beside it: ``pairs`` times the floor and then the daemon, one after the
other, each over the same simulated stream. Per pair, ``ratio_p99`` (end-to-end p99 latency)
and ``ratio_cpu`` (daemon CPU per sample); the daemon's calibration minute (eager adaptation,
the calibration guard) and the time after it are reported apart (``phases``), each against
the same floor. Load and stolen CPU come with every run, and the p99 ratio of the samples
during which the hypervisor stole nothing (``ratio_p99_without_steal``).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from wrenchd.service.pipeline.config import PipelineConfig

#: the daemon's calibration [s]: the phases split there
CALIBRATION_S = PipelineConfig().calibration_s


def _ratio(num: float | None, den: float | None) -> float | None:
    return None if num is None or not den else num / den


def pair_ratios(floor: dict[str, Any], daemon: dict[str, Any]) -> dict[str, Any]:
    """Ratios of one pair: overall and per phase of the daemon, to the floor's overall."""
    p99, cpu = floor["e2e_p99_us"], floor["daemon_cpu_us_per_sample"]
    out = {"ratio_p99": _ratio(daemon["e2e_p99_us"], p99),
           "ratio_cpu": _ratio(daemon["daemon_cpu_us_per_sample"], cpu),
           # the samples during which the hypervisor stole no CPU, in both runs
           "ratio_p99_without_steal": _ratio(daemon.get("e2e_p99_us_without_steal"),
                                             floor.get("e2e_p99_us_without_steal"))}
    for name in ("before", "after"):
        ph = (daemon.get("phases") or {}).get(name)
        if ph:
            out[name] = {"ratio_p99": _ratio(ph["e2e_p99_us"], p99),
                         "ratio_cpu": _ratio(ph["daemon_cpu_us_per_sample"], cpu)}
    return out


def _median(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.median(kept)) if kept else None


def isolated(**kwargs: Any) -> dict[str, Any]:
    """:func:`~wrenchd.service.bench.daemon_latency.bench_service` (``kwargs``, JSON values)
    in a Python process of its own, its result.

    A process's zenoh runtime threads, which run its subscriber callbacks, are made with its
    first session, in the class of the thread that opens it, and serve all its later
    sessions: in one process a daemon run after a floor run would be measured by callbacks
    left in the class the first run had, not the daemon's (on 2 cores its 1-arm p99 read
    0.9-1.0 ms where the same daemon on its own reads 0.36-0.41 ms). A fresh process measures
    each run as ``wrenchd bench service`` or ``floor`` alone would.
    """
    with tempfile.TemporaryDirectory(prefix="wrenchd-ratio-") as tmp:
        out = Path(tmp) / "run.json"
        code = ("import json, sys\n"
                "from wrenchd.service.bench.daemon_latency import bench_service\n"
                "result = bench_service(**json.loads(sys.argv[1]))\n"
                "open(sys.argv[2], 'w').write(json.dumps(result))\n")
        done = subprocess.run([sys.executable, "-c", code, json.dumps(kwargs), str(out)],
                              capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"a bench run failed (exit {done.returncode}): "
                               f"{done.stderr.strip()[-2000:]}")
        return json.loads(out.read_text())


def bench_ratio(n_arms: int = 1, rate_hz: float = 1000.0, duration_s: float = 90.0,
                pairs: int = 2, split_s: float = CALIBRATION_S,
                log: Callable[[str], None] = lambda _: None, **kwargs: Any) -> dict[str, Any]:
    """``pairs`` x (floor, daemon) over ``duration_s`` each, each run in a process of its own
    (:func:`isolated`; keyword arguments go to
    :func:`~wrenchd.service.bench.daemon_latency.bench_service`); the median of the pairs'
    ratios, each pair's runs and ratios."""
    if pairs < 1:
        raise ValueError("pairs must be at least 1")
    runs = []
    for k in range(pairs):
        floor = isolated(n_arms=n_arms, rate_hz=rate_hz, duration_s=duration_s, floor=True,
                         **kwargs)
        log(f"pair {k + 1}: floor p99 {floor['e2e_p99_us']:.0f} us")
        daemon = isolated(n_arms=n_arms, rate_hz=rate_hz, duration_s=duration_s,
                          split_s=split_s, **kwargs)
        log(f"pair {k + 1}: daemon p99 {daemon['e2e_p99_us']:.0f} us, "
            f"dropped {daemon['dropped']}")
        runs.append({"floor": floor, "daemon": daemon, **pair_ratios(floor, daemon)})
    summary: dict[str, Any] = {
        key: _median([r[key] for r in runs])
        for key in ("ratio_p99", "ratio_cpu", "ratio_p99_without_steal")}
    for name in ("before", "after"):
        summary[name] = {key: _median([(r.get(name) or {}).get(key) for r in runs])
                         for key in ("ratio_p99", "ratio_cpu")}
    return {"arms": n_arms, "rate_hz": rate_hz, "duration_s": duration_s, "pairs": pairs,
            "split_s": split_s, **summary,
            "dropped": sum(r["daemon"]["dropped"] for r in runs),
            "floor_p99_us": [r["floor"]["e2e_p99_us"] for r in runs],
            "daemon_p99_us": [r["daemon"]["e2e_p99_us"] for r in runs],
            "load_average_1min": [r[w]["load_average_1min"] for r in runs
                                  for w in ("floor", "daemon")],
            "steal_cpu_s": [r[w]["steal_cpu_s"] for r in runs for w in ("floor", "daemon")],
            "runs": runs}
