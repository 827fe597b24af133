"""``wrenchd robot``: the simulated PSM streamed over zenoh, its ground truth recorded.

The simulated arm publishes its joint states in real time on ``{prefix}/{arm}/measured_js``
(JSON with ``sensor_msgs/JointState`` fields, or ROS 2 CDR) and the whole session, with the
simulator's ground truth, is recorded to MCAP each second. ``wrenchd serve`` starts one
beside the daemon on its embedded default; the daemon subscribes to the same key.

The scenario is simulated in blocks of up to two minutes; each new block starts a fresh
trajectory (the next seed), with time continuing. The first block has no contact in its first
minute: the daemon's contact-free calibration of step 2.

SIGINT/SIGTERM stop it promptly at any point (:mod:`~wrenchd.service.runtime.stopping`: the
handler only sets a flag): while it publishes, before the next sample; while it waits for its
subscriber or simulates a block (on a thread of its own), within 10 ms. Either way what was published is recorded and the file finished.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from pathlib import Path

from wrenchd.adapters.mcap_session_writer import SessionWriter
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.adapters.sim.simulator import SimulatorConfig
from wrenchd.adapters.messages import encode_joint_state, encode_setup_change, stamp_ns_of
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session, wait_for_subscriber
from wrenchd.service.runtime.stopping import StopSignals
from wrenchd.models.physics.effects.drift import drift_onsets

BLOCK_S = 120.0
CONTACT_FREE_START_S = 60.0     # the daemon's default calibration_s
MATCH_TIMEOUT_S = 5.0           # wait this long for a subscriber before the first sample


def _unless_stopped(stop: StopSignals, compute):
    """``compute()``'s result, computed on a thread while this one waits for it or for a stop
    (then None at once: the computation, under a second of CPU in C code that no flag can
    reach, is abandoned on its daemon thread)."""
    result: list = []

    def run() -> None:
        try:
            result.append((True, compute()))
        except BaseException as exc:  # noqa: BLE001 - re-raised on the caller's thread
            result.append((False, exc))

    thread = threading.Thread(target=run, name="wrenchd-robot-simulate", daemon=True)
    thread.start()
    while thread.is_alive():
        if stop.wait(0.01):
            return None
    ok, value = result[0]
    if not ok:
        raise value
    return value


def serve_simulated(scenario: str, seed: int, duration_s: float | None, out_dir: Path,
                    arm: str = "PSM1", rate_hz: float = 200.0,
                    zenoh: ZenohConfig | None = None, prefix: str = "dvrk",
                    encoding: str = "json", quiet: bool = False,
                    announce_setup: bool = True) -> int:
    """Stream ``scenario`` in real time until ``duration_s`` or SIGINT/SIGTERM. Returns 0.

    With ``announce_setup``, the set-up changes the scenario makes (an insufflation step, a
    ramp's start; and each new block, which starts the scenario's set-up afresh, when it has
    any) are announced on ``{prefix}/{arm}/setup`` as they happen, as an insufflator or the
    OR's console connected to the daemon would."""
    with StopSignals() as stop:
        return _serve(stop, scenario, seed, duration_s, out_dir, arm, rate_hz, zenoh, prefix,
                      encoding, quiet, announce_setup)


def _serve(stop: StopSignals, scenario: str, seed: int, duration_s: float | None,
           out_dir: Path, arm: str, rate_hz: float, zenoh: ZenohConfig | None, prefix: str,
           encoding: str, quiet: bool, announce_setup: bool) -> int:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{arm}-{scenario}-seed{seed}.mcap"
    key = f"{prefix}/{arm}/measured_js"
    session = open_session(zenoh or ZenohConfig())
    published = 0
    try:
        publisher = session.declare_publisher(key)
        setup_pub = session.declare_publisher(f"{prefix}/{arm}/setup") if announce_setup else None
        with SessionWriter(path, metadata={
                "source": "wrenchd serve (simulated PSM)", "arm": arm,
                "scenario": {"name": scenario, "seed": seed, "block_s": BLOCK_S}}) as writer:
            t0_wall = None
            offset, block = 0.0, 0
            while not stop.requested:
                length = BLOCK_S if duration_s is None else min(BLOCK_S, duration_s - offset)
                if length <= 0:
                    break
                # the first block leaves the daemon its contact-free calibration minute
                sim = _unless_stopped(stop, lambda length=length, block=block: run_scenario(
                    scenario, length, seed + block,
                    config=SimulatorConfig(publish_rate_hz=rate_hz),
                    contact_free_s=CONTACT_FREE_START_S if block == 0 else None))
                if sim is None:
                    break
                js = dataclasses.replace(sim.joint_states, t=sim.joint_states.t + offset)
                truth = sim.truth
                changes = ([(offset + start_s, name) for name, start_s, _ in drift_onsets(sim)]
                           if setup_pub is not None else [])
                if changes and block > 0:
                    changes.insert(0, (offset, "new block"))
                if t0_wall is None:                     # the clock starts with the first sample
                    wait_for_subscriber(publisher, MATCH_TIMEOUT_S, pause=stop.wait)
                    if stop.requested:
                        break
                    print(f"wrenchd: simulated {arm} ({scenario}) publishing on '{key}' at "
                          f"{rate_hz:g} Hz, recording to {path}", flush=True)
                    t0_wall = time.monotonic()
                start, sent = 0, 0              # sent: samples of this block published
                for i in range(len(js)):
                    delay = t0_wall + js.t[i] - time.monotonic()
                    if delay > 0:
                        stop.wait(delay)
                    if stop.requested:
                        break
                    while changes and js.t[i] >= changes[0][0]:
                        t_change, what = changes.pop(0)
                        setup_pub.put(encode_setup_change(stamp_ns_of(t_change), note=what))
                    publisher.put(encode_joint_state(encoding, stamp_ns_of(js.t[i]), js.names,
                                                     js.position[i], js.velocity[i],
                                                     js.effort[i]))
                    published += 1
                    sent = i + 1
                    if js.t[i] - js.t[start] >= 1.0:           # record and report each second
                        writer.write_joint_states(js.slice(start, sent), truth.slice(start, sent))
                        start = sent
                        if not quiet:
                            print(f"t={js.t[i]:7.1f} s  published {published}  "
                                  f"contact={bool(truth.in_contact[i])}", flush=True)
                if sent > start:                                # what was published, no more
                    writer.write_joint_states(js.slice(start, sent), truth.slice(start, sent))
                offset += length
                block += 1
        publisher.undeclare()
        if setup_pub is not None:
            setup_pub.undeclare()
    finally:
        session.close()
    print(f"wrenchd robot: stopped after {published} samples; session in {path}", flush=True)
    return 0

