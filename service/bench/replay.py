"""``wrenchd bench replay``: throughput of the replay (samples per second, real-time factor)."""

from __future__ import annotations

import os
import time


def _rounded(x: float | None) -> float | None:
    return None if x is None else round(x, 2)


def run_replay_bench(duration_s: float = 120.0, policy: str = "gated", seed: int = 3) -> dict:
    """Replay a 200 Hz ``insufflation-change`` session of ``duration_s`` with ``policy``.

    Returns ``{"samples_per_s", "realtime_factor", ...}`` of the default replay (batched,
    torch step 1, adaptation in the forked worker): the replay call itself (pipeline,
    adaptation, batched pre-pass), not simulating or writing, with the CPU seconds of this
    process (pipeline and step-1 thread, ``cpu_s``) and of the worker (``worker_cpu_s``): on
    two cores the wall time is at least half their sum. The same run also times inline
    adaptation, the kernel step 1 and the frozen policy.
    """
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from wrenchd.service.runtime.scheduling import one_compute_thread

    one_compute_thread()
    from wrenchd.adapters.sim.scenarios import run_scenario
    from wrenchd.models.estimator.pretrained import load_pretrained
    from wrenchd.service.pipeline import PipelineConfig
    from wrenchd.service.replay.loop import replay
    from wrenchd.service.replay.policies import get_policy

    session = run_scenario("insufflation-change", duration_s, seed)
    fs = load_pretrained("seal")
    config = get_policy(policy).configure(PipelineConfig())
    result: dict = {"policy": policy, "session": f"sim:insufflation-change:{duration_s:g}:{seed}",
                    "rate_hz": session.joint_states.rate_hz, "threads": 1}
    frozen = get_policy("frozen").configure(PipelineConfig())
    # the default first; the others measured in the same run for comparison
    for name, cfg, kwargs in (("default", config, {}),
                              ("inline_adaptation", config, {"adaptation": "inline"}),
                              ("kernel_step1", config, {"step1": "kernel"}),
                              ("frozen_no_adaptation", frozen, {})):
        cpu0 = os.times()
        start = time.perf_counter()
        r = replay(session, fs, cfg, policy=policy, **kwargs)
        wall = time.perf_counter() - start
        cpu1 = os.times()
        sps = len(r.t) / wall
        result[name] = {"samples_per_s": round(sps), "wall_s": round(wall, 2),
                        "rounds": r.status["counters"]["rounds"],
                        "waited_for_worker": r.meta.get("rounds_waited"),
                        # of the wall time, blocked on the worker's answer (idle work aside)
                        "blocked_on_worker_s": _rounded(r.meta.get("blocked_on_worker_s")),
                        # this process (the pipeline and the step-1 thread) and the forked
                        # adaptation worker, which has ended and been waited for by now
                        "cpu_s": round(cpu1.user + cpu1.system - cpu0.user - cpu0.system, 2),
                        "worker_cpu_s": round(cpu1.children_user + cpu1.children_system
                                              - cpu0.children_user - cpu0.children_system, 2)}
    best = result["default"]["samples_per_s"]
    result["samples"] = len(session.joint_states)
    result["samples_per_s"] = best
    result["realtime_factor"] = round(best / session.joint_states.rate_hz, 2)
    return result
