"""The wrenchd daemon: zenoh in, two-step estimate + gate + lifelong adaptation, zenoh and MCAP out.

One zenoh session per daemon; per arm:

* a subscriber on ``measured_js`` whose callback only stamps the payload with its arrival time
  and puts it in a bounded ring (no decoding, inference or training in a zenoh callback); a
  full ring drops its oldest sample and counts it (``dropped``);
* the daemon's estimation thread (one for all arms, interleaving them) drains the ring
  through the arm's :class:`ArmPipeline` (decode -> validate -> estimate -> gate), publishes
  the wrench and events, and hands inputs, estimates, events and a status snapshot to the log
  writer process (:mod:`wrenchd.service.runtime.log_process`), which formats and writes them to the arm's
  :class:`McapLog` (flushed every second, rotated) outside the daemon's GIL;
* a queryable ``status`` (JSON: model version, rates, latency percentiles, counters, gate and
  drift state) and a liveliness token ``alive``.

One adaptation worker process serves all arms (:mod:`wrenchd.service.runtime.worker`). With
``robot = "simulated"`` (the embedded default) the daemon also starts the simulated PSM as a
separate process publishing on each arm's ``measured_js`` (``wrenchd robot``), recording its
ground truth beside the logs.

SIGINT/SIGTERM stop cleanly: subscribers are undeclared first (no callback runs after), the
estimation thread finishes what is queued, the worker stops, the logs are finished, the
session is closed.
"""

from __future__ import annotations

import gc
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import orjson

from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, TOPIC_EVENTS, TOPIC_STATUS, McapLog
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.messages import (decode_joint_state, decode_setup_change, encode_wrench,
                               prepare_encoding)
from wrenchd.adapters.zenoh_io import open_session
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.runtime.settings import ArmConfig, ServiceSettings
from wrenchd.models.adaptation.adapter import normalisation_of
from wrenchd.service.pipeline import ArmPipeline, Estimate, Event
from wrenchd.service.runtime.log_process import LogWriterProcess
from wrenchd.service.runtime.scheduling import enter_realtime, normal_scheduling, realtime, realtime_below
from wrenchd.service.runtime.worker import ProcessAdaptation, WorkerProcess

SWITCH_INTERVAL_S = 2e-4
LINK_CHECK_S = 0.5      # how often the session's routers and peers are counted [s]
BATCH = 32              # samples of one arm estimated before the next arm's turn
SETUP_INBOX = 64        # set-up change notices waiting at most per arm (the oldest go)


def load_free_space(spec: str) -> FreeSpaceModel:
    """A shipped step-1 model by name (``base``, ``seal``) or a step-1 checkpoint file."""
    from wrenchd.models.estimator.checkpoint import load_checkpoint
    from wrenchd.models.estimator.pretrained import PRETRAINED, load_pretrained

    if spec in PRETRAINED:
        return load_pretrained(spec)
    ckpt = load_checkpoint(spec)
    if ckpt.kind != "free_space":
        raise ConfigError(f"{spec}: the arm model must be a step-1 checkpoint, got {ckpt.kind}")
    return ckpt.model


class SampleRing:
    """Bounded FIFO between the zenoh callback and the estimation thread; drops the oldest.

    ``wake`` is set on every put; rings of one daemon share it (one estimation thread).
    """

    def __init__(self, capacity: int, wake: threading.Event | None = None) -> None:
        self._items: deque[tuple[int, bytes]] = deque()
        self._capacity = capacity
        self._lock = threading.Lock()
        self.wake = wake if wake is not None else threading.Event()
        self.dropped = 0

    def put(self, item: tuple[int, bytes]) -> None:
        with self._lock:
            if len(self._items) >= self._capacity:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
        self.wake.set()

    def drain(self) -> list[tuple[int, bytes]]:
        with self._lock:
            items = list(self._items)
            self._items.clear()
        return items


def _event_bytes(body: dict[str, Any]) -> bytes:
    """JSON of an event or status: NumPy values natively, a non-finite number as ``null``,
    anything else as its text."""
    return orjson.dumps(body, default=str,
                        option=orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS)


def _percentiles(values) -> dict[str, float | None]:
    if not values:
        return {"p50": None, "p99": None, "max": None}
    a = np.fromiter(values, dtype=float)
    return {"p50": float(np.percentile(a, 50)), "p99": float(np.percentile(a, 99)),
            "max": float(a.max())}


def estimate_payload(est: Estimate, frame_id: str = "psm_base") -> tuple[str, tuple]:
    """The ``/wrenchd/estimate`` log record of one estimate, as plain values for the log
    writer (:func:`wrenchd.adapters.mcap_log.format_record` makes the bytes)."""
    return ("estimate", (est.stamp_ns, frame_id, est.wrench.tolist(), bool(est.free),
                         float(est.score), int(est.model_version), bool(est.restarted),
                         est.predicted_torque.tolist(), est.external_torque.tolist()))



class Console:
    """Status lines printed by their own thread from a bounded queue: a slow or paused
    terminal (Ctrl-S), a stuck journal or an unread pipe must never block estimation; lines
    beyond ``capacity`` waiting are dropped (counted)."""

    def __init__(self, capacity: int = 200) -> None:
        self._queue: queue.Queue[str | None] = queue.Queue(maxsize=capacity)
        self.dropped = 0
        self.thread = threading.Thread(target=self._run, name="wrenchd-console", daemon=True)
        self.thread.start()

    def say(self, line: str) -> None:
        try:
            self._queue.put_nowait(line)
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while (line := self._queue.get()) is not None:
            try:
                print(line, flush=True)
            except (OSError, ValueError):         # stdout closed: nothing to tell anyone
                pass

    def close(self, timeout_s: float = 2.0) -> None:
        try:
            self._queue.put(None, timeout=timeout_s)
        except queue.Full:
            pass
        self.thread.join(timeout=timeout_s)


class ArmRuntime:
    """One arm's subscriber, ring, estimation thread, publishers, queryable, token and log."""

    def __init__(self, cfg: ArmConfig, settings: ServiceSettings, session,
                 worker: WorkerProcess | None, wake: threading.Event,
                 free_space: FreeSpaceModel) -> None:
        self.cfg, self.settings = cfg, settings
        self.name = cfg.name
        self.keys = cfg.keys.resolve(settings.prefix, cfg.name)
        backend = (ProcessAdaptation(worker, cfg.name) if worker is not None else None)
        self.pipeline = ArmPipeline(cfg.name, free_space, cfg.pipeline, backend)
        if cfg.corr_checkpoint:
            self._load_corr(cfg.corr_checkpoint)
        prepare_encoding(cfg.encoding)
        self.ring = SampleRing(settings.ring.capacity, wake)
        self.latency_us: deque[float] = deque(maxlen=5000)
        self.rate_hz = 0.0
        self.last: Estimate | None = None
        self.log = McapLog(cfg.name, settings.log, metadata={
            "arm": cfg.name, "settings": settings.model_dump(mode="json"),
            "keys": self.keys})
        self.log_writer: LogWriterProcess | None = None    # set by the daemon before start()
        self.console: Console | None = None                 # likewise
        self.realtime_priority: int | None = None           # likewise: the sample path's
        self.zenoh_links: dict[str, int] = {"routers": 0, "peers": 0, "link_losses": 0}
        self._log_problem_reported = False
        self.pub_wrench = session.declare_publisher(self.keys["wrench"])
        self.pub_events = session.declare_publisher(self.keys["events"])
        self.queryable = session.declare_queryable(self.keys["status"], self._on_query)
        self.token = session.liveliness().declare_token(self.keys["alive"])
        # set-up changes (JSON, any encoding): a few at most, handled on the estimation thread
        self.setup_inbox: deque[bytes] = deque(maxlen=SETUP_INBOX)
        self.setup_dropped = 0          # notices pushed out of a full inbox (counted, reported)
        self._wake = wake
        self.sub_setup = session.declare_subscriber(self.keys["setup"], self._on_setup)
        self.sub = session.declare_subscriber(self.keys["measured_js"], self._on_sample)
        now = time.monotonic()
        self._next_status = now + settings.status_interval_s
        self._count_at, self._count_t = 0, now

    def _load_corr(self, path: str) -> None:
        from wrenchd.models.estimator.checkpoint import load_checkpoint

        ckpt = load_checkpoint(path)
        if ckpt.kind != "corr":
            raise ConfigError(f"{path}: corr_checkpoint must be a Corr checkpoint, got {ckpt.kind}")
        self.pipeline.estimator.swap_correction(ckpt.model)
        self.pipeline.model_version = int(ckpt.validation.get("version", 0))

    # -- zenoh callbacks (zenoh's threads): keep them trivial ----------------------------
    def _on_sample(self, sample) -> None:
        self.ring.put((time.perf_counter_ns(), sample.payload.to_bytes()))

    def _on_setup(self, sample) -> None:
        if len(self.setup_inbox) == SETUP_INBOX:
            self.setup_dropped += 1
        self.setup_inbox.append(sample.payload.to_bytes())
        self._wake.set()

    def _on_query(self, query) -> None:
        try:
            query.reply(self.keys["status"], _event_bytes(self.status()))
        except Exception as exc:  # noqa: BLE001 - a query must never kill the daemon
            print(f"wrenchd: status query failed: {exc}", file=sys.stderr)

    def status(self) -> dict[str, Any]:
        s = self.pipeline.status()
        s["counters"]["dropped"] = self.ring.dropped
        s["counters"]["setup_dropped"] = self.setup_dropped
        s["rate_hz"] = self.rate_hz
        s["latency_us"] = _percentiles(list(self.latency_us))
        s["encoding"] = self.cfg.encoding
        s["realtime_priority"] = self.realtime_priority
        s["zenoh"] = dict(self.zenoh_links)
        s["keys"] = self.keys
        s["log"] = {"path": str(self.log.path) if self.log.path else None,
                    "written": self.log.written, "lost": self.log.lost,
                    "problem": self.log.problem}
        s["adaptation_worker_alive"] = (self.pipeline.backend.worker.alive
                                        if isinstance(self.pipeline.backend, ProcessAdaptation)
                                        else None)
        return s

    # -- on the estimation thread --------------------------------------------------------
    def _publish_events(self, events: list[Event]) -> None:
        for ev in events:
            payload = _event_bytes(ev.to_json())
            self.pub_events.put(payload)
            self._log(TOPIC_EVENTS, max(int(ev.t * 1e9), 0), payload)

    def _log(self, topic: str, stamp_ns: int, payload) -> None:
        """Hand a record (bytes, or a formatter's name and arguments) to the log writer."""
        self.log_writer.put(self.log, topic, stamp_ns, payload)

    def _decode(self, payload: bytes):
        """The decoded joint state, or None after publishing the refusal's error event."""
        try:
            return decode_joint_state(self.cfg.encoding, payload)
        except DataError as exc:
            self._publish_refusal(self.pipeline.reject(time.time(), "decode", str(exc)),
                                  payload)
            return None

    def _publish_refusal(self, ev: Event, payload: bytes) -> None:
        """Publish and log a refused payload's error event with its size and first bytes."""
        self._publish_events([Event(ev.t, ev.kind, {**ev.detail, "payload_bytes": len(payload),
                                                    "payload_head": payload[:64].hex()})])

    def handle_setup(self) -> None:
        """Announced set-up changes received so far: decoded, validated and given to the
        pipeline (its ``setup_change`` event, or an ``error`` event naming what was wrong)."""
        while self.setup_inbox:
            payload = self.setup_inbox.popleft()
            try:
                stamp_ns, detail = decode_setup_change(payload)
            except DataError as exc:
                self._publish_refusal(self.pipeline.refuse_setup(time.time(), str(exc)), payload)
                continue
            try:
                events = self.pipeline.setup_change(
                    None if stamp_ns is None else stamp_ns / 1e9, detail)
            except Exception as exc:  # noqa: BLE001 - never let a notice kill the arm
                self.internal_error(exc)
                continue
            self._publish_events(events)

    def handle(self, arrived_ns: int, payload: bytes) -> None:
        """One payload through decode -> pipeline -> publish -> log."""
        msg = self._decode(payload)
        if msg is not None:
            self._emit(arrived_ns, payload, msg, *self.pipeline.process(msg))

    def handle_many(self, items: list[tuple[int, bytes]]) -> None:
        """Queued payloads of this arm, in order: a backlog goes through the pipeline in one
        pass (:meth:`ArmPipeline.process_many`); each wrench is published as soon as its
        batch is estimated."""
        if len(items) < ArmPipeline.BATCH_MIN:
            for arrived_ns, payload in items:
                self.handle_safe(arrived_ns, payload)
            return
        try:
            decoded = [(arrived_ns, payload, self._decode(payload))
                       for arrived_ns, payload in items]
            decoded = [d for d in decoded if d[2] is not None]
            results = self.pipeline.process_many([d[2] for d in decoded])
        except Exception as exc:  # noqa: BLE001 - never let one batch kill the arm
            self.internal_error(exc)
            return
        for (arrived_ns, payload, msg), (est, events) in zip(decoded, results):
            self.emit_safe(arrived_ns, payload, msg, est, events)

    def internal_error(self, exc: Exception) -> None:
        """A bug met on this arm's path: a counted ``internal`` error event, never a crash."""
        ev = self.pipeline.reject(time.time(), "internal", f"{type(exc).__name__}: {exc}")
        self._publish_events([ev])

    def emit_safe(self, arrived_ns: int, payload: bytes, msg, est: Estimate | None,
                  events: list[Event]) -> None:
        try:
            self._emit(arrived_ns, payload, msg, est, events)
        except Exception as exc:  # noqa: BLE001 - never let one sample kill the arm
            self.internal_error(exc)

    def _emit(self, arrived_ns: int, payload: bytes, msg, est: Estimate | None,
              events: list[Event]) -> None:
        """Publish and log one sample's outcome."""
        enc = self.cfg.encoding
        if est is not None:
            extra = ({"free": est.free, "model_version": est.model_version,
                      "score": min(est.score, 1e9)} if enc == "json" else None)
            self.pub_wrench.put(encode_wrench(enc, est.stamp_ns, est.wrench, self.cfg.frame_id,
                                              extra))
            self.latency_us.append((time.perf_counter_ns() - arrived_ns) / 1e3)
            self.last = est
            # Formatting and writing happen on the log writer thread. A JSON input with its
            # six names is logged as received; anything else is re-encoded there.
            if enc == "json" and len(msg.name) == len(JOINT_NAMES):
                record = payload
            else:
                names = msg.name if len(msg.name) == len(JOINT_NAMES) else JOINT_NAMES
                record = ("joint_state", (est.stamp_ns, list(names), msg.position.tolist(),
                                          msg.velocity.tolist(), msg.effort.tolist(),
                                          msg.frame_id))
            self._log(TOPIC_JOINT_STATES, est.stamp_ns, record)
            self._log(TOPIC_ESTIMATE, est.stamp_ns, estimate_payload(est, self.cfg.frame_id))
        if events:
            self._publish_events(events)

    def handle_safe(self, arrived_ns: int, payload: bytes) -> None:
        """:meth:`handle`, turning any exception into a counted ``internal`` error event."""
        try:
            self.handle(arrived_ns, payload)
        except Exception as exc:  # noqa: BLE001 - never let one sample kill the arm
            self.internal_error(exc)

    def housekeeping(self, now: float) -> None:
        """Once in a while: rate, status snapshot to the log and console, log problems."""
        if now >= self._next_status:
            est = self.pipeline.counters.estimated
            self.rate_hz = (est - self._count_at) / max(now - self._count_t, 1e-9)
            self._count_at, self._count_t = est, now
            self._next_status = now + self.settings.status_interval_s
            status = self.status()
            stamp = self.last.stamp_ns if self.last is not None else 0
            self._log(TOPIC_STATUS, stamp, _event_bytes(status))
            self._console(status)
        if self.log.problem and not self._log_problem_reported:
            self._log_problem_reported = True
            self._publish_events([Event(time.time(), "log_error",
                                        {"arm": self.name, "error": self.log.problem})])
        elif self.log.problem is None:                # a fresh file is open again
            self._log_problem_reported = False

    def _console(self, status: dict[str, Any]) -> None:
        est = self.last
        say = self.console.say if self.console is not None else print
        if est is None:
            say(f"{self.name}: waiting for joint states on '{self.keys['measured_js']}'")
            return
        c = status["counters"]
        lat = status["latency_us"]
        say(f"{self.name} t={est.t:8.2f} s  {self.rate_hz:6.1f} Hz  "
              f"|F|={np.linalg.norm(est.wrench[:3]):5.2f} N  "
              f"{'free   ' if est.free else 'contact'}  model v{est.model_version}  "
              f"p99 {lat['p99'] or 0:7.0f} us  dropped {c['dropped']}  errors {c['errors']}")

    def close(self) -> None:
        """Undeclare in a safe order (the thread must have stopped)."""
        for entity in (self.sub, self.sub_setup, self.queryable, self.token, self.pub_wrench,
                       self.pub_events):
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - closing must go on
                pass
        self.pipeline.close()


def _robot_command(settings: ServiceSettings, arm: str) -> list[str]:
    sim = settings.simulator
    endpoints = settings.zenoh.listen or ["tcp/127.0.0.1:7447"]
    cmd = [sys.executable, "-m", "wrenchd", "robot", "--scenario", sim.scenario,
           "--seed", str(sim.seed), "--arm", arm, "--rate", str(sim.rate_hz),
           "--prefix", settings.prefix,
           "--out-dir", str(Path(settings.log.directory) / "robot"), "--quiet"]
    for ep in endpoints:
        cmd += ["--connect", ep.replace("0.0.0.0", "127.0.0.1")]
    if settings.duration_s is not None:
        cmd += ["--duration", str(settings.duration_s)]
    return cmd


class Daemon:
    """All arms of one daemon (see the module docstring)."""

    def __init__(self, settings: ServiceSettings) -> None:
        self.settings = settings
        self.stop = threading.Event()
        self.wake = threading.Event()               # set by every arm's zenoh callback
        self.thread: threading.Thread | None = None
        self.session = None
        self.worker: WorkerProcess | None = None
        self.arms: list[ArmRuntime] = []
        self.robots: list[subprocess.Popen] = []
        self.log_writer: LogWriterProcess | None = None
        self.console: Console | None = None
        self.realtime_priority: int | None = None
        self._links: tuple[int, int] | None = None       # (routers, peers) last counted
        self._links_next = 0.0

    def start(self) -> None:
        s = self.settings
        # The zenoh callback threads and the estimation threads share the GIL; at the default
        # 5 ms switch interval a sample could wait that long for its thread to run.
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        self.realtime_priority = self._realtime_priority()   # checked before loading
        if s.cpus.daemon is not None:
            # before any thread or process is made: they all inherit it (the worker resets
            # its own when cpus.worker is set)
            os.sched_setaffinity(0, s.cpus.daemon)
        adapt = {a.name: a.pipeline.adaptation for a in s.arms
                 if a.pipeline.adaptation.enabled and a.pipeline.policy.name != "frozen"}
        loaded: dict[str, FreeSpaceModel] = {}           # one copy of each distinct model
        for spec in {a.model for a in s.arms}:
            loaded[spec] = load_free_space(spec)
        self.models = {a.name: loaded[a.model] for a in s.arms}
        if adapt:
            frac = min(c.max_cpu_fraction for c in adapt.values())
            norms = {name: normalisation_of(self.models[name]) for name in adapt}
            self.worker = WorkerProcess(adapt, s.effective_models_dir(), frac, norms,
                                        cpus=s.cpus.worker)
        if self.realtime_priority is not None:
            # from here until the estimation thread is started, every thread made (zenoh's
            # runtime and callback threads, estimation) inherits the real-time class; the worker
            # was spawned before, and the robots are started after it is left
            realtime(self.realtime_priority)
        try:
            self.session = open_session(s.zenoh)
        except BaseException:
            normal_scheduling()
            raise
        try:
            for cfg in s.arms:
                worker = self.worker if cfg.name in adapt else None
                self.arms.append(ArmRuntime(cfg, s, self.session, worker, self.wake,
                                            self.models[cfg.name]))
        except Exception:
            normal_scheduling()
            self.close()
            raise
        first: dict[int, ArmRuntime] = {}
        for arm in self.arms:                           # arms of one model share its weights
            model = id(self.models[arm.name])
            if model in first:
                arm.pipeline.estimator.share_step1(first[model].pipeline.estimator)
            else:
                first[model] = arm
        self.log_writer = LogWriterProcess([arm.log for arm in self.arms], cpus=s.cpus.worker)
        self.console = Console()
        for arm in self.arms:
            arm.log_writer = self.log_writer
            arm.console = self.console
            arm.realtime_priority = self.realtime_priority
        # Everything loaded so far (torch, models: ~260k objects) lives as long as the daemon.
        # Freezing it keeps the cyclic GC from scanning it: a full collection of it takes
        # 100-300 ms on this machine, a stall every estimate would wait through.
        gc.collect()
        gc.freeze()
        self.thread = threading.Thread(target=self._estimate, name="wrenchd-estimate",
                                       daemon=True)
        self.thread.start()
        if self.realtime_priority is not None:
            # The log writer and the console take the GIL too: left in the normal class, one
            # preempted by other programs while holding it would hold up estimation with it.
            # One step below, they never preempt the sample path.
            for thread in (self.log_writer.thread, self.console.thread):
                realtime_below(self.realtime_priority, thread.native_id)
            normal_scheduling()
        if s.robot == "simulated":
            for arm in self.arms:
                self.robots.append(subprocess.Popen(_robot_command(s, arm.name)))
        if self.realtime_priority is not None:
            # the main thread too, now that it has started every process it starts: it wakes
            # five times a second, and so takes the GIL (see the log writer above)
            realtime_below(self.realtime_priority)
        for arm in self.arms:
            print(f"wrenchd: {arm.name} ({arm.cfg.encoding}) listening on "
                  f"'{arm.keys['measured_js']}', publishing wrenches on '{arm.keys['wrench']}', "
                  f"logging to {s.log.directory}", flush=True)

    def _realtime_priority(self) -> int | None:
        """The SCHED_FIFO priority of the sample path, None for the normal class; an explicit
        priority this process may not take is refused (:class:`ConfigError`), ``auto`` falls
        back to the normal class and says so."""
        wanted = self.settings.cpus.realtime_priority
        priority = enter_realtime(wanted)
        if priority is None:
            if wanted == "auto":
                print("wrenchd: real-time scheduling is not permitted here, so the sample path "
                      "runs in the normal class (latency then depends on what else runs; see "
                      "[cpus] realtime_priority)", file=sys.stderr, flush=True)
            return None
        normal_scheduling()
        return priority

    def _estimate(self) -> None:
        """The estimation thread: every arm's queued samples, in arrival order per arm, arms
        taking turns (arms of one model with one sample each are stepped together; a backlog
        of one arm goes through in one pass), then each arm's housekeeping; until stopped
        (what is queued at the stop is still estimated).

        One thread for all arms, not one each: estimation threads of one process would only
        take turns on the GIL, and each switch costs; interleaving keeps arms fair.
        """
        arms = self.arms
        while True:
            stopping = self.stop.is_set()
            self.wake.wait(0.05)
            self.wake.clear()
            for arm in arms:
                if arm.setup_inbox:               # before the samples that came after them
                    arm.handle_setup()
            queued = [(arm, arm.ring.drain()) for arm in arms]
            depth = max((len(items) for _, items in queued), default=0)
            # arms take turns, at most BATCH samples each (samples that arrive meanwhile set
            # ``wake``); a backlog of one arm goes through its pipeline in one pass
            for k in range(0, depth, BATCH):
                groups: dict[int, list[tuple[ArmRuntime, list[tuple[int, bytes]]]]] = {}
                for arm, items in queued:
                    chunk = items[k:k + BATCH]
                    if chunk:                          # arms of one model: stepped together
                        groups.setdefault(id(arm.pipeline.estimator.step1_kernel), []).append(
                            (arm, chunk))
                for group in groups.values():
                    if len(group) == 1:
                        group[0][0].handle_many(group[0][1])
                    else:
                        self._handle_joint(group)
            now = time.monotonic()
            for arm in arms:
                arm.housekeeping(now)
            if now >= self._links_next:
                self._links_next = now + LINK_CHECK_S
                self._watch_links()
            if stopping:
                break

    def _watch_links(self) -> None:
        """Count the routers and peers the session is connected to; every change is a
        ``zenoh_link`` event on every arm (``lost`` when the last one went: what the daemon
        publishes then reaches nobody, though its log keeps everything)."""
        try:
            links = (len(self.session.info.routers_zid()), len(self.session.info.peers_zid()))
        except Exception:  # noqa: BLE001 - a session being closed
            return
        before, self._links = self._links, links
        if before == links:
            return
        lost = sum(links) == 0 and before is not None
        for arm in self.arms:
            arm.zenoh_links.update(routers=links[0], peers=links[1])
            arm.zenoh_links["link_losses"] += int(lost)
            if before is None:                               # the first count: no change yet
                continue
            arm._publish_events([Event(time.time(), "zenoh_link", {
                "arm": arm.name, "routers": links[0], "peers": links[1], "lost": lost})])

    @staticmethod
    def _handle_joint(group: list[tuple[ArmRuntime, list[tuple[int, bytes]]]]) -> None:
        """Queued samples of several arms sharing a step-1 model: their recurrences run as
        one batch (:meth:`ArmPipeline.process_many_joint`), the weights read once a step."""
        try:
            decoded = [[(arrived_ns, payload, msg) for arrived_ns, payload in chunk
                        if (msg := arm._decode(payload)) is not None] for arm, chunk in group]
            results = ArmPipeline.process_many_joint(
                [arm.pipeline for arm, _ in group], [[d[2] for d in dec] for dec in decoded])
        except Exception as exc:  # noqa: BLE001 - never let one batch kill the arms
            for arm, _ in group:
                arm.internal_error(exc)
            return
        for (arm, _), dec, res in zip(group, decoded, results):
            for (arrived_ns, payload, msg), (est, events) in zip(dec, res):
                arm.emit_safe(arrived_ns, payload, msg, est, events)

    def run(self, duration_s: float | None = None) -> int:
        """Start, serve until SIGINT/SIGTERM or ``duration_s``, stop cleanly. Returns 0."""
        def _stop(signum, _frame):
            self.stop.set()

        old = {sig: signal.signal(sig, _stop) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            self.start()
            deadline = None if duration_s is None else time.monotonic() + duration_s
            while not self.stop.wait(0.2):
                if deadline is not None and time.monotonic() >= deadline:
                    break
        finally:
            self.close()
            for sig, handler in old.items():
                signal.signal(sig, handler)
        return 0

    def close(self) -> None:
        self.stop.set()
        for robot in self.robots:
            if robot.poll() is None:
                robot.send_signal(signal.SIGINT)
        for arm in self.arms:
            try:
                arm.sub.undeclare()          # no callback after this point
            except Exception:  # noqa: BLE001
                pass
        self.wake.set()
        if self.thread is not None and self.thread.is_alive():
            self.thread.join(timeout=10.0)
        for arm in self.arms:
            arm.close()
        if self.console is not None:
            self.console.close()
            self.console = None
        if self.log_writer is not None:            # writes what is queued, finishes the files
            self.log_writer.close()
            self.log_writer = None
        else:
            for arm in self.arms:
                arm.log.close()
        if self.worker is not None:
            self.worker.close()
        for robot in self.robots:
            try:
                robot.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                robot.kill()
        if self.session is not None:
            self.session.close()
            self.session = None
        totals = {a.name: (a.pipeline.counters.estimated, a.ring.dropped,
                           a.pipeline.counters.errors, [str(p) for p in a.log.paths])
                  for a in self.arms}
        for name, (n, dropped, errors, paths) in totals.items():
            print(f"wrenchd: {name} stopped: {n} estimates, {dropped} dropped, {errors} errors; "
                  f"log {', '.join(paths) or '(none)'}", flush=True)
        self.arms = []
