"""One arm of the daemon: its subscriber's ring, pipeline, publishers, status and log."""

from __future__ import annotations

import sys
import threading
import time
from collections import deque
from typing import Any

import numpy as np

from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, TOPIC_EVENTS, TOPIC_STATUS, McapLog
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.messages import (JOINT_STATE_TYPE, WRENCH_TYPE, decode_joint_state,
                                      decode_setup_change, encode_wrench, prepare_encoding)
from wrenchd.adapters.rmw_zenoh import PUBLISHER, SUBSCRIPTION, Stamper, endpoint
from wrenchd.adapters.ros2_msgs import is_cdr
from wrenchd.adapters.zenoh_io import sample_mark, wire_encoding, zenoh_encoding
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.compiled import kernels_in_use
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.runtime.settings import ArmConfig, ServiceSettings
from wrenchd.service.runtime.scheduling import thread_scheduling
from wrenchd.service.pipeline import ArmPipeline, Estimate, Event, EventKind
from wrenchd.service.runtime.log_process import LogWriterProcess
from wrenchd.service.pipeline.step1 import Step1
from wrenchd.service.runtime.plumbing import Console, SampleRing, event_bytes, percentiles
from wrenchd.service.runtime.worker import ProcessAdaptation, WorkerProcess

SETUP_INBOX = 64        # set-up change notices waiting at most per arm (the oldest go)
#: the daemon's node id in the ROS graph (rmw_zenoh); arm i's subscription and publisher are
#: the node's entities 1 + 2 i and 2 + 2 i
ROS_NODE_ID = 0


def estimate_payload(est: Estimate, frame_id: str = "psm_base") -> tuple[str, tuple]:
    """The ``/wrenchd/estimate`` log record of one estimate, as plain values for the log
    writer (:func:`wrenchd.adapters.mcap_log.format_record` makes the bytes)."""
    return ("estimate", (est.stamp_ns, frame_id, est.wrench.tolist(), bool(est.free),
                         float(est.score), int(est.model_version), bool(est.restarted),
                         est.external_torque.tolist()))


def joint_state_payload(payload: bytes, msg, encoding: str) -> bytes | tuple[str, tuple]:
    """The ``/joint_states`` log record of an estimated input ``payload`` (decoded: ``msg``,
    a :class:`~wrenchd.models.series.JointSample`; received in ``encoding``): one with its six
    names as received (JSON is made into the message by the log writer, little-endian CDR is
    that message already), anything else re-encoded there, with the default names."""
    if len(msg.name) == len(JOINT_NAMES) and (encoding == "json" or is_cdr(payload)):
        return payload
    names = msg.name if len(msg.name) == len(JOINT_NAMES) else JOINT_NAMES
    return ("joint_state", (msg.stamp_ns, list(names), msg.position.tolist(),
                            msg.velocity.tolist(), msg.effort.tolist(), msg.frame_id))


class ArmRuntime:
    """One arm's subscriber, ring, estimation thread, publishers, queryable, token and log."""

    def __init__(self, cfg: ArmConfig, settings: ServiceSettings, session,
                 worker: WorkerProcess | None, wake: threading.Event,
                 free_space: FreeSpaceModel, step1: Step1 | None = None,
                 subscribe: bool = True) -> None:
        self.cfg, self.settings = cfg, settings
        self.step1 = step1
        self.name = cfg.name
        self.keys = cfg.keys.resolve(settings.prefix, cfg.name, settings.ros.domain_id)
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
            "keys": self.keys, "step1": step1.to_json() if step1 is not None else None})
        self.log_writer: LogWriterProcess | None = None    # set by the daemon before start()
        self.console: Console | None = None                 # likewise
        self.realtime_priority: int | None = None           # likewise: the sample path's
        self.estimation_tid: int | None = None              # likewise, once it runs
        self.zenoh_links: dict[str, int] = {"routers": 0, "peers": 0, "link_losses": 0}
        self.live = None        # Foxglove live view (adapters/foxglove_live.ArmLiveView), set by the daemon
        self._log_problem_reported = False
        self._json = zenoh_encoding("json")
        self.pub_wrench = session.declare_publisher(self.keys["wrench"],
                                                    encoding=zenoh_encoding(cfg.encoding),
                                                    express=cfg.express)
        self.pub_events = session.declare_publisher(self.keys["events"], encoding=self._json)
        self.queryable = session.declare_queryable(self.keys["status"], self._on_query)
        self.token = session.liveliness().declare_token(self.keys["alive"])
        self.ros_tokens, self.stamper = self._ros_endpoints(session)
        # set-up changes (JSON, any encoding): a few at most, handled on the estimation thread
        self.setup_inbox: deque[bytes] = deque(maxlen=SETUP_INBOX)
        self.setup_dropped = 0          # notices pushed out of a full inbox (counted, reported)
        self._wake = wake
        self.sub_setup = session.declare_subscriber(self.keys["setup"], self._on_setup)
        # its own subscriber (callback intake), or the daemon's channel serves it (``intake``)
        self.sub = (session.declare_subscriber(self.keys["measured_js"], self._on_sample)
                    if subscribe else None)
        self.intake = None                  # the daemon's ChannelIntake, set by the daemon
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

    def _ros_endpoints(self, session) -> tuple[list, Stamper | None]:
        """With the ``rmw_zenoh`` keys preset: the liveliness tokens of this arm's subscription
        and wrench publisher as entities of the daemon's ROS node, and the stamper of the
        wrenches' attachments (:mod:`wrenchd.adapters.rmw_zenoh`); else none."""
        if self.cfg.keys.preset != "rmw_zenoh":
            return [], None
        ros, i = self.settings.ros, [a.name for a in self.settings.arms].index(self.name)
        zid = str(session.info.zid())
        topics = self.cfg.keys.topics(self.settings.prefix, self.name)
        sub = endpoint(SUBSCRIPTION, ros.domain_id, zid, ROS_NODE_ID, 1 + 2 * i, ros.node,
                       topics["measured_js"], JOINT_STATE_TYPE, ros.namespace)
        pub = endpoint(PUBLISHER, ros.domain_id, zid, ROS_NODE_ID, 2 + 2 * i, ros.node,
                       topics["wrench"], WRENCH_TYPE, ros.namespace)
        liveliness = session.liveliness()
        return [liveliness.declare_token(e.token) for e in (sub, pub)], Stamper(pub.gid)

    def event_time(self) -> float:
        """The time [s] of an event no sample carries (a refused payload, a link change, a log
        error): the arm's latest estimated sample's stamp; the wall clock before the first."""
        return self.last.t if self.last is not None else time.time()

    # -- zenoh callbacks (zenoh's threads): keep them trivial ----------------------------
    def _on_sample(self, sample) -> None:
        self.ring.put((time.perf_counter_ns(), sample.payload.to_bytes(), sample_mark(sample)))

    def _on_setup(self, sample) -> None:
        if len(self.setup_inbox) == SETUP_INBOX:
            self.setup_dropped += 1
        self.setup_inbox.append(sample.payload.to_bytes())
        self._wake.set()

    def _on_query(self, query) -> None:
        try:
            query.reply(self.keys["status"], event_bytes(self.status()), encoding=self._json)
        except Exception as exc:  # noqa: BLE001 - a query must never kill the daemon
            print(f"wrenchd: status query failed: {exc}", file=sys.stderr)

    def status(self) -> dict[str, Any]:
        s = self.pipeline.status()
        if self.step1 is not None:                 # what step 1 is, and where it came from
            s["model"].update(self.step1.to_json())
            if self.step1.origin == "simulator" and self.settings.robot != "simulated":
                s["model"]["warning"] = "a simulator-trained step 1 serves a real arm"
        s["model"]["kernels"] = kernels_in_use()    # numba (compiled) or numpy
        s["counters"]["dropped"] = self.ring.dropped if self.intake is None else self.intake.full
        s["intake"] = ({"mode": "callback"} if self.intake is None else
                       {"mode": "channel", "key": self.intake.pattern,
                        "full": self.intake.full, "foreign": self.intake.foreign})
        s["counters"]["setup_dropped"] = self.setup_dropped
        s["rate_hz"] = self.rate_hz
        s["latency_us"] = percentiles(list(self.latency_us))
        s["encoding"] = self.cfg.encoding
        s["realtime_priority"] = self.realtime_priority
        if self.estimation_tid is not None:         # what the kernel gives the sample path
            s["scheduling"] = thread_scheduling(self.estimation_tid)
        s["zenoh"] = dict(self.zenoh_links)
        s["keys"] = self.keys
        log = self.log
        s["log"] = {"path": str(log.path) if log.path else None,
                    "written": log.written, "lost": log.lost, "problem": log.problem,
                    # the directory's log files (all arms') and its file system's free space
                    "directory": log.config.directory, "bytes_used": log.bytes_used,
                    "bytes_free": log.bytes_free, "max_total_bytes": log.config.max_total_bytes,
                    "removed_files": log.removed_files, "removed_bytes": log.removed_bytes}
        s["adaptation_worker_alive"] = (self.pipeline.backend.worker.alive
                                        if isinstance(self.pipeline.backend, ProcessAdaptation)
                                        else None)
        return s

    # -- on the estimation thread --------------------------------------------------------
    def _publish_events(self, events: list[Event]) -> None:
        for ev in events:
            payload = event_bytes(ev.to_json())
            self.pub_events.put(payload)
            self._log(TOPIC_EVENTS, max(int(ev.t * 1e9), 0), payload)
        if self.live is not None:                 # live view: never raises, never blocks
            self.live.events(events)

    def _log(self, topic: str, stamp_ns: int, payload) -> None:
        """Hand a record (bytes, or a formatter's name and arguments) to the log writer."""
        self.log_writer.put(self.log, topic, stamp_ns, payload)

    def _decode(self, payload: bytes, mark: str | None = None):
        """The decoded joint state (in the encoding the sample is marked with, else the arm's),
        or None after publishing the refusal's error event."""
        try:
            return decode_joint_state(wire_encoding(mark, self.cfg.encoding), payload)
        except DataError as exc:
            self._publish_refusal(self.pipeline.reject(self.event_time(), "decode", str(exc)),
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
                self._publish_refusal(self.pipeline.refuse_setup(self.event_time(), str(exc)),
                                      payload)
                continue
            try:
                events = self.pipeline.setup_change(
                    None if stamp_ns is None else stamp_ns / 1e9, detail)
            except Exception as exc:  # noqa: BLE001 - never let a notice kill the arm
                self.internal_error(exc)
                continue
            self._publish_events(events)

    def handle(self, arrived_ns: int, payload: bytes, mark: str | None = None) -> None:
        """One payload through decode -> pipeline -> publish -> log."""
        msg = self._decode(payload, mark)
        if msg is not None:
            self._emit(arrived_ns, payload, msg, *self.pipeline.process(msg), mark=mark)

    def handle_many(self, items: list[tuple[int, bytes, str | None]]) -> None:
        """Queued payloads of this arm, in order: a backlog goes through the pipeline in one
        pass (:meth:`ArmPipeline.process_many`); each wrench is published as soon as its
        batch is estimated."""
        if len(items) < ArmPipeline.BATCH_MIN:
            for arrived_ns, payload, mark in items:
                self.handle_safe(arrived_ns, payload, mark)
            return
        try:
            decoded = [(arrived_ns, payload, self._decode(payload, mark), mark)
                       for arrived_ns, payload, mark in items]
            decoded = [d for d in decoded if d[2] is not None]
            results = self.pipeline.process_many([d[2] for d in decoded])
        except Exception as exc:  # noqa: BLE001 - never let one batch kill the arm
            self.internal_error(exc)
            return
        for (arrived_ns, payload, msg, mark), (est, events) in zip(decoded, results):
            self.emit_safe(arrived_ns, payload, msg, est, events, mark)

    def internal_error(self, exc: Exception) -> None:
        """A bug met on this arm's path: a counted ``internal`` error event, never a crash."""
        ev = self.pipeline.reject(self.event_time(), "internal", f"{type(exc).__name__}: {exc}")
        self._publish_events([ev])

    def emit_safe(self, arrived_ns: int, payload: bytes, msg, est: Estimate | None,
                  events: list[Event], mark: str | None = None) -> None:
        try:
            self._emit(arrived_ns, payload, msg, est, events, mark)
        except Exception as exc:  # noqa: BLE001 - never let one sample kill the arm
            self.internal_error(exc)

    def _emit(self, arrived_ns: int, payload: bytes, msg, est: Estimate | None,
              events: list[Event], mark: str | None = None) -> None:
        """Publish and log one sample's outcome (``mark``: the sample's zenoh encoding)."""
        enc = self.cfg.encoding
        if est is not None:
            extra = ({"free": est.free, "model_version": est.model_version,
                      "score": min(est.score, 1e9)} if enc == "json" else None)
            wrench = encode_wrench(enc, est.stamp_ns, est.wrench, self.cfg.frame_id, extra)
            if self.stamper is None:
                self.pub_wrench.put(wrench)
            else:                                   # rmw_zenoh: every sample has its attachment
                self.pub_wrench.put(wrench, attachment=self.stamper.next())
            self.latency_us.append((time.perf_counter_ns() - arrived_ns) / 1e3)
            self.last = est
            # formatting and writing happen in the log writer process
            self._log(TOPIC_JOINT_STATES, est.stamp_ns,
                      joint_state_payload(payload, msg, wire_encoding(mark, enc)))
            self._log(TOPIC_ESTIMATE, est.stamp_ns, estimate_payload(est, self.cfg.frame_id))
            if self.live is not None:             # live view: decimated, never raises
                self.live.estimate(est)
        if events:
            self._publish_events(events)

    def handle_safe(self, arrived_ns: int, payload: bytes, mark: str | None = None) -> None:
        """:meth:`handle`, turning any exception into a counted ``internal`` error event."""
        try:
            self.handle(arrived_ns, payload, mark)
        except Exception as exc:  # noqa: BLE001 - never let one sample kill the arm
            self.internal_error(exc)

    def log_status(self) -> dict[str, Any]:
        """The status now, handed to the log writer; returned."""
        status = self.status()
        stamp = self.last.stamp_ns if self.last is not None else 0
        self._log(TOPIC_STATUS, stamp, event_bytes(status))
        return status

    def housekeeping(self, now: float) -> None:
        """Once in a while: rate, status snapshot to the log and console, log problems and
        the files the disk budget removed."""
        if now >= self._next_status:
            est = self.pipeline.counters.estimated
            self.rate_hz = (est - self._count_at) / max(now - self._count_t, 1e-9)
            self._count_at, self._count_t = est, now
            self._next_status = now + self.settings.status_interval_s
            status = self.log_status()
            if self.live is not None:             # live view: never raises
                self.live.status(status)
            self._console(status)
        if self.log.problem and not self._log_problem_reported:
            self._log_problem_reported = True
            self._publish_events([Event(self.event_time(), EventKind.LOG_ERROR,
                                        {"arm": self.name, "error": self.log.problem})])
        elif self.log.problem is None:                # a fresh file is open again
            self._log_problem_reported = False
        if self.log.removed:                          # what the disk budget did
            self._publish_events(self._budget_events())

    def _budget_events(self) -> list[Event]:
        """An event per notice of the log's disk budget: ``log_removed`` (path, bytes) for a
        file it removed, ``log_error`` for one it could not."""
        events, t = [], self.event_time()
        while self.log.removed:
            what, path, detail = self.log.removed.popleft()
            if what == "removed":
                events.append(Event(t, EventKind.LOG_REMOVED, {"arm": self.name, "path": path,
                                                       "bytes": detail}))
            else:
                events.append(Event(t, EventKind.LOG_ERROR, {"arm": self.name, "error": detail}))
        return events

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
        for entity in (self.sub, self.sub_setup, self.queryable, self.token, *self.ros_tokens,
                       self.pub_wrench, self.pub_events):
            if entity is None:
                continue
            try:
                entity.undeclare()
            except Exception:  # noqa: BLE001 - closing must go on
                pass
        self.pipeline.close()
