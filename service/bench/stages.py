"""Where the daemon's estimation thread spends its CPU, stage by stage (``bench service
--stages``).

With :data:`ENV` naming a file, ``wrenchd serve`` wraps the methods of :data:`STAGES` before
it starts: each call adds its thread CPU time (``time.thread_time_ns``) to its stage, and at
exit the totals go to that file as JSON (per stage: calls, total seconds, microseconds a
call). Stages nest (``pipeline (one sample)`` holds ``estimate (one)``); a wrapper costs
about a microsecond a call, so the figures are a little high and the daemon's CPU per sample
too: use them to compare stages, not as the daemon's speed. Without :data:`ENV` nothing is
wrapped.
"""

from __future__ import annotations

import atexit
import importlib
import json
import os
import threading
import time
from pathlib import Path

#: the environment variable naming the file the totals go to
ENV = "WRENCHD_BENCH_STAGES"

#: (module, class, method, stage): what is timed
STAGES = (
    ("wrenchd.service.runtime.intake", "ChannelIntake", "take", "intake"),
    ("wrenchd.service.runtime.arm", "ArmRuntime", "handle_many", "handle (one arm's batch)"),
    ("wrenchd.service.runtime.daemon", "Daemon", "_handle_joint", "handle (arms stepped together)"),
    ("wrenchd.service.runtime.arm", "ArmRuntime", "_decode", "decode"),
    ("wrenchd.service.pipeline.arm", "ArmPipeline", "process", "pipeline (one sample)"),
    ("wrenchd.service.pipeline.arm", "ArmPipeline", "process_many_joint", "pipeline (a batch)"),
    ("wrenchd.service.pipeline.arm", "ArmPipeline", "_admit", "admit"),
    ("wrenchd.models.estimator.estimator", "TwoStepEstimator", "step_one", "estimate (one)"),
    ("wrenchd.models.estimator.estimator", "TwoStepEstimator", "step_many_joint",
     "estimate (a batch)"),
    ("wrenchd.service.pipeline.arm", "ArmPipeline", "_after", "gate, guard, drift, offer"),
    ("wrenchd.service.pipeline.arm", "ArmPipeline", "_adapt", "adaptation tick"),
    ("wrenchd.service.runtime.arm", "ArmRuntime", "_emit", "publish and log"),
    ("wrenchd.service.runtime.arm", "ArmRuntime", "housekeeping", "housekeeping"),
)


def install(path: str | os.PathLike) -> dict[str, list[int]]:
    """Wrap :data:`STAGES` and write their totals to ``path`` at exit; the live totals
    ({stage: [thread CPU ns, calls]})."""
    totals: dict[str, list[int]] = {}
    lock = threading.Lock()

    def timed(fn, stage: str):
        def wrapper(*args, **kwargs):
            c0 = time.thread_time_ns()
            try:
                return fn(*args, **kwargs)
            finally:
                spent = time.thread_time_ns() - c0
                with lock:
                    entry = totals.setdefault(stage, [0, 0])
                    entry[0] += spent
                    entry[1] += 1
        wrapper.__wrapped__ = fn
        return wrapper

    for module, cls_name, method, stage in STAGES:
        cls = getattr(importlib.import_module(module), cls_name)
        raw = cls.__dict__[method]
        if isinstance(raw, staticmethod):
            setattr(cls, method, staticmethod(timed(raw.__func__, stage)))
        else:
            setattr(cls, method, timed(raw, stage))

    def dump() -> None:
        Path(path).write_text(json.dumps(summary(totals), indent=1) + "\n")

    atexit.register(dump)
    return totals


def summary(totals: dict[str, list[int]]) -> dict[str, dict[str, float]]:
    """{stage: calls, total_s, us_per_call}, the stages in :data:`STAGES`' order."""
    order = {stage: k for k, (_, _, _, stage) in enumerate(STAGES)}
    return {stage: {"calls": calls, "total_s": round(ns / 1e9, 4),
                    "us_per_call": round(ns / calls / 1e3, 2)}
            for stage, (ns, calls) in sorted(totals.items(), key=lambda kv: order[kv[0]])
            if calls}
