"""Zenoh session set-up: one session per process, loopback peer by default.

Multicast scouting is off unless asked for, so a wrenchd on a hospital network never
announces itself or joins strangers' sessions by accident. Every session must be closed
explicitly (a callback subscriber left open keeps the interpreter from exiting).
"""

from __future__ import annotations

import json
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from models.errors import AdapterError


class ZenohConfig(BaseModel):
    """How this process joins the zenoh network."""

    model_config = ConfigDict(extra="forbid")

    mode: Literal["peer", "client", "router"] = Field(default="peer", description="zenoh mode")
    listen: list[str] = Field(default_factory=list,
                              description="endpoints to listen on, e.g. tcp/127.0.0.1:7447")
    connect: list[str] = Field(default_factory=list, description="endpoints to connect to")
    multicast_scouting: bool = Field(default=False, description="discover peers by multicast")

    def to_zenoh(self):
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast_scouting))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        return conf


def open_session(config: ZenohConfig):
    """Open a zenoh session; raises AdapterError with the endpoint when it cannot."""
    import zenoh

    try:
        return zenoh.open(config.to_zenoh())
    except Exception as exc:  # zenoh.ZError and friends
        raise AdapterError(f"cannot open zenoh session ({config.model_dump()}): {exc}") from exc
