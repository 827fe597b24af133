"""ZenohConfig: the reconnection settings reach zenoh, and a client waits for a late router
only when told to (a real router process on loopback)."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest
from pydantic import ValidationError

from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.models.errors import AdapterError
from tests.support import ROUTER, free_port, readline_within


def test_retry_and_timeout_settings_reach_zenoh():
    conf = ZenohConfig(mode="client", connect=["tcp/127.0.0.1:7447"], connect_timeout_ms=3000,
                       retry_period_init_ms=100, retry_period_max_ms=400).to_zenoh()
    connect = json.loads(conf.get_json("connect"))
    assert connect["timeout_ms"] == 3000
    assert connect["retry"] == {"period_init_ms": 100, "period_max_ms": 400,
                                "period_increase_factor": 2.0}
    assert json.loads(ZenohConfig().to_zenoh().get_json("connect"))["timeout_ms"] is None
    with pytest.raises(ValidationError, match="retry_period_max_ms"):
        ZenohConfig(retry_period_init_ms=2000, retry_period_max_ms=1000)


def test_a_client_fails_without_its_router_unless_it_may_wait():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with pytest.raises(AdapterError, match="cannot open zenoh session"):
        open_session(ZenohConfig(mode="client", connect=[endpoint]))

    started: list[subprocess.Popen] = []

    def late_router():
        started.append(subprocess.Popen([sys.executable, "-c", ROUTER, endpoint],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True))

    timer = threading.Timer(1.0, late_router)
    timer.start()
    t0 = time.monotonic()
    session = None
    try:
        session = open_session(ZenohConfig(mode="client", connect=[endpoint],
                                           connect_timeout_ms=20_000))
        waited = time.monotonic() - t0
    finally:
        timer.join()
        if session is not None:
            session.close()
        for router in started:
            readline_within(router, 30.0, "the router")
            router.stdin.close()
            router.wait(timeout=10)
    assert 1.0 <= waited < 20.0, waited
