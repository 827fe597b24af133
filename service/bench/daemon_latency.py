"""``wrenchd bench service``: end-to-end latency of the daemon over loopback zenoh.

The daemon runs as a real subprocess (``robot = "external"``, adaptation on: its calibration
phase trains the correction net eagerly, so the worker process is busy the whole time). This
process plays the robots: one thread publishes pre-encoded joint states of a simulated trocar
session for every arm at ``rate_hz``, and a subscriber per arm records when each wrench comes
back. Latency = arrival of the wrench - publication of its joint state, both on this
process's monotonic clock; wrenches are matched to joint states by their stamp.

Reported: ``e2e_p50_us``, ``e2e_p99_us`` (all arms pooled), ``dropped`` (joint states
published without a wrench back; the daemon's own ring drops, reported per arm, are among
them), ``rate_hz`` (wrenches per
second per arm, median over arms), and per-arm details.
"""

from __future__ import annotations

import gc
import itertools
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from wrenchd.adapters.messages import check_encoding, decode_wrench, encode_joint_state
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.service.bench.stages import ENV as STAGES_ENV
from wrenchd.service.provenance import load_average, steal_ticks, ticks_per_s
from wrenchd.service.runtime.scheduling import (enter_realtime, normal_scheduling, realtime_below,
                                              thread_scheduling)

STEAL_PERIOD_S = 0.1    # how often the hypervisor's steal counter is read while publishing


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _config(path: Path, endpoint: str, arms: list[str], log_dir: Path,
            adaptation: bool = True, log: bool = True,
            pin: tuple[list[int], list[int]] | None = None,
            realtime: int | str = "auto", intake: str = "channel", model: str = "seal",
            encoding: str = "json") -> None:
    lines = ['robot = "external"', "[cpus]", f"realtime_priority = {json.dumps(realtime)}"]
    if pin is not None:
        lines += [f"daemon = {pin[0]}", f"worker = {pin[1]}"]
    lines += ["[zenoh]", f'listen = ["{endpoint}"]', "[log]",
             f'directory = "{log_dir}"', f"enabled = {str(log).lower()}", "[ring]",
             "capacity = 4000", f'intake = "{intake}"']
    for arm in arms:
        lines += ["[[arms]]", f'name = "{arm}"', f'encoding = "{encoding}"',
                  f"model = {json.dumps(model)}",
                  "[arms.pipeline.adaptation]", f"enabled = {str(adaptation).lower()}"]
    path.write_text("\n".join(lines) + "\n")


def _rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` and its children [MB] (Linux /proc)."""
    total = 0
    pids = [pid]
    try:
        children = Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
        pids += [int(c) for c in children]
    except OSError:
        pass
    for p in pids:
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except OSError:
            continue
    return total / 1024.0


def _cpu_s(pid: int) -> float:
    """User + system CPU time of one process so far [s] (Linux /proc)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _zenoh_thread_classes() -> list[str]:
    """The scheduling classes of this process's zenoh receive and send threads (``rx-*``,
    ``tx-*``), which run the subscriber callbacks that time each wrench's arrival: sorted,
    each once (``normal``, ``fifo``, ``rr``, ...)."""
    seen = set()
    for task in Path("/proc/self/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
        except OSError:
            continue                                  # a thread that has just ended
        if name.startswith(("rx-", "tx-")):
            policy = thread_scheduling(int(task.name))["class"]
            if policy is not None:
                seen.add("normal" if policy == "SCHED_OTHER"
                         else policy.removeprefix("SCHED_").lower())
    return sorted(seen)


def _cpu_now(pid: int) -> dict[str, float]:
    """CPU seconds of the daemon and of its children (the worker), with the wall clock."""
    return {"daemon": _cpu_s(pid), "worker": sum(_cpu_s(c) for c in _children(pid)),
            "wall": time.monotonic()}


def _phase(lat_us: np.ndarray, c0: dict[str, float], c1: dict[str, float],
           samples: float) -> dict[str, float | None]:
    """Latency percentiles [us] and CPU [us per sample; fraction of a core] of one phase."""
    wall = max(c1["wall"] - c0["wall"], 1e-9)
    return {"e2e_p50_us": float(np.percentile(lat_us, 50)) if lat_us.size else None,
            "e2e_p99_us": float(np.percentile(lat_us, 99)) if lat_us.size else None,
            "daemon_cpu_us_per_sample": round((c1["daemon"] - c0["daemon"]) * 1e6
                                              / max(samples, 1.0), 1),
            "daemon_cpu_fraction": round((c1["daemon"] - c0["daemon"]) / wall, 3),
            "worker_cpu_fraction": round((c1["worker"] - c0["worker"]) / wall, 3)}


def _stolen_windows(steal: list[tuple[float, int | None]]) -> list[tuple[float, float]]:
    """``[(start_s, end_s)]`` of the sampling windows in which the hypervisor stole CPU time.
    ``steal`` is ``[(time_s, cumulative ticks)]``; a window is one sampling interval."""
    out = []
    for (t0, a), (t1, b) in itertools.pairwise(steal):
        if a is not None and b is not None and b > a:
            out.append((t0, t1))
    return out


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _drain(stream, path: Path) -> threading.Thread:
    """Copy a child's output stream to ``path`` until it closes, in a daemon thread.

    The daemon prints a status line per arm every second from its estimation thread; a pipe
    nobody reads is full after ~64 KB (about 11 minutes) and the next print, and with it
    estimation, blocks (a status line every 5 ms stalls it within seconds)."""
    def copy() -> None:
        with open(path, "w") as sink:
            for line in stream:
                sink.write(line)
    thread = threading.Thread(target=copy, name=f"drain-{path.name}", daemon=True)
    thread.start()
    return thread


#: How long the daemon may take to load its models and say it listens [s].
START_TIMEOUT_S = 120.0


def _await_listening(daemon: subprocess.Popen, n_arms: int, timeout_s: float) -> None:
    """Read the daemon's stdout until each arm's ``listening`` line, at most ``timeout_s``;
    a daemon that exits or stays silent is stopped and RuntimeError quotes its stderr."""
    lines: list[str] = []

    def read() -> None:
        while sum("listening" in line for line in lines) < n_arms:
            line = daemon.stdout.readline()
            if not line:
                return
            lines.append(line)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(timeout_s)
    if sum("listening" in line for line in lines) < n_arms:
        daemon.kill()
        err = daemon.communicate(timeout=10.0)[1] if daemon.stderr else ""
        raise RuntimeError(f"the daemon did not start within {timeout_s:g} s: "
                           f"{''.join(lines)}{err}")


def bench_service(n_arms: int = 1, rate_hz: float = 1000.0, duration_s: float = 20.0,
                  warmup_s: float = 3.0, adaptation: bool = True,
                  log: bool = True, floor: bool = False, pin: bool = False,
                  realtime: int | str = "auto", intake: str = "channel",
                  split_s: float | None = None, stages: bool = False, model: str = "seal",
                  recording: str | None = None, encoding: str = "json") -> dict[str, Any]:
    """Run the benchmark; returns the result dictionary.

    Also samples the daemon's resident memory (with its worker) once a second: the soak run
    is this benchmark with a long ``duration_s`` (``wrenchd bench soak``). With ``floor``
    the daemon is replaced by :mod:`wrenchd.service.bench.floor` (its plumbing without estimation:
    ``wrenchd bench floor``). With ``pin`` the daemon gets the last CPU to itself and its
    worker and this process share the others (the daemon's ``cpus`` settings). ``realtime``
    is the daemon's ``[cpus] realtime_priority`` (``auto``, ``off`` or a SCHED_FIFO priority),
    and this process's publisher and subscriber take the same: a robot's publisher runs in the
    real-time class, and a bench left in the normal class would be measured waiting behind the
    machine's other work (under load, its p99 is several times the one with both in the
    real-time class). The floor (and this process beside it) takes the class the daemon
    would. Only a process's first session makes zenoh's runtime threads, in the class of the
    thread that opens it: run a bench in a process that opened none before (as
    :func:`~wrenchd.service.bench.ratio.bench_ratio` does). ``intake`` is the daemon's
    ``[ring] intake`` (and the floor's). With ``split_s`` the result also has ``phases``: the
    latency and CPU figures of the samples sent before ``split_s`` (after the warm-up; the
    daemon's calibration minute when it is ``calibration_s``) and of those after it. With
    ``stages`` (the daemon only) the result also has ``stages``: the estimation thread's CPU
    time per stage over the whole run, warm-up included (:mod:`wrenchd.service.bench.stages`).
    ``model`` is every arm's step 1 (a shipped name or a bundle directory); ``recording`` (a
    file ``wrenchd replay`` reads) is published in place of the simulator's ``trocar``
    scenario, from its start again when it ends, at ``rate_hz`` (give its own rate).
    ``encoding`` is the arms' wire encoding (``json`` or ``cdr``), the floor's too."""
    from wrenchd.adapters.sim.scenarios import run_scenario
    from wrenchd.adapters.sim.simulator import SimulatorConfig

    arms = [f"PSM{k + 1}" for k in range(n_arms)]
    total_s = warmup_s + duration_s
    # a long soak repeats one simulated minute (time keeps increasing)
    block_s = min(total_s, 60.0)
    n = int(total_s * rate_hz)
    if recording is None:
        js = run_scenario("trocar", block_s + 1.0, 11,
                          config=SimulatorConfig(publish_rate_hz=rate_hz,
                                                 internal_rate_hz=max(1000.0, rate_hz))
                          ).joint_states
        m = int(block_s * rate_hz)
    else:
        from wrenchd.service.replay.source import load_session

        js = load_session(recording).joint_states
        m = len(js)
    stamps = [int(round(i * 1e9 / rate_hz)) for i in range(n)]
    payloads = [encode_joint_state(check_encoding(encoding), stamps[i], js.names,
                                   js.position[i % m], js.velocity[i % m], js.effort[i % m])
                for i in range(n)]
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    workdir = Path(tempfile.mkdtemp(prefix="wrenchd-bench-"))
    placement = None
    if pin:
        cpus = sorted(os.sched_getaffinity(0))
        if len(cpus) < 2:
            raise RuntimeError("--pin needs at least two CPUs")
        placement = ([cpus[-1]], cpus[:-1])
        os.sched_setaffinity(0, placement[1])
    if Path(model).exists():                  # a bundle: named from the daemon's workdir
        model = str(Path(model).resolve())
    _config(workdir / "bench.toml", endpoint, arms, workdir / "logs", adaptation, log, placement,
            realtime, intake, model, encoding)
    command = ([sys.executable, "-m", "wrenchd.service.bench.floor", "--listen", endpoint,
                "--intake", intake, "--realtime", str(realtime), "--encoding", encoding,
                "--arms", *arms] if floor else
               [sys.executable, "-m", "wrenchd", "serve", "--config",
                str(workdir / "bench.toml")])
    env = dict(os.environ)
    if stages and not floor:
        env[STAGES_ENV] = str(workdir / "stages.json")
    stage_times: dict[str, Any] | None = None
    daemon = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        preexec_fn=(lambda: os.sched_setaffinity(0, placement[0])) if placement else None)
    sent_ns = {arm: np.zeros(n, dtype=np.int64) for arm in arms}
    received: dict[str, list[tuple[int, bytes]]] = {arm: [] for arm in arms}
    session = None
    bench_priority = None
    status: dict[str, Any] = {}
    callback_classes: list[str] = []
    drains: list[threading.Thread] = []
    try:
        _await_listening(daemon, len(arms), START_TIMEOUT_S)
        drains = [_drain(daemon.stdout, workdir / "daemon.out"),
                  _drain(daemon.stderr, workdir / "daemon.err")]
        # as the daemon's setting says (its default takes the real-time class where it may),
        # the floor's too; before this process's first session opens: zenoh's runtime threads,
        # which run the subscriber callbacks, are made then, in the class of the thread that
        # opens it, and serve every later session of the process (see bench_ratio)
        bench_priority = enter_realtime(realtime)
        if bench_priority is not None:
            for thread in drains:          # they take the GIL too, beside the callbacks
                realtime_below(bench_priority, thread.native_id)
        session = open_session(ZenohConfig(connect=[endpoint]))
        subs = [session.declare_subscriber(
            f"dvrk/{arm}/wrenchd/measured_cf",
            lambda s, arm=arm: received[arm].append((time.perf_counter_ns(),
                                                     s.payload.to_bytes())))
            for arm in arms]
        # express, as the daemon's wrenches: batched, the arms' joint states of one tick could
        # wait up to zenoh's batching time limit (1 ms) here, in some runs and not in others,
        # and the floor and the daemon with them
        pubs = {arm: session.declare_publisher(f"dvrk/{arm}/measured_js", express=True)
                for arm in arms}
        time.sleep(1.0)                                     # let the routes settle
        callback_classes = _zenoh_thread_classes()
        period_ns = int(1e9 / rate_hz)
        # Pace by sleeping, never by spinning: a spinning publisher holds the GIL and delays
        # this process's own subscriber callbacks, which would be measured as daemon latency.
        sys.setswitchinterval(1e-4)
        # This process's own GC pauses would delay its subscriber callbacks and be measured as
        # daemon latency: freeze what is loaded and collect nothing while measuring.
        gc.collect()
        gc.freeze()
        gc.disable()
        rss: list[tuple[float, float]] = []
        steal: list[tuple[float, int | None]] = []       # (time since start s, ticks)
        start = time.perf_counter_ns()
        next_rss = 0.0
        next_steal = 0.0
        cpu_at: dict[str, float] = {}
        cpu_split: dict[str, float] = {}
        first = int(warmup_s * rate_hz)
        split = int(split_s * rate_hz) if split_s is not None and split_s > warmup_s else None
        for i in range(n):
            due = start + i * period_ns
            if i == first:              # CPU time spent by the daemon and its worker from here
                cpu_at = _cpu_now(daemon.pid)
            if i == split:
                cpu_split = _cpu_now(daemon.pid)
            if (due - start) / 1e9 >= next_steal:
                steal.append(((time.perf_counter_ns() - start) / 1e9, steal_ticks()))
                next_steal += STEAL_PERIOD_S
            if (due - start) / 1e9 >= next_rss:
                rss.append((next_rss, _rss_mb(daemon.pid)))
                next_rss += 1.0
            now = time.perf_counter_ns()
            if due > now:
                time.sleep((due - now) / 1e9)
            for arm in arms:
                sent_ns[arm][i] = time.perf_counter_ns()
                pubs[arm].put(payloads[i])
        cpu = _cpu_now(daemon.pid)
        steal.append(((time.perf_counter_ns() - start) / 1e9, steal_ticks()))
        time.sleep(2.0)                                     # the last wrenches come back
        gc.enable()
        for arm in arms if not floor else []:          # the floor answers no status
            replies = list(session.get(f"dvrk/{arm}/wrenchd/status", timeout=5.0))
            ok = [r.ok for r in replies if r.ok is not None]
            status[arm] = json.loads(ok[0].payload.to_bytes()) if ok else {}
        for sub in subs:
            sub.undeclare()
        for pub in pubs.values():
            pub.undeclare()
    finally:
        if session is not None:
            session.close()
        if bench_priority is not None:
            normal_scheduling()
        daemon.send_signal(signal.SIGINT)
        try:
            if drains:                           # the drain threads own its output now
                daemon.wait(timeout=60)
                for thread in drains:
                    thread.join(timeout=10)
            else:
                daemon.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            daemon.kill()
        if STAGES_ENV in env and (workdir / "stages.json").is_file():
            stage_times = json.loads((workdir / "stages.json").read_text())
        if daemon.returncode == 0:
            shutil.rmtree(workdir, ignore_errors=True)   # kept when the daemon failed
    index = {s: i for i, s in enumerate(stamps)}
    stolen = _stolen_windows(steal)
    stolen_starts = np.array([a for a, _ in stolen])
    stolen_ends = np.array([b for _, b in stolen])
    latencies, per_arm = [], {}
    latency_at: list[float] = []                  # send time [s] of each pooled latency
    clean: list[float] = []          # latencies during which the hypervisor stole nothing
    for arm in arms:
        lat, got = [], np.zeros(n, dtype=bool)
        lat_at: list[float] = []                          # send time of each latency [s]
        for arrived, payload in received[arm]:
            stamp = decode_wrench(encoding, payload)[0]
            i = index.get(stamp)
            if i is None:
                continue
            got[i] = True
            if i >= first:
                lat.append((arrived - sent_ns[arm][i]) / 1e3)
                lat_at.append(i / rate_hz)
                t_sent, t_back = (sent_ns[arm][i] - start) / 1e9, (arrived - start) / 1e9
                if not np.any((stolen_starts < t_back) & (stolen_ends > t_sent)):
                    clean.append(lat[-1])
        missing = int((~got).sum())
        ring = int(status.get(arm, {}).get("counters", {}).get("dropped", 0))
        arr = np.array(lat) if lat else np.array([np.nan])
        per_arm[arm] = {"e2e_p50_us": float(np.percentile(arr, 50)),
                        "e2e_p99_us": float(np.percentile(arr, 99)),
                        "e2e_max_us": float(np.max(arr)), "missing": missing,
                        "ring_dropped": ring, "received": int(got.sum()),
                        "rate_hz": float(got[first:].sum() / duration_s),
                        "model_version": status.get(arm, {}).get("model", {}).get("version"),
                        "adaptation_rounds": status.get(arm, {}).get("counters", {}).get(
                            "rounds"),
                        # when the worst ones happened: [send time s, latency ms], worst first
                        "e2e_worst": [[round(lat_at[k], 3), round(lat[k] / 1e3, 1)]
                                      for k in np.argsort(lat)[::-1][:10]] if lat else []}
        latencies.extend(lat)
        latency_at.extend(lat_at)
    pooled = np.array(latencies) if latencies else np.array([np.nan])
    ticks = [(t, k) for t, k in steal if k is not None and t >= warmup_s]
    hz = ticks_per_s()
    # The hypervisor of a shared VM stops its CPUs now and then (up to a large part of a
    # second); what arrives meanwhile waits, whatever the daemon does.
    hypervisor = {
        "steal_cpu_s": round((ticks[-1][1] - ticks[0][1]) / hz, 3) if len(ticks) > 1 else None,
        "steal_windows": sum(1 for a, _ in stolen if a >= warmup_s),
        "steal_window_s": STEAL_PERIOD_S,
        "e2e_p99_us_without_steal": float(np.percentile(clean, 99)) if clean else None,
        "samples_without_steal": len(clean)}
    # the tail over time: a p99 made by a few long stalls reads differently from a wide
    # spread everywhere (per second after the warm-up, all arms pooled: p99 and max [ms])
    by_second: list[list[float]] = []
    if latencies:
        secs = np.floor(np.array(latency_at)).astype(int)
        pooled_lat = np.array(latencies)
        for sec in np.unique(secs):
            w = pooled_lat[secs == sec]
            by_second.append([int(sec), round(float(np.percentile(w, 99)) / 1e3, 2),
                              round(float(w.max()) / 1e3, 1)])
    after_warmup = [mb for t, mb in rss if t >= warmup_s] or [np.nan]
    memory = {"rss_start_mb": round(after_warmup[0], 1), "rss_end_mb": round(after_warmup[-1], 1),
              "rss_max_mb": round(float(np.max(after_warmup)), 1),
              "rss_growth_mb": round(after_warmup[-1] - after_warmup[0], 1),
              "rss_every_60s_mb": [round(mb, 1) for t, mb in rss if t % 60 == 0]}
    estimated = sum(a["rate_hz"] for a in per_arm.values()) * duration_s   # after warm-up
    usage = {"daemon_cpu_us_per_sample": round(
                 (cpu["daemon"] - cpu_at["daemon"]) * 1e6 / max(estimated, 1.0), 1),
             "daemon_cpu_fraction": round((cpu["daemon"] - cpu_at["daemon"])
                                          / (cpu["wall"] - cpu_at["wall"]), 3),
             "worker_cpu_fraction": round((cpu["worker"] - cpu_at["worker"])
                                          / (cpu["wall"] - cpu_at["wall"]), 3),
             "load_average_1min": (load_average() or [None])[0]}
    phases = None
    if cpu_split:
        at = np.array(latency_at)
        rate = sum(a["rate_hz"] for a in per_arm.values())
        phases = {name: _phase(np.array(latencies)[mask] if latencies else np.array([]), c0, c1,
                               rate * (span[1] - span[0]))
                  for name, mask, c0, c1, span in (
                      ("before", at < split_s, cpu_at, cpu_split, (warmup_s, split_s)),
                      ("after", at >= split_s, cpu_split, cpu, (split_s, total_s)))}
        phases["split_s"] = split_s
    extra = {} if stage_times is None else {"stages": stage_times}
    return {**memory, **usage, **hypervisor, "phases": phases, **extra,
            "e2e_p50_us": float(np.percentile(pooled, 50)),
            "e2e_p99_us": float(np.percentile(pooled, 99)),
            # samples without a wrench back (the daemon's ring drops are among them)
            "dropped": int(sum(a["missing"] for a in per_arm.values())),
            "rate_hz": float(np.median([a["rate_hz"] for a in per_arm.values()])),
            "arms": n_arms, "target_rate_hz": rate_hz, "duration_s": duration_s,
            "warmup_s": warmup_s, "cpu_count": os.cpu_count(),
            "adaptation": adaptation and not floor, "mcap_log": log and not floor,
            "intake": intake, "encoding": encoding,
            "daemon": "bench floor (no estimation)" if floor else "wrenchd serve",
            "cpus": ({"daemon": placement[0], "worker_and_bench": placement[1]}
                     if placement else None),
            # the daemon's sample path (its default takes the real-time class where
            # permitted); the floor's is the setting it was given
            "realtime_priority": realtime if floor else next(
                (st.get("realtime_priority") for st in status.values()), realtime),
            "bench_realtime_priority": bench_priority,
            "bench_zenoh_thread_classes": callback_classes,
            "e2e_by_second": by_second, "per_arm": per_arm}
