"""The latency floor of ``wrenchd bench service`` on this machine (``wrenchd bench floor``).

A stand-in for the daemon with the daemon's plumbing and none of its work: the daemon's
intake (one :class:`~wrenchd.service.runtime.intake.ChannelIntake` for all arms, or with
``--intake callback`` per arm a subscriber whose callback puts the payload in a
:class:`~wrenchd.service.runtime.plumbing.SampleRing`), one thread that takes the samples,
reads each joint state's stamp and publishes a zero wrench with that stamp, in the arms'
encoding (``--encoding``: JSON or CDR). What ``bench
service`` measures against it is what zenoh on loopback, the hand-off to the thread, the GIL
and this machine's scheduling cost before any estimation: the part of the daemon's latency
that no faster estimator can remove.

Run by the bench as ``python -m wrenchd.service.bench.floor --listen ENDPOINT --arms PSM1 ...
--realtime SETTING``: in the scheduling class the daemon would take, as the daemon does, from
before its session opens.
"""

from __future__ import annotations

import argparse
import sys
import threading

import numpy as np
import orjson

from wrenchd.adapters import cdr_wire
from wrenchd.adapters.messages import encode_wrench
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.service.cli.bench import realtime_setting
from wrenchd.service.runtime.intake import ChannelIntake
from wrenchd.service.runtime.stopping import StopSignals
from wrenchd.service.runtime.plumbing import SWITCH_INTERVAL_S, SampleRing
from wrenchd.service.runtime.scheduling import enter_realtime
from wrenchd.service.runtime.settings import ArmConfig

_ZERO = np.zeros(6)


def _json_stamp(payload: bytes) -> int | None:
    try:
        stamp = orjson.loads(payload)["header"]["stamp"]
        return stamp["sec"] * 1_000_000_000 + stamp["nanosec"]
    except (orjson.JSONDecodeError, KeyError, TypeError):
        return None


_STAMP_OF = {"json": _json_stamp, "cdr": cdr_wire.read_stamp}


def _answer(pub, items, encoding: str) -> None:
    stamp_of = _STAMP_OF[encoding]
    for item in items:
        stamp_ns = stamp_of(item[1])
        if stamp_ns is not None:
            pub.put(encode_wrench(encoding, stamp_ns, _ZERO))


def _serve(rings: dict[str, SampleRing], pubs: dict, wake: threading.Event,
           stop: threading.Event, encoding: str) -> None:
    while not stop.is_set():
        wake.wait(0.05)
        wake.clear()
        for arm, ring in rings.items():
            _answer(pubs[arm], ring.drain(), encoding)


def _serve_channel(intake: ChannelIntake, pubs: dict, stop: threading.Event,
                   encoding: str) -> None:
    while not stop.is_set():
        taken = intake.take()
        if taken is None:
            return
        for pub, items in zip(pubs.values(), taken):
            _answer(pub, items, encoding)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m wrenchd.service.bench.floor")
    parser.add_argument("--listen", required=True, help="zenoh endpoint to listen on")
    parser.add_argument("--arms", nargs="+", default=["PSM1"])
    parser.add_argument("--intake", choices=["channel", "callback"], default="channel")
    parser.add_argument("--encoding", choices=["json", "cdr"], default="json")
    parser.add_argument("--realtime", type=realtime_setting, default="off",
                        help="as the daemon's [cpus] realtime_priority: auto, off or a "
                             "SCHED_FIFO priority, taken before the session opens so that "
                             "zenoh's threads and the answering thread inherit it")
    args = parser.parse_args(argv)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    stop, wake = threading.Event(), threading.Event()
    enter_realtime(args.realtime)
    session = open_session(ZenohConfig(listen=[args.listen]))
    # express or batched as the daemon's wrench publishers are by default
    express = ArmConfig.model_fields["express"].default
    pubs = {arm: session.declare_publisher(f"dvrk/{arm}/wrenchd/measured_cf", express=express)
            for arm in args.arms}
    intake, subs = None, []
    if args.intake == "channel":
        intake = ChannelIntake(session, [f"dvrk/{arm}/measured_js" for arm in args.arms],
                               4000 * len(args.arms))
        thread = threading.Thread(target=_serve_channel,
                                  args=(intake, pubs, stop, args.encoding), daemon=True)
    else:
        rings = {arm: SampleRing(4000, wake) for arm in args.arms}
        subs = [session.declare_subscriber(
            f"dvrk/{arm}/measured_js",
            lambda s, ring=rings[arm]: ring.put((0, s.payload.to_bytes())))
            for arm in args.arms]
        thread = threading.Thread(target=_serve,
                                  args=(rings, pubs, wake, stop, args.encoding), daemon=True)
    thread.start()
    for arm in args.arms:
        print(f"bench floor: {arm} listening", flush=True)
    try:
        with StopSignals() as signals:        # the handler only flags (see stopping)
            while not signals.wait(0.2):
                pass
    finally:
        stop.set()
        for sub in subs:
            sub.undeclare()
        if intake is not None:
            intake.tick()
        thread.join(timeout=5.0)
        if intake is not None:
            intake.close()
        for pub in pubs.values():
            pub.undeclare()
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
