"""The daemon's live view in Foxglove: a Foxglove SDK WebSocket server on the daemon.

``wrenchd serve --foxglove-port PORT`` (or ``[foxglove] port``) starts the SDK's WebSocket
server on ``host`` (loopback by default) and advertises, per arm (``{arm}`` is its name):

* ``/{arm}/wrenchd/wrench``, JSON ``wrenchd.Wrench`` at ``rate_hz``: ``timestamp``
  {sec, nsec} (the sample's stamp), ``frame_id``, ``force`` {x,y,z} [N], ``torque``
  {x,y,z} [N m];
* ``/{arm}/wrenchd/external_torque``, ``foxglove.JointStates`` (protobuf) at ``rate_hz``: one
  joint per PSM joint, ``effort`` = external torque [N m; N on the insertion joint];
* ``/{arm}/wrenchd/gate``, JSON ``wrenchd.Gate`` at ``rate_hz`` and at every change of the
  verdict: ``state`` free|contact, ``contact``, ``score``, ``model_version``;
* ``/{arm}/wrenchd/status``, JSON ``wrenchd.Status``: the arm's status snapshot (as the zenoh
  status queryable answers), every status interval;
* ``/{arm}/wrenchd/events``, ``foxglove.Log`` (protobuf): every event, errors at level ERROR.

The view lets a person watch an arm's estimate as it is made, plotted in Foxglove; it never
holds up estimation (:class:`ArmLiveView` says how). The SDK
(``foxglove-sdk``, import name ``foxglove``) is imported only when a view is started, so the
daemon runs without it when no port is given. ``deploy/foxglove/wrenchd-layout.json`` is a
Foxglove layout of these topics for the arm ``PSM1`` (set-up: ``docs/deployment.md``, "Live
view in Foxglove").
"""

from __future__ import annotations

import math
import sys
from typing import Any, Iterable

import orjson
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.adapters.ros2_msgs import split_ns
from wrenchd.models.errors import AdapterError
from wrenchd.models.series import JOINT_NAMES

#: the topics of one arm (``str.format`` templates of ``arm``)
TOPICS: dict[str, str] = {
    "wrench": "/{arm}/wrenchd/wrench",
    "external_torque": "/{arm}/wrenchd/external_torque",
    "gate": "/{arm}/wrenchd/gate",
    "status": "/{arm}/wrenchd/status",
    "events": "/{arm}/wrenchd/events",
}

_DRAFT = "https://json-schema.org/draft/2020-12/schema"
_TIME = {"type": "object", "description": "sample stamp",
         "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}


def _vector(unit: str) -> dict[str, Any]:
    return {"type": "object", "description": f"[{unit}]",
            "properties": {a: {"type": "number"} for a in "xyz"}}


WRENCH_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT, "title": "wrenchd.Wrench", "type": "object",
    "description": "Estimated tip wrench: force in the frame's axes [N], torque about the tip "
                   "[N m].",
    "properties": {"timestamp": _TIME, "frame_id": {"type": "string"},
                   "force": _vector("N"), "torque": _vector("N m")},
}
GATE_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT, "title": "wrenchd.Gate", "type": "object",
    "description": "The free-motion gate's verdict on the latest sample and the model serving.",
    "properties": {"timestamp": _TIME,
                   "state": {"type": "string", "enum": ["free", "contact"]},
                   "contact": {"type": "boolean"},
                   "score": {"type": ["number", "null"],
                             "description": "peak score: largest per-joint |residual| / scale "
                                            "[scale units]; a contact starts above "
                                            "[gate] enter_sigma"},
                   "model_version": {"type": "integer"}},
}
STATUS_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT, "title": "wrenchd.Status", "type": "object",
    "description": "The daemon's status snapshot of one arm (as the zenoh status queryable).",
    "properties": {"arm": {"type": "string"}, "model": {"type": "object"},
                   "rate_hz": {"type": "number"}, "counters": {"type": "object"},
                   "gate": {"type": "object"}, "latency_us": {"type": "object"}},
}

_JSON_OPTIONS = orjson.OPT_SERIALIZE_NUMPY | orjson.OPT_NON_STR_KEYS


class FoxgloveConfig(BaseModel):
    """``[foxglove]``: the live view's WebSocket server (off unless ``port`` is set)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    port: int | None = Field(default=None, ge=0, le=65535,
                             description="WebSocket port (0: any free one); unset: no live view")
    host: str = Field(default="127.0.0.1", min_length=1,
                      description="address to bind (loopback: this machine only)")
    rate_hz: float = Field(default=100.0, gt=0.0, le=10000.0,
                           description="wrench, torque and gate messages per second at most")


def _stamp(stamp_ns: int) -> dict[str, int]:
    sec, nsec = split_ns(stamp_ns)
    return {"sec": sec, "nsec": nsec}


class LiveView:
    """One Foxglove WebSocket server and its channels (one :class:`ArmLiveView` per arm).

    The server speaks the subprotocol ``foxglove.sdk.v1`` (the Foxglove WebSocket protocol v1
    under its new name); clients that offer only ``foxglove.websocket.v1`` are refused by the
    SDK.
    """

    def __init__(self, config: FoxgloveConfig, name: str = "wrenchd") -> None:
        if config.port is None:
            raise AdapterError("the Foxglove live view needs a port ([foxglove] port)")
        try:
            import foxglove
        except ImportError as exc:
            raise AdapterError("the Foxglove live view needs the foxglove-sdk package "
                               f"(pip install foxglove-sdk): {exc}") from exc
        self.config = config
        self._foxglove = foxglove
        self.context = foxglove.Context()      # this view's channels only
        try:
            self.server = foxglove.start_server(name=name, host=config.host,
                                                port=config.port, context=self.context)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types
            raise AdapterError(f"cannot start the Foxglove server on {config.host}:"
                               f"{config.port}: {exc}") from exc
        self.arms: list[ArmLiveView] = []

    @property
    def port(self) -> int:
        """The port the server listens on (the one chosen when ``port`` was 0)."""
        return int(self.server.port)

    @property
    def url(self) -> str:
        return f"ws://{self.config.host}:{self.port}"

    def arm(self, name: str, frame_id: str = "psm_base") -> ArmLiveView:
        """The channels of one arm."""
        view = ArmLiveView(self, name, frame_id)
        self.arms.append(view)
        return view

    def close(self) -> None:
        """Close the channels and stop the server (never raises)."""
        for view in self.arms:
            view.close()
        try:
            self.server.stop()
        except Exception as exc:  # noqa: BLE001 - stopping must go on
            print(f"wrenchd: stopping the Foxglove server: {exc}", file=sys.stderr)


def open_live_view(config: FoxgloveConfig) -> LiveView | None:
    """The live view of ``config``, or None when no port is set."""
    return None if config.port is None else LiveView(config)


class ArmLiveView:
    """One arm's channels; its methods are called on the estimation thread and never raise.

    The view never holds up estimation: the SDK's log calls only queue the message for each
    subscribed client (a slow client loses its oldest messages, never blocks the caller);
    wrenches, torques and gate are decimated to ``rate_hz`` by their sample stamps; nothing is
    encoded for a channel no client subscribes to; and any failure of the view is counted and
    said once on stderr, never raised into the estimation thread.

    Args:
        view: the server.
        arm: arm name (topics).
        frame_id: frame of the arm's wrench.
    """

    def __init__(self, view: LiveView, arm: str, frame_id: str) -> None:
        fg = view._foxglove
        from foxglove.channels import JointStatesChannel, LogChannel
        from foxglove.messages import JointState, JointStates, Log, LogLevel, Timestamp

        ctx = view.context
        self.arm, self.frame_id = arm, frame_id
        self.topics = {k: v.format(arm=arm) for k, v in TOPICS.items()}
        self._wrench = fg.Channel(self.topics["wrench"], schema=WRENCH_SCHEMA, context=ctx)
        self._torque = JointStatesChannel(self.topics["external_torque"], context=ctx)
        self._gate = fg.Channel(self.topics["gate"], schema=GATE_SCHEMA, context=ctx)
        self._status = fg.Channel(self.topics["status"], schema=STATUS_SCHEMA, context=ctx)
        self._events = LogChannel(self.topics["events"], context=ctx)
        self._JointState, self._JointStates, self._Log = JointState, JointStates, Log
        self._Timestamp, self._LogLevel = Timestamp, LogLevel
        self.period_ns = int(round(1e9 / view.config.rate_hz))
        self._next_ns: int | None = None        # stamp from which the next sample is shown
        self._free: bool | None = None          # the gate's state last shown
        self.published = 0                      # samples shown (wrench channel)
        self.failures = 0                       # calls that failed (said once on stderr)
        self._said = False

    # -- called by the daemon --------------------------------------------------------------
    def estimate(self, est) -> None:
        """One estimate (:class:`wrenchd.service.pipeline.Estimate`): shown when at least
        ``1/rate_hz`` of sample time passed since the last one shown (a stamp going back by
        more than that restarts the clock), or when the gate's verdict changed."""
        try:
            stamp = est.stamp_ns
            nxt = self._next_ns
            due = nxt is None or stamp >= nxt or stamp < nxt - 2 * self.period_ns
            changed = bool(est.free) != self._free
            if not (due or changed):
                return
            if due:
                self._next_ns = stamp + self.period_ns
                self.published += 1
                if self._wrench.has_sinks():
                    w = est.wrench
                    self._wrench.log(orjson.dumps({
                        "timestamp": _stamp(stamp), "frame_id": self.frame_id,
                        "force": {"x": w[0], "y": w[1], "z": w[2]},
                        "torque": {"x": w[3], "y": w[4], "z": w[5]}}, option=_JSON_OPTIONS))
                if self._torque.has_sinks():
                    self._torque.log(self._joint_states(stamp, est.external_torque))
            self._free = bool(est.free)
            if self._gate.has_sinks():
                score = float(est.score)
                self._gate.log(orjson.dumps({
                    "timestamp": _stamp(stamp), "state": "free" if est.free else "contact",
                    "contact": not est.free, "score": score if math.isfinite(score) else None,
                    "model_version": int(est.model_version)}))
        except Exception as exc:  # noqa: BLE001 - the view must never stop estimation
            self._failed(exc)

    def events(self, events: Iterable) -> None:
        """Events (:class:`wrenchd.service.pipeline.Event`) as ``foxglove.Log`` messages."""
        try:
            if not self._events.has_sinks():
                return
            for ev in events:
                detail = orjson.dumps(ev.detail, default=str, option=_JSON_OPTIONS).decode()
                level = self._LogLevel.Error if ev.kind == "error" else self._LogLevel.Info
                t = ev.t if math.isfinite(ev.t) and ev.t >= 0 else 0.0
                self._events.log(self._Log(timestamp=self._Timestamp.from_epoch_secs(t),
                                           level=level, message=f"{ev.kind} {detail}",
                                           name=f"wrenchd.{self.arm}"))
        except Exception as exc:  # noqa: BLE001
            self._failed(exc)

    def status(self, status: dict[str, Any]) -> None:
        """The arm's status snapshot (a JSON-able dict; NumPy values are written natively,
        anything else as its text)."""
        try:
            if self._status.has_sinks():
                self._status.log(orjson.dumps(status, default=str, option=_JSON_OPTIONS))
        except Exception as exc:  # noqa: BLE001
            self._failed(exc)

    def close(self) -> None:
        for channel in (self._wrench, self._torque, self._gate, self._status, self._events):
            try:
                channel.close()
            except Exception:  # noqa: BLE001 - closing must go on
                pass

    # -- helpers ---------------------------------------------------------------------------
    def _joint_states(self, stamp_ns: int, torque) -> Any:
        sec, nsec = split_ns(stamp_ns)
        joints = [self._JointState(name=name, effort=float(value))
                  for name, value in zip(JOINT_NAMES, torque)]
        return self._JointStates(timestamp=self._Timestamp(sec, nsec), joints=joints)

    def _failed(self, exc: Exception) -> None:
        self.failures += 1
        if not self._said:
            self._said = True
            print(f"wrenchd: Foxglove live view of {self.arm} failed ({type(exc).__name__}: "
                  f"{exc}); estimation goes on, the view may miss messages", file=sys.stderr,
                  flush=True)
