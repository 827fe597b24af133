"""``wrenchd fit`` end to end: a ROS 2 bag that the rosbags library writes from a real WPI
recording becomes a model bundle, which ``wrenchd replay --model`` and ``wrenchd serve``
(an external robot on zenoh) then serve; a recording too still to identify from is refused."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.support import (LAB_EPOCH_NS, expect_line, free_port, ros2_bag_from, stop_within,
                           wait_for, write_config)
from wrenchd.adapters.csv_psm import read_wpi_csv
from wrenchd.adapters.messages import decode_wrench, encode_joint_state
from wrenchd.adapters.zenoh_io import ZenohConfig, open_session
from wrenchd.models.series import JOINT_NAMES
from wrenchd.service.cli.echo import query_status

CLI = [sys.executable, "-m", "wrenchd"]


def _run(*args, timeout: float = 240.0) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def bundle(wpi_data, tmp_path_factory) -> tuple[Path, dict]:
    root = tmp_path_factory.mktemp("fit")
    js, _ = read_wpi_csv(wpi_data / "one_no_weight.csv")
    bag = ros2_bag_from(js, root / "psm1_free_motion")
    out = root / "psm1-bundle"
    done = _run("fit", str(bag), "-o", str(out), "--epochs", "30", "--json",
                str(root / "fit.json"), "--quiet")
    assert done.returncode == 0, done.stderr
    return out, json.loads((root / "fit.json").read_text())


def test_fit_writes_a_bundle_from_a_ros2_bag(bundle):
    out, report = bundle
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["origin"] == "robot" and manifest["arm"] == "PSM1"
    assert list(manifest["data"]) == ["psm1_free_motion"]
    assert manifest["weights"]["config"]["kind"] == "hybrid"
    s = report["held_out"]
    assert s["samples"] == 1200 and report["train_samples"] == 4799
    ls, hybrid, spread = (np.array(s[k]) for k in ("ls_rmse", "hybrid_rmse", "torque_std"))
    # physics alone explains most of the big joints' torque on the held-out 6 s (a repeat of
    # the trajectory: measured 0.09-0.17 against 0.7-0.95 N m, N)
    assert np.all(ls[:3] < 0.3 * spread[:3]), (ls, spread)
    # the residual, trained 30 epochs here, helps there (measured 20-40 % lower on joints 1-3)
    assert np.all(hybrid[:3] < ls[:3]), (hybrid, ls)
    assert 0.9 <= s["inside_coverage"] <= 1.0
    assert [c["joint"] for c in report["coverage"]] == list(JOINT_NAMES)
    assert "| outer_pitch |" in (out / "report.md").read_text()


def test_replay_serves_the_bundle(bundle, wpi_data, tmp_path):
    out, _ = bundle
    done = _run("replay", str(wpi_data / "two.csv"), "--model", str(out), "--report",
                str(tmp_path / "rep"))
    assert done.returncode == 0, done.stderr
    metrics = json.loads((tmp_path / "rep" / "metrics.json").read_text())
    assert metrics["samples"] == 5999 and metrics["counters"]["errors"] == 0


def test_serve_takes_the_bundle_and_says_where_it_came_from(bundle, wpi_data, tmp_path):
    out, report = bundle
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = write_config(tmp_path / "wrenchd.toml", endpoint, "json", tmp_path / "logs",
                          arms=("PSM1",), model=str(out))
    js, _ = read_wpi_csv(wpi_data / "two.csv")
    daemon = subprocess.Popen([*CLI, "serve", "--config", str(config)], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    wrenches: list[np.ndarray] = []
    session = None
    try:
        expect_line(daemon, "measured_js", 120.0, "the daemon")
        session = open_session(ZenohConfig(connect=[endpoint]))
        sub = session.declare_subscriber(
            "dvrk/PSM1/wrenchd/measured_cf",
            lambda s: wrenches.append(decode_wrench("json", s.payload.to_bytes())[2]))
        pub = session.declare_publisher("dvrk/PSM1/measured_js")
        time.sleep(0.5)
        n = 600                                          # 3 s at 200 Hz, in real time
        start = time.monotonic()
        for i in range(n):
            delay = start + js.t[i] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            pub.put(encode_joint_state("json", LAB_EPOCH_NS + round(js.t[i] * 1e9), js.names,
                                       js.position[i], js.velocity[i], js.effort[i]))
        wait_for(lambda: len(wrenches) >= n, 20.0, "a wrench per joint state")
        status = query_status(session, "dvrk/PSM1/wrenchd/status", 10.0)
        pub.undeclare()
        sub.undeclare()
    finally:
        if session is not None:
            session.close()
        stop_within(daemon, 30.0, "the daemon")
    model = status["model"]
    assert model["origin"] == "robot" and model["kind"] == "hybrid"
    assert model["digest"] == report["bundle_digest"] and "warning" not in model
    assert np.all(np.isfinite(np.array(wrenches)))
    assert status["counters"]["errors"] == 0 and status["counters"]["estimated"] >= n


def test_a_still_recording_is_refused(wpi_data, tmp_path):
    js, _ = read_wpi_csv(wpi_data / "one_no_weight.csv")
    still = js.slice(0, 5999)
    still = type(still)(still.t, np.repeat(still.position[:1], len(still), 0),
                        np.zeros_like(still.velocity), still.effort)
    done = _run("fit", str(ros2_bag_from(still, tmp_path / "still")), "-o", str(tmp_path / "b"))
    assert done.returncode == 2, done.stderr
    assert "too little motion" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "b").exists()


def test_a_bundle_whose_step1_reads_ahead_is_refused(bundle, tmp_path):
    """An offline study's model (an acceleration filter reading samples ahead) never serves."""
    from wrenchd.adapters.bundle import read_bundle, write_bundle
    from wrenchd.models.errors import ConfigError
    from wrenchd.service.pipeline.step1 import load_bundle_step1

    out, _ = bundle
    original = read_bundle(out)
    config = json.loads(json.dumps(original.weights_config))
    config["config"]["acceleration"]["lookahead_s"] = 0.01
    copy = write_bundle(tmp_path / "ahead", arm="PSM1", origin="robot",
                        physics=original.physics, report_md="", report=original.report,
                        data_files=[out / "manifest.json"], weights=original.weights,
                        weights_config=config)
    model, _ = load_bundle_step1(out)                  # the bundle as fitted serves
    assert model.acceleration.lookahead == 0
    with pytest.raises(ConfigError, match="cannot serve"):
        load_bundle_step1(tmp_path / "ahead")
    assert copy.weights_config["config"]["acceleration"]["lookahead_s"] == 0.01
