"""The wrenchd daemon: zenoh in, two-step estimate + gate + lifelong adaptation, zenoh and MCAP out.

The daemon serves the estimated tip wrench [N, N m] of every arm it is given, at the rate of
the arm's joint states (up to 1 kHz), while the correction net keeps adapting, without letting
decoding, inference, logging or training delay one another. One zenoh session per daemon;
per arm:

* its joint states on ``measured_js``, queued inside zenoh by one subscriber for all arms
  (:class:`~wrenchd.service.runtime.intake.ChannelIntake`) or, with ``[ring] intake =
  "callback"``, stamped and put in a bounded ring by a callback per arm; either drops the
  oldest sample when full (``dropped``);
* the estimation thread (one for all arms) takes the queued samples through the arm's
  :class:`ArmPipeline` (decode -> validate -> estimate -> gate), publishes the wrench and
  events, and hands the records to the log writer process
  (:mod:`wrenchd.service.runtime.log_process`), which writes the arm's :class:`McapLog`;
* a queryable ``status`` (JSON), a liveliness token ``alive`` and, with the ``rmw_zenoh`` keys
  preset, the tokens and attachments of a ROS 2 node (:mod:`wrenchd.adapters.rmw_zenoh`).

One adaptation worker process serves all arms (:mod:`wrenchd.service.runtime.worker`). With
``robot = "simulated"`` the daemon also starts the simulated PSM (``wrenchd robot``). SIGINT
and SIGTERM stop it cleanly and within a bound (:meth:`Daemon.close`,
:mod:`~wrenchd.service.runtime.stopping`). Threads, processes and their reasons:
docs/architecture.md.
"""

from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path


from wrenchd.adapters.foxglove_live import open_live_view
from wrenchd.adapters.rmw_zenoh import node_token
from wrenchd.adapters.zenoh_io import open_session
from wrenchd.service.runtime.settings import ServiceSettings
from wrenchd.models.adaptation import normalisation_of
from wrenchd.service.pipeline import ArmPipeline, Event, EventKind
from wrenchd.service.runtime.log_process import LogWriterProcess
from wrenchd.service.runtime.scheduling import enter_realtime, normal_scheduling, realtime, realtime_below
from wrenchd.service.pipeline.step1 import Step1, load_step1
from wrenchd.service.runtime.arm import ROS_NODE_ID, ArmRuntime
from wrenchd.service.runtime.intake import ChannelIntake, channel_fits
from wrenchd.service.runtime import stopping
from wrenchd.service.runtime.plumbing import SWITCH_INTERVAL_S, Console, gather
from wrenchd.service.runtime.worker import WorkerProcess


LINK_CHECK_S = 0.5      # how often the session's routers and peers are counted [s]
TICK_S = 0.05           # with the channel intake: how often the estimation thread is woken
                        # when no sample comes (housekeeping, notices, the stop) [s]
BATCH = 32              # samples of one arm estimated before the next arm's turn
ROBOT_STOP_S = 3.0      # how long a simulated robot may take to end after SIGINT [s]
STOP_BOUND_S = 8.0      # the whole stop's bound: past it the daemon exits, saying what it waited for


def _say_killed(what: str, pid: int | None, when: str) -> None:
    """The line on stderr that says a child process did not end when asked and was killed."""
    print(f"wrenchd: warning: {what} (pid {pid}) had not ended {when}; killed it",
          file=sys.stderr, flush=True)


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
    """All arms of one daemon: their intake, the estimation thread, the worker and the logs."""

    def __init__(self, settings: ServiceSettings) -> None:
        self.settings = settings
        self.stop = threading.Event()
        self.wake = threading.Event()               # set by every arm's zenoh callback
        self.thread: threading.Thread | None = None
        self.session = None
        self.ros_node = None                        # the rmw_zenoh node token, if any arm needs it
        self.worker: WorkerProcess | None = None
        self.arms: list[ArmRuntime] = []
        self.robots: list[subprocess.Popen] = []
        self.log_writer: LogWriterProcess | None = None
        self.console: Console | None = None
        self.live = None                            # Foxglove live view ([foxglove] port)
        self.intake: ChannelIntake | None = None    # [ring] intake = "channel"
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
            # every thread the process has (NumPy's BLAS may have started some at import) and,
            # by inheritance, every thread and process made from here (the worker resets its
            # own when cpus.worker is set)
            for tid in os.listdir("/proc/self/task"):
                os.sched_setaffinity(int(tid), s.cpus.daemon)
        adapt = {a.name: a.pipeline.adaptation for a in s.arms
                 if a.pipeline.adaptation.enabled and a.pipeline.policy.name != "frozen"}
        loaded: dict[str, Step1] = {}                    # one copy of each distinct model
        for spec in {a.model for a in s.arms}:
            loaded[spec] = load_step1(spec)
            stopping.check()                    # a stop while starting ends the start
        self.step1 = {a.name: loaded[a.model] for a in s.arms}
        self.models = {name: step1.model for name, step1 in self.step1.items()}
        if s.robot != "simulated":
            for name, step1 in self.step1.items():
                if step1.origin == "simulator":
                    print(f"wrenchd: warning: {name} serves {step1.spec!r}, a step-1 model "
                          f"trained on the simulator, to a real arm; its forces are those of a "
                          f"simulated PSM (fit one to this arm: wrenchd fit)", file=sys.stderr,
                          flush=True)
        if adapt:
            frac = min(c.max_cpu_fraction for c in adapt.values())
            norms = {name: normalisation_of(self.models[name]) for name in adapt}
            self.worker = WorkerProcess(
                adapt, s.effective_models_dir(), frac, norms, cpus=s.cpus.worker,
                keep_checkpoints=s.keep_checkpoints,
                pinned_checkpoints={a.name: a.corr_checkpoint for a in s.arms
                                    if a.corr_checkpoint})
        # before the real-time window: the live view's server threads stay in the normal class
        self.live = open_live_view(s.foxglove)
        if self.realtime_priority is not None:
            # from here until the estimation thread is started, every thread made (zenoh's
            # runtime and callback threads, estimation) inherits the real-time class; the worker
            # was spawned before, and the robots are started after it is left
            realtime(self.realtime_priority)
        try:
            stopping.check()
            self.session = open_session(s.zenoh)
        except BaseException:
            normal_scheduling()
            raise
        try:
            if any(a.keys.preset == "rmw_zenoh" for a in s.arms):     # the node, before its
                self.ros_node = self.session.liveliness().declare_token(node_token(  # entities
                    s.ros.domain_id, str(self.session.info.zid()), ROS_NODE_ID, s.ros.node,
                    s.ros.namespace))
            channel = self._channel_intake()
            for cfg in s.arms:
                worker = self.worker if cfg.name in adapt else None
                self.arms.append(ArmRuntime(cfg, s, self.session, worker, self.wake,
                                            self.models[cfg.name], self.step1[cfg.name],
                                            subscribe=not channel))
            if channel:
                self.intake = ChannelIntake(
                    self.session, [arm.keys["measured_js"] for arm in self.arms],
                    s.ring.capacity * len(self.arms))
                for arm in self.arms:
                    arm.intake = self.intake
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
            arm.live = self.live.arm(arm.name, arm.cfg.frame_id) if self.live else None
        # Everything loaded so far (torch, models: ~260k objects) lives as long as the daemon.
        # Freezing it keeps the cyclic GC from scanning it: a full collection of it takes
        # 100-300 ms, a stall every estimate would wait through.
        gc.collect()
        gc.freeze()
        self.thread = threading.Thread(target=self._estimate, name="wrenchd-estimate",
                                       daemon=True)
        self.thread.start()
        for arm in self.arms:
            arm.estimation_tid = self.thread.native_id
        if self.realtime_priority is not None:
            # The log writer and the console take the GIL too: left in the normal class, one
            # preempted by other programs while holding it would hold up estimation with it.
            # One step below, they never preempt the sample path.
            for thread in (self.log_writer.thread, self.console.thread):
                realtime_below(self.realtime_priority, thread.native_id)
            normal_scheduling()
        stopping.check()
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
        if self.live is not None:
            print(f"wrenchd: Foxglove live view on {self.live.url}", flush=True)

    def _channel_intake(self) -> bool:
        """Whether the arms' joint states come through one channel (``[ring] intake``): asked
        for, and one key expression fits every arm's key (else the callback intake, said on
        stderr)."""
        s = self.settings
        if s.ring.intake != "channel":
            return False
        keys = [cfg.keys.resolve(s.prefix, cfg.name, s.ros.domain_id)["measured_js"]
                for cfg in s.arms]
        if not channel_fits(keys):
            print(f"wrenchd: the arms' joint-state keys {keys} are not exact keys that one key "
                  f"expression fits; taking them through a callback each ([ring] intake = "
                  f"\"callback\")", file=sys.stderr, flush=True)
            return False
        return True

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
        gather_s = self.settings.ring.gather_us / 1e6 if len(arms) > 1 else 0.0
        intake = self.intake
        while True:
            last_pass = self.stop.is_set()
            if intake is not None:                   # blocks until a sample or a tick
                taken = intake.take()
                if taken is None:
                    break
                last_pass = self.stop.is_set()        # the stop's tick: this pass is the last
            else:
                self.wake.wait(0.05)
                self.wake.clear()
                if gather_s > 0.0 and not last_pass:       # [ring] gather_us
                    gather([arm.ring for arm in arms], self.wake, gather_s, self.stop)
            for arm in arms:
                if arm.setup_inbox:               # before the samples that came after them
                    arm.handle_setup()
            if intake is not None:
                queued = list(zip(arms, taken))
            else:
                queued = [(arm, arm.ring.drain()) for arm in arms]
            depth = max((len(items) for _, items in queued), default=0)
            # arms take turns, at most BATCH samples each (samples that arrive meanwhile set
            # ``wake``); a backlog of one arm goes through its pipeline in one pass
            for k in range(0, depth, BATCH):
                groups: dict[int, list[tuple[ArmRuntime, list[tuple]]]] = {}
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
            if last_pass:
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
            arm._publish_events([Event(arm.event_time(), EventKind.ZENOH_LINK, {
                "arm": arm.name, "routers": links[0], "peers": links[1], "lost": lost})])

    @staticmethod
    def _handle_joint(group: list[tuple[ArmRuntime, list[tuple]]]) -> None:
        """Queued samples ``(arrival [ns], payload, zenoh encoding)`` of several arms sharing a
        step-1 model: their recurrences run as one batch
        (:meth:`ArmPipeline.process_many_joint`), the weights read once a step."""
        try:
            decoded = [[(arrived_ns, payload, msg, mark) for arrived_ns, payload, mark in chunk
                        if (msg := arm._decode(payload, mark)) is not None]
                       for arm, chunk in group]
            results = ArmPipeline.process_many_joint(
                [arm.pipeline for arm, _ in group], [[d[2] for d in dec] for dec in decoded])
        except Exception as exc:  # noqa: BLE001 - never let one batch kill the arms
            for arm, _ in group:
                arm.internal_error(exc)
            return
        for (arm, _), dec, res in zip(group, decoded, results):
            for (arrived_ns, payload, msg, mark), (est, events) in zip(dec, res):
                arm.emit_safe(arrived_ns, payload, msg, est, events, mark)

    def run(self, duration_s: float | None = None) -> int:
        """Start, serve until SIGINT/SIGTERM or ``duration_s``, stop cleanly. Returns 0, or
        :data:`~wrenchd.service.runtime.stopping.EXIT_STOP_HUNG` from a stop that did not
        finish within its bound (the watchdog's exit, said on stderr)."""
        with stopping.StopSignals() as signals:
            try:
                self.start()
                deadline = None if duration_s is None else time.monotonic() + duration_s
                # the channel intake's estimation thread sleeps in zenoh: woken here when idle
                wait_s = TICK_S if self.intake is not None else 0.2
                while not signals.wait(wait_s):
                    if self.intake is not None:
                        self.intake.tick()
                    if deadline is not None and time.monotonic() >= deadline:
                        break
            finally:
                signals.bound(STOP_BOUND_S)
                self.close()
        return 0

    def close(self) -> None:
        """Stop: subscribers are undeclared first (no callback runs after), the estimation
        thread finishes what is queued, the worker is asked to stop, the logs are finished, the
        worker and the robots are waited for, the session is closed. Every child ends by
        itself; one that has not within its bound is killed, and a line on stderr says so
        (``... killed it``). Under :meth:`run`, a stop that has not finished within
        ``STOP_BOUND_S`` says what it waited for and exits 3
        (:mod:`~wrenchd.service.runtime.stopping`)."""
        self.stop.set()
        for robot in self.robots:
            if robot.poll() is None:
                robot.send_signal(signal.SIGINT)
        for arm in self.arms:
            if arm.sub is None:              # the channel intake's, undeclared below
                continue
            try:
                arm.sub.undeclare()          # no callback after this point
            except Exception:  # noqa: BLE001
                pass
        self.wake.set()
        stopping.stage("the estimation thread to finish the queued samples")
        if self.intake is not None:
            self.intake.tick()                     # the thread takes what is queued and stops
        if self.thread is not None and self.thread.is_alive():
            self.thread.join(timeout=10.0)
        if self.intake is not None:                # no more samples after this point
            self.intake.close()
        for arm in self.arms:      # the final counters: even a run stopped in its first
            try:                   # second (no status yet) leaves a finished log
                arm.log_status()
            except Exception:  # noqa: BLE001 - closing must go on
                pass
        if self.worker is not None:                # asked now, waited for last: its exit
            self.worker.stop()                     # overlaps the logs' closing
        stopping.stage("the arms to close")
        for arm in self.arms:
            arm.close()
        if self.live is not None:                  # after the estimation thread stopped
            self.live.close()
            self.live = None
        if self.console is not None:
            self.console.close()
            self.console = None
        stopping.stage("the log writer to finish the files")
        if self.log_writer is not None:            # writes what is queued, finishes the files
            pid = self.log_writer.process.pid if self.log_writer.process else None
            if self.log_writer.close():
                _say_killed("the log writer process", pid, "when asked to finish its files")
            self.log_writer = None
        else:
            for arm in self.arms:
                arm.log.close()
        stopping.stage("the adaptation worker to end")
        if self.worker is not None and self.worker.close():
            _say_killed("the adaptation worker", self.worker.process.pid,
                        "after its stop message")
        stopping.stage("the simulated robot to end")
        for robot in self.robots:
            try:
                robot.wait(timeout=ROBOT_STOP_S)
            except subprocess.TimeoutExpired:
                robot.kill()
                robot.wait()
                _say_killed("the simulated robot", robot.pid,
                            f"{ROBOT_STOP_S:g} s after SIGINT")
        if self.ros_node is not None:
            try:
                self.ros_node.undeclare()
            except Exception:  # noqa: BLE001 - closing must go on
                pass
            self.ros_node = None
        stopping.stage("the zenoh session to close")
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
