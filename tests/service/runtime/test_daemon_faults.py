"""Faults and load with real processes: a daemon killed with SIGKILL leaves a readable log; a
burst and two arms at once get every wrench, with one-by-one numbers."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from contextlib import contextmanager

import numpy as np
import pytest
import zenoh

from wrenchd.adapters.mcap_session_reader import read_session_report
from wrenchd.adapters.messages import encode_joint_state
from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from tests.support import expect_line, free_port, stop_within, wait_for, write_config


@contextmanager
def serving(config, endpoint: str, arms: int):
    """``wrenchd serve --config config`` as a subprocess and a zenoh session connected to
    it; on exit the session is closed and the daemon stopped with SIGINT, which it must
    survive cleanly."""
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    session = None
    try:
        for k in range(arms):
            expect_line(daemon, "listening", 120.0, f"the daemon (arm {k + 1} of {arms})")
        session = open_session(ZenohConfig(connect=[endpoint]))
        yield session
    finally:
        if session is not None:
            session.close()
        _, err = stop_within(daemon, 60.0, "the daemon", signal.SIGINT)
    assert daemon.returncode == 0, err


def test_kill_9_of_the_daemon_still_finishes_its_log(tmp_path):
    """The log writer is a process of its own: when the daemon dies without a word, it
    writes what it was handed and finishes the file. (A writer killed too loses at most the
    flush interval: tests/adapters/test_mcap_log.py.)"""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp_path / "wrenchd.toml", endpoint, "json", tmp_path / "logs")
    daemon = subprocess.Popen([sys.executable, "-m", "wrenchd", "serve", "--config",
                               str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
    js = run_scenario("trocar", 6.0, 5).joint_states
    received: list[int] = []
    session = None
    try:
        expect_line(daemon, "measured_js", 120.0, "the daemon")
        session = open_session(ZenohConfig(connect=[endpoint]))
        sub = session.declare_subscriber("dvrk/PSM2/wrenchd/measured_cf",
                                         lambda s: received.append(1))
        pub = session.declare_publisher("dvrk/PSM2/measured_js")
        time.sleep(0.5)
        start = time.monotonic()
        for i in range(len(js)):                        # 6 s at 200 Hz, in real time
            delay = start + js.t[i] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            pub.put(encode_joint_state("json", int(round(js.t[i] * 1e9)), js.names,
                                       js.position[i], js.velocity[i], js.effort[i]))
        wait_for(lambda: len(received) >= len(js), 10.0, "every wrench")
        daemon.send_signal(signal.SIGKILL)              # no stop, no word to its children
        daemon.wait(timeout=10)
        pub.undeclare()
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        # its pipes close when its children are gone too: the log writer when it has finished
        # the files, the worker when it sees its parent gone (seconds on a loaded machine)
        stop_within(daemon, 60.0, "the daemon", signal.SIGKILL)
    assert daemon.returncode == -signal.SIGKILL
    logs = sorted((tmp_path / "logs").glob("PSM2-*.mcap"))
    assert len(logs) == 1
    wait_for(lambda: not read_session_report(logs[0])[1].truncated, 20.0, "a finished log")
    recovered, info = read_session_report(logs[0])
    n = len(recovered.joint_states)
    # what the daemon had not handed over yet (one 20 ms batch) is lost, nothing else
    assert len(js) - 20 <= n <= len(js)
    np.testing.assert_allclose(recovered.joint_states.effort, js.effort[:n], rtol=1e-9)


def test_a_burst_is_worked_off_in_batches_without_loss(tmp_path):
    """1 400 joint states published as fast as this process can (a backlog far beyond one
    sample per wake-up, within the ring's 2 000): every one gets its wrench, in stamp order,
    with the estimates of a sample-by-sample pipeline (the daemon works a backlog off with
    process_many)."""
    from wrenchd.models.estimator.pretrained import load_pretrained
    from wrenchd.service.pipeline import ArmPipeline, PipelineConfig

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp_path / "wrenchd.toml", endpoint, "json", tmp_path / "logs")
    js = run_scenario("trocar", 7.0, 6).joint_states
    payloads = [encode_joint_state("json", int(round(js.t[i] * 1e9)), js.names,
                                   js.position[i], js.velocity[i], js.effort[i])
                for i in range(len(js))]
    received: list[bytes] = []
    with serving(config, endpoint, arms=1) as session:
        sub = session.declare_subscriber("dvrk/PSM2/wrenchd/measured_cf",
                                         lambda s: received.append(s.payload.to_bytes()))
        # blocking congestion control: the burst must reach the daemon (a dropping
        # publisher would lose samples in zenoh, which this test is not about)
        pub = session.declare_publisher("dvrk/PSM2/measured_js",
                                        congestion_control=zenoh.CongestionControl.BLOCK)
        time.sleep(0.5)
        for p in payloads:
            pub.put(p)
        try:
            wait_for(lambda: len(received) >= len(js), 60.0, "every wrench")
        except AssertionError:
            raise AssertionError(f"{len(received)} wrenches for {len(js)} joint states") \
                from None
        pub.undeclare()
        sub.undeclare()
    from wrenchd.adapters.messages import decode_joint_state, decode_wrench

    got = [decode_wrench("json", p) for p in received]
    stamps = [g[0] for g in got]
    assert stamps == [int(round(t * 1e9)) for t in js.t]
    # the same numbers as one sample at a time (calibration 2 s as in the daemon's config;
    # model swaps happen at other samples, so only the first second, before any round)
    ref = ArmPipeline("PSM2", load_pretrained("seal"), PipelineConfig(calibration_s=2.0))
    n = 200
    for i in range(n):
        est, _ = ref.process(decode_joint_state("json", payloads[i]))
        np.testing.assert_allclose(got[i][2], est.wrench, rtol=1e-4, atol=1e-5)
    ref.close()


@pytest.mark.parametrize("intake, gather_us", [("channel", 0), ("callback", 0),
                                               ("callback", 300)])
def test_two_arms_of_one_model_get_the_numbers_each_would_get_alone(tmp_path, intake,
                                                                    gather_us):
    """Two arms fed together at 200 Hz, through the one channel or a callback each (the
    daemon steps arms of one model as one batch; with ``[ring] gather_us`` it waits for the
    other arm's sample first): every wrench comes back on each arm, equal to a one-arm
    pipeline's to float32 rounding (the first second, before any adaptation round can change
    the nets)."""
    from wrenchd.adapters.messages import decode_joint_state, decode_wrench
    from wrenchd.models.estimator.pretrained import load_pretrained
    from wrenchd.service.pipeline import ArmPipeline, PipelineConfig

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp_path / "wrenchd.toml", endpoint, "json", tmp_path / "logs",
                          arms=("PSM1", "PSM3"))
    config.write_text(config.read_text()
                      + f"[ring]\nintake = \"{intake}\"\ngather_us = {gather_us}\n")
    sessions = {"PSM1": run_scenario("trocar", 2.0, 7).joint_states,
                "PSM3": run_scenario("trocar", 2.0, 8).joint_states}
    payloads = {arm: [encode_joint_state("json", int(round(js.t[i] * 1e9)), js.names,
                                         js.position[i], js.velocity[i], js.effort[i])
                      for i in range(len(js))] for arm, js in sessions.items()}
    received: dict[str, list[bytes]] = {arm: [] for arm in sessions}
    with serving(config, endpoint, arms=2) as session:
        subs = [session.declare_subscriber(f"dvrk/{arm}/wrenchd/measured_cf",
                                           lambda s, arm=arm: received[arm].append(
                                               s.payload.to_bytes())) for arm in sessions]
        pubs = {arm: session.declare_publisher(f"dvrk/{arm}/measured_js") for arm in sessions}
        time.sleep(0.5)
        start = time.monotonic()
        n = len(sessions["PSM1"])
        for i in range(n):
            delay = start + i / 200.0 - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            for arm in sessions:
                pubs[arm].put(payloads[arm][i])
        wait_for(lambda: all(len(r) >= n for r in received.values()), 20.0, "every wrench")
        for s in subs:
            s.undeclare()
        for p in pubs.values():
            p.undeclare()
    seal = load_pretrained("seal")
    for arm, js in sessions.items():
        ref = ArmPipeline(arm, seal, PipelineConfig(calibration_s=2.0))
        got = [decode_wrench("json", p) for p in received[arm]]
        assert [g[0] for g in got] == [int(round(t * 1e9)) for t in js.t]
        for i in range(200):
            est, _ = ref.process(decode_joint_state("json", payloads[arm][i]))
            np.testing.assert_allclose(got[i][2], est.wrench, rtol=1e-4, atol=1e-5)
        ref.close()
