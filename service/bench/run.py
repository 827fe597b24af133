"""``wrenchd bench``: speed measured, not asserted.

``inference`` times one streaming step of the whole two-step estimator (the four step-1 group
networks, Corr and the wrench map) on one core, and batched offline inference, on a simulated
``trocar-contact`` session. Latency does not depend on the weights' values, so freshly
initialised networks (normalised on the session) are used; the figure is the cost of the
computation the service runs per sample.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from wrenchd.service.provenance import RunMeter, stamp


def bench_inference(duration_s: float = 60.0, seed: int = 3, warmup: int = 500) -> dict:
    """Returns ``{"step_p50_us", "step_p99_us", "batch_samples_per_s", ...}``."""
    import torch

    torch.set_num_threads(1)
    from wrenchd.adapters.sim.scenarios import run_scenario
    from wrenchd.models.estimator.correction import Corr
    from wrenchd.models.estimator.estimator import TwoStepEstimator
    from wrenchd.models.estimator.free_space import FreeSpaceModel

    torch.manual_seed(seed)
    js = run_scenario("trocar-contact", duration_s, seed).joint_states
    x = np.c_[js.position, js.velocity]
    base = FreeSpaceModel()
    base.set_input_normalisation(x)
    base.set_output_normalisation(js.effort)
    corr = Corr()
    corr.set_normalisation(x, js.effort)
    est = TwoStepEstimator(base.eval(), corr)
    for i in range(min(warmup, len(js))):
        est.step_one(js.t[i], js.position[i], js.velocity[i], js.effort[i])
    est.reset_state()
    lat_us = np.empty(len(js))
    clock = time.perf_counter_ns
    for i in range(len(js)):
        start = clock()
        est.step_one(js.t[i], js.position[i], js.velocity[i], js.effort[i])
        lat_us[i] = (clock() - start) / 1e3
    start = time.perf_counter()
    est.predict_batch(js)
    batch_s = time.perf_counter() - start
    return {
        "step_p50_us": round(float(np.percentile(lat_us, 50)), 1),
        "step_p99_us": round(float(np.percentile(lat_us, 99)), 1),
        "batch_samples_per_s": round(len(js) / batch_s),
        "samples": len(js),
        "estimator": "step 1 (4 group LSTMs) + Corr + damped J^-T wrench",
        "threads": 1,
    }


def run(kind: str, json_path: str | None, duration_s: float, arms: int = 1,
        rate_hz: float = 1000.0, pin: bool = False, realtime: int | str = "auto",
        recording: str | None = None, intake: str = "channel", pairs: int = 2,
        stages: bool = False, model: str = "seal", encoding: str = "json") -> int:
    """Run the bench ``kind``, print its result as JSON (with its provenance) and write it to
    ``json_path`` too when given."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    meter = RunMeter()
    if kind == "inference":
        result = bench_inference(duration_s=duration_s)
    elif kind == "arm":
        result = bench_arm_thread(duration_s=duration_s, model=model, recording=recording,
                                  encoding=encoding)
    elif kind in ("service", "soak", "floor"):
        from wrenchd.service.bench.daemon_latency import bench_service

        result = bench_service(n_arms=arms, rate_hz=rate_hz, duration_s=duration_s,
                               floor=kind == "floor", pin=pin, realtime=realtime,
                               intake=intake, stages=stages, model=model,
                               recording=recording, encoding=encoding)
    elif kind == "ratio":
        from wrenchd.service.bench.ratio import bench_ratio

        result = bench_ratio(n_arms=arms, rate_hz=rate_hz, duration_s=duration_s, pairs=pairs,
                             pin=pin, realtime=realtime, intake=intake, model=model,
                             recording=recording, encoding=encoding,
                             log=lambda line: print(line, file=sys.stderr, flush=True))
    elif kind == "replay":
        from wrenchd.service.bench.replay import run_replay_bench

        result = run_replay_bench(duration_s)
    elif kind == "fit":
        from wrenchd.service.bench.fit import bench_fit

        result = bench_fit(recording, duration_s)
    else:
        raise SystemExit(f"wrenchd bench: unknown benchmark {kind!r}")
    from wrenchd.models.estimator.compiled import kernels_in_use

    result["kernels"] = kernels_in_use()        # the daemon's too: it inherits the environment
    stamp(result, run=meter)
    text = json.dumps(result, indent=2)
    print(text)
    if json_path:
        Path(json_path).parent.mkdir(parents=True, exist_ok=True)
        Path(json_path).write_text(text + "\n")
    return 0


#: ``bench arm``: samples per block; every other block is paced at 1 kHz
PACED_BLOCK = 500


def bench_arm_thread(duration_s: float = 20.0, model: str = "seal",
                     recording: str | None = None, encoding: str = "json") -> dict:
    """Per-sample cost of the daemon's work for one arm, without zenoh: decode the joint
    state (``encoding``: JSON or CDR), run the pipeline (frozen: no adaptation rounds),
    encode the wrench, hand both log records to the log writer (``log``); and, apart
    (``log_writer``), the log writer process's work: format and write them to MCAP.
    Percentiles per stage [us], one ``trocar`` session at 200 Hz, or ``recording`` (a file
    ``wrenchd replay`` reads) played again until it lasts ``duration_s``; step 1 ``model``
    (a shipped name or a bundle directory, as the daemon's ``[model] step1``).

    After a first block of ``PACED_BLOCK`` samples (warming up, counted in neither), the
    samples go in blocks of as many, every other one paced as the daemon sees them at 1 kHz
    (the thread sleeps until the next millisecond after each sample): ``paced`` against
    ``tight`` (back to back) says what the idle between samples costs the work (wall time
    and the thread's own CPU time per sample, the log writer's work included)."""
    import tempfile

    import numpy as np

    from collections import deque

    from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, LogConfig, McapLog, format_record
    from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
    from wrenchd.adapters.messages import decode_joint_state, encode_joint_state, encode_wrench
    from wrenchd.adapters.sim.scenarios import run_scenario
    from wrenchd.service.pipeline.step1 import load_free_space
    from wrenchd.service.runtime.arm import estimate_payload, joint_state_payload
    from wrenchd.service.pipeline import ArmPipeline, PipelineConfig, PolicyConfig

    if recording is None:
        js = run_scenario("trocar", duration_s, 1).joint_states
    else:
        from wrenchd.service.replay.source import load_session

        once = load_session(recording).joint_states
        span = float(once.t[-1] - once.t[0]) if len(once) > 1 else 0.0
        times = max(1, math.ceil(duration_s / span)) if span > 0 else 1
        js = load_session(f"concat:{recording}*{times}").joint_states
    payloads = [encode_joint_state(encoding, int(round(js.t[i] * 1e9)), js.names,
                                   js.position[i], js.velocity[i], js.effort[i])
                for i in range(len(js))]
    extra = encoding == "json"
    pipeline = ArmPipeline("PSM1", load_free_space(model),
                           PipelineConfig(policy=PolicyConfig(name="frozen")))
    # the daemon's own work per sample (decode, pipeline, wrench encode, hand-over to the log
    # writer); the log writer process's work (format, write) is timed apart: it runs elsewhere
    stages: dict[str, list[float]] = {"decode": [], "pipeline": [], "encode": [], "log": []}
    writer: list[float] = []
    # per pacing mode: (wall [us], the thread's CPU [us]) of each sample's whole work
    modes: dict[str, tuple[list[float], list[float]]] = {"tight": ([], []), "paced": ([], [])}
    queue: deque = deque()
    next_t = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        log = McapLog("PSM1", LogConfig(directory=tmp))
        for i, payload in enumerate(payloads):
            block = i // PACED_BLOCK
            paced = block % 2 == 0 and block > 0
            if paced:
                next_t += 1e-3
                wait = next_t - time.perf_counter()
                if wait > 0:
                    time.sleep(wait)
            else:
                next_t = time.perf_counter()
            c0 = time.thread_time()
            t0 = time.perf_counter()
            msg = decode_joint_state(encoding, payload)
            t1 = time.perf_counter()
            est, _ = pipeline.process(msg)
            t2 = time.perf_counter()
            encode_wrench(encoding, est.stamp_ns, est.wrench, "psm_base",
                          {"free": est.free, "model_version": est.model_version,
                           "score": min(est.score, 1e9)} if extra else None)
            t3 = time.perf_counter()
            queue.append((0, TOPIC_JOINT_STATES, est.stamp_ns,
                          joint_state_payload(payload, msg, encoding)))
            queue.append((0, TOPIC_ESTIMATE, est.stamp_ns, estimate_payload(est)))
            t4 = time.perf_counter()
            while queue:
                _, topic, stamp_ns, record = queue.popleft()
                log.write(topic, stamp_ns, format_record(record))
            log.tick()
            t5 = time.perf_counter()
            writer.append((t5 - t4) * 1e6)
            if block > 0:
                wall, cpu = modes["paced" if paced else "tight"]
                wall.append((t5 - t0) * 1e6)
                cpu.append((time.thread_time() - c0) * 1e6)
            for name, a, b in (("decode", t0, t1), ("pipeline", t1, t2), ("encode", t2, t3),
                               ("log", t3, t4)):
                stages[name].append((b - a) * 1e6)
        log.close()
    total = np.sum([stages[k] for k in stages], axis=0)
    out = {f"{k}_p50_us": round(float(np.percentile(v, 50)), 1) for k, v in stages.items()}
    out.update({f"{k}_p99_us": round(float(np.percentile(v, 99)), 1) for k, v in stages.items()})
    out.update({"total_p50_us": round(float(np.percentile(total, 50)), 1),
                "total_p99_us": round(float(np.percentile(total, 99)), 1),
                "log_writer_p50_us": round(float(np.percentile(writer, 50)), 1),
                "log_writer_p99_us": round(float(np.percentile(writer, 99)), 1),
                "samples": len(payloads), "threads": 1, "encoding": encoding})
    for mode, (wall, cpu) in modes.items():
        if wall:
            out[mode] = {"wall_p50_us": round(float(np.percentile(wall, 50)), 1),
                         "wall_p99_us": round(float(np.percentile(wall, 99)), 1),
                         "thread_cpu_p50_us": round(float(np.percentile(cpu, 50)), 1),
                         "thread_cpu_mean_us": round(float(np.mean(cpu)), 1),
                         "samples": len(wall)}
    return out
