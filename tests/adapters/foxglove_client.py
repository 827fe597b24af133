"""A minimal Foxglove WebSocket protocol client for tests, on the ``websockets`` package's
synchronous client; every wait has a deadline.

The Foxglove SDK's server (foxglove-sdk 0.30) accepts the subprotocol ``foxglove.sdk.v1`` (and
``foxglove.sdk.v1.1``) and refuses a client offering only the older name
``foxglove.websocket.v1`` (HTTP 400); ``foxglove.sdk.v1`` is the ws-protocol's v1 under a new
name. The client offers both, as Foxglove's own app does, and the server picks
``foxglove.sdk.v1``.

The protocol (https://github.com/foxglove/ws-protocol, ``docs/spec.md``): the server sends
JSON text messages (``serverInfo``, ``advertise`` with the channels, ...); a client subscribes
with ``{"op": "subscribe", "subscriptions": [{"id", "channelId"}]}``; the server then sends
binary ``Message Data`` frames: opcode 1 (u8), subscription id (u32 LE), log time [ns]
(u64 LE), the message payload.
"""

from __future__ import annotations

import json
import struct
import time
from contextlib import ExitStack
from dataclasses import dataclass, field

from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"
LEGACY_SUBPROTOCOL = "foxglove.websocket.v1"
MESSAGE_DATA = 1          # binary opcode of a message data frame
_HEADER = struct.Struct("<BIQ")


@dataclass
class Frame:
    topic: str
    log_time_ns: int
    payload: bytes


@dataclass
class FoxgloveClient:
    """One connection: what the server said, its channels by topic, the frames received."""

    url: str
    server_info: dict | None = None
    channels: dict[str, dict] = field(default_factory=dict)
    frames: list[Frame] = field(default_factory=list)
    others: list[str] = field(default_factory=list)      # other text ops seen

    def __post_init__(self) -> None:
        self._stack = ExitStack()
        self.ws = self._stack.enter_context(connect(
            self.url, subprotocols=[SUBPROTOCOL, LEGACY_SUBPROTOCOL], open_timeout=10,
            proxy=None, max_size=None))
        assert self.ws.subprotocol == SUBPROTOCOL, self.ws.subprotocol
        self._subscriptions: dict[int, str] = {}

    def close(self) -> None:
        self._stack.close()

    def _receive(self, timeout: float) -> bool:
        """Handle one message from the server; False when none came within ``timeout``."""
        try:
            msg = self.ws.recv(timeout=max(timeout, 0.0))
        except TimeoutError:
            return False
        if isinstance(msg, str):
            body = json.loads(msg)
            op = body.get("op")
            if op == "serverInfo":
                self.server_info = body
            elif op == "advertise":
                for ch in body["channels"]:
                    self.channels[ch["topic"]] = ch
            elif op == "unadvertise":
                gone = set(body["channelIds"])
                self.channels = {t: c for t, c in self.channels.items() if c["id"] not in gone}
            else:
                self.others.append(op)
            return True
        if msg and msg[0] == MESSAGE_DATA:
            _, sub_id, log_time = _HEADER.unpack_from(msg)
            self.frames.append(Frame(self._subscriptions[sub_id], log_time,
                                     bytes(msg[_HEADER.size:])))
        return True

    def wait_for_channels(self, topics: set[str], timeout: float) -> None:
        """Read until ``serverInfo`` and every topic of ``topics`` are advertised."""
        deadline = time.monotonic() + timeout
        while self.server_info is None or not topics <= set(self.channels):
            if not self._receive(deadline - time.monotonic()) and time.monotonic() >= deadline:
                raise AssertionError(f"within {timeout} s: serverInfo {self.server_info is not None}"
                                     f", advertised {sorted(self.channels)}, wanted "
                                     f"{sorted(topics)}")

    def subscribe(self, topics: list[str]) -> None:
        subs = []
        for topic in topics:
            sub_id = len(self._subscriptions) + 1
            self._subscriptions[sub_id] = topic
            subs.append({"id": sub_id, "channelId": self.channels[topic]["id"]})
        self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def collect_until(self, done, timeout: float, what: str) -> None:
        """Receive until ``done(self)`` is true; AssertionError naming ``what`` after
        ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while not done(self):
            left = deadline - time.monotonic()
            if left <= 0:
                counts = {}
                for f in self.frames:
                    counts[f.topic] = counts.get(f.topic, 0) + 1
                raise AssertionError(f"timed out after {timeout} s waiting for {what}; "
                                     f"frames by topic: {counts}")
            self._receive(min(left, 0.5))

    def drain(self, quiet_s: float, timeout: float = 10.0) -> None:
        """Receive until nothing came for ``quiet_s`` (at most ``timeout`` s in all)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and self._receive(quiet_s):
            pass

    def payloads(self, topic: str) -> list[Frame]:
        return [f for f in self.frames if f.topic == topic]
