"""Replay: determinism, batched == streaming, metrics, policies, CLI, daemon-log sessions."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from wrenchd.adapters.mcap_log import TOPIC_ESTIMATE, LogConfig, McapLog
from wrenchd.adapters.mcap_session import TOPIC_JOINT_STATES
from wrenchd.adapters.mcap_session_reader import read_session
from wrenchd.adapters.messages import encode_joint_state
from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.features import segment_starts
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.models.adaptation import AdaptationConfig
from wrenchd.service.pipeline import ArmPipeline, PipelineConfig
from wrenchd.service.replay.policies import Policy, get_policy, policy_names, register_policy
import wrenchd.service.replay.loop as replay_loop
from wrenchd.service.replay.loop import BatchedEstimator, replay
from wrenchd.service.replay.metrics import free_error_series, replay_metrics
from wrenchd.service.replay.output import write_replay_mcap
from wrenchd.service.replay.source import joint_state_messages, load_session

ROOT = Path(__file__).resolve().parents[3]
# short sessions: calibration 3 s so the gate, the delay line and rounds all act
BASE = PipelineConfig(calibration_s=3.0, adaptation=AdaptationConfig(min_train_samples=200))


@pytest.fixture(scope="module")
def fs():
    torch.set_num_threads(1)
    return load_pretrained("seal")


@pytest.fixture(scope="module")
def contact_session():
    return load_session("sim:trocar-contact:10:5")


def test_policies_registry_and_custom_policy():
    assert {"gated", "frozen", "ungated", "drift-triggered", "periodic-reset"} <= set(
        policy_names())
    cfg = get_policy("periodic-reset").configure(BASE)
    assert cfg.policy.name == "periodic-reset" and cfg.calibration_s == 3.0
    p = register_policy(Policy("test-slow", "gated, 3 s delay", "gated",
                               {"policy": {"release_delay_s": 3.0}}), replace=True)
    assert p.configure(BASE).policy.release_delay_s == 3.0
    with pytest.raises(ConfigError):
        Policy("bad", "", "gated", {"policy": {"release_delay_s": -1}}).configure(BASE)
    with pytest.raises(ConfigError):
        get_policy("nope")


@pytest.mark.parametrize("policy", ["gated", "ungated"])
def test_batched_equals_streaming(fs, contact_session, policy):
    cfg = get_policy(policy).configure(BASE)
    a = replay(contact_session, fs, cfg, batched=False)
    b = replay(contact_session, fs, cfg, batched=True, step1="kernel")   # bit parity
    assert a.status["counters"]["swaps"] > 0          # the adaptation really swapped nets
    np.testing.assert_array_equal(a.model_version, b.model_version)
    np.testing.assert_array_equal(a.free, b.free)
    # Corr in blocks vs one sample: float32 rounding of the matmul only
    np.testing.assert_allclose(b.external, a.external, rtol=0, atol=1e-5)
    np.testing.assert_allclose(b.wrench, a.wrench, rtol=0, atol=1e-4)
    np.testing.assert_array_equal(a.offered_t, b.offered_t)


def test_replay_refuses_what_process_refuses(fs, contact_session):
    """Replay checks the session's bounds in one pass and lets ``process`` skip its own
    check of those samples: the refusals (events, counters) and estimates are still those
    of ``process`` checking every sample itself."""
    js = contact_session.joint_states
    effort, position = js.effort.copy(), js.position.copy()
    effort[50, 2] = 500.0                                 # beyond the 200 N insertion bound
    position[80, 0] = -4.0                                # beyond 3.2 rad
    bad = dataclasses.replace(js, effort=effort, position=position)
    velocity = bad.velocity.copy()
    velocity[120, 3] = np.nan                             # past JointStates' own check
    object.__setattr__(bad, "velocity", velocity)
    session = dataclasses.replace(contact_session, joint_states=bad)
    cfg = get_policy("frozen").configure(BASE)
    r = replay(session, fs, cfg, step1="kernel")
    pipeline = ArmPipeline("PSM1", fs, cfg)
    events, stamps, wrench = [], [], []
    for msg in joint_state_messages(bad):
        est, evs = pipeline.process(msg)
        events += evs
        if est is not None:
            stamps.append(est.stamp_ns)
            wrench.append(est.wrench)
    errors = [e.to_json() for e in events if e.kind == "error"]
    assert [e["reason"][:8] for e in errors] == ["effort[3", "position", "velocity"]
    assert [e.to_json() for e in r.events] == [e.to_json() for e in events]
    assert r.status["counters"] == pipeline.status()["counters"]
    np.testing.assert_array_equal(r.stamp_ns, stamps)
    np.testing.assert_allclose(r.wrench, wrench, rtol=0, atol=1e-4)


def test_replay_is_deterministic(fs, contact_session, tmp_path):
    cfg = get_policy("gated").configure(BASE)
    outs = []
    for k in range(2):
        r = replay(contact_session, fs, cfg)
        write_replay_mcap(tmp_path / f"{k}.mcap", r)
        outs.append((tmp_path / f"{k}.mcap").read_bytes())
    assert outs[0] == outs[1]


def test_metrics_on_simulated_contact_session(fs, contact_session):
    r_frozen = replay(contact_session, fs, get_policy("frozen").configure(BASE))
    m = replay_metrics(r_frozen, contact_session)
    truth = contact_session.truth
    assert truth.in_contact.any()
    assert m["samples"] == len(contact_session.joint_states)
    assert m["truth"]["force_rmse_N"]["contact"] > 0 and m["sensor"] is not None
    assert m["final_model_version"] == 0 and m["contamination"]["offered"] == 0
    # the gate sees the grasped-handle contacts (they are several N)
    assert m["gate"]["recall"] is not None and m["gate"]["recall"] > 0.3
    r_ungated = replay(contact_session, fs, get_policy("ungated").configure(BASE))
    mu = replay_metrics(r_ungated, contact_session)
    # ungated offers every sample with a window: contact samples are among them
    assert mu["contamination"]["offered"] == len(contact_session.joint_states)
    assert mu["contamination"]["in_contact"] == int(truth.in_contact.sum())
    after = contact_session.joint_states.t >= mu["gate"]["after_s"]
    assert mu["contamination"]["in_contact_after_calibration"] == int(
        truth.in_contact[after].sum())
    # ungated, every contact episode after the calibration is among those offered, each
    # with its true peak and the free-motion error before it
    episodes = mu["contamination"]["episodes_after_calibration"]
    rising = np.flatnonzero(np.diff(truth.in_contact.astype(int)) == 1) + 1
    starts = contact_session.joint_states.t[rising]
    starts = starts[starts >= mu["gate"]["after_s"]]
    assert [e["start_s"] for e in episodes] == pytest.approx(starts.tolist(), abs=1e-6)
    assert sum(e["offered"] for e in episodes) <= mu["contamination"]["in_contact"]
    force = np.linalg.norm(truth.external_wrench[:, :3], axis=1)
    assert max(e["peak_N"] for e in episodes) == pytest.approx(force[after].max())
    assert all(e["free_error_before_N"] is None or e["free_error_before_N"] >= 0
               for e in episodes)


def test_drift_recovery_metric_on_insufflation(fs):
    s = load_session("sim:insufflation-change:20:1")
    m = replay_metrics(replay(s, fs, get_policy("frozen").configure(BASE)), s)
    (d,) = m["drifts"]
    assert d["id"] == "insufflation_step" and d["onset_s"] == pytest.approx(8.0)
    assert d["free_force_error_before_N"] > 0 and d["free_force_error_after_N"] > 0


def test_free_error_series_bins_the_error_from_a_time_on(fs, contact_session):
    r = replay(contact_session, fs, get_policy("frozen").configure(BASE))
    truth = contact_session.truth
    err = np.linalg.norm(r.wrench[:, :3] - truth.external_wrench[r.sample, :3], axis=1)
    contact = truth.in_contact[r.sample]
    for rms, stat in ((True, lambda e: np.sqrt(np.mean(e ** 2))), (False, np.mean)):
        s = free_error_series(r, contact_session, 3.0, start_s=2.5, rms=rms)
        np.testing.assert_allclose(s["t"], [2.5, 5.5, 8.5])      # the last bin is partial
        for k, a in enumerate(s["t"]):
            inside = (r.t >= a) & (r.t < a + 3.0)
            assert s["free_n"][k] == (inside & ~contact).sum() > 0
            assert s["free"][k] == pytest.approx(stat(err[inside & ~contact]), rel=1e-9)
            if (inside & contact).any():
                assert s["contact"][k] == pytest.approx(stat(err[inside & contact]), rel=1e-9)
            else:
                assert np.isnan(s["contact"][k])
        # the bins together hold every free sample from the start on, and only those
        assert s["free_n"].sum() == (~contact & (r.t >= 2.5)).sum()
    whole = free_error_series(r, contact_session)                 # 1 s bins from the start
    assert whole["t"][0] == r.t[0] and len(whole["t"]) == int(np.ceil(r.t[-1] - r.t[0]))
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="longer than 0 s"):
            free_error_series(r, contact_session, bad)


def _daemon_log(path_dir: Path, session) -> Path:
    """A daemon-log-shaped MCAP: McapLog with a fake clock, joint states and estimates."""
    clock = [0.0]
    log = McapLog("PSM1", LogConfig(directory=str(path_dir)), metadata={"arm": "PSM1"},
                  clock=lambda: clock[0])
    js = session.joint_states
    for i in range(len(js)):
        stamp = int(round(js.t[i] * 1e9))
        log.write(TOPIC_JOINT_STATES, stamp, encode_joint_state(
            "json", stamp, js.names, js.position[i], js.velocity[i], js.effort[i]))
        log.write_json(TOPIC_ESTIMATE, stamp, {"header": {}, "force": [0] * 3, "free": True,
                                               "model_version": 0, "external": [0] * 6})
        clock[0] = js.t[i]
        log.tick()
    log.close()
    return log.paths[0]


def test_daemon_log_replays(fs, tmp_path):
    src = load_session("sim:trocar:6:4")
    path = _daemon_log(tmp_path, src)
    logged = read_session(path)
    assert logged.truth is None and len(logged.joint_states) == len(src.joint_states)
    s = load_session(str(path))
    r = replay(s, fs, get_policy("gated").configure(BASE))
    assert len(r.t) == len(src.joint_states)
    # the same joint states (to the log's 10 significant digits) give the same estimate
    frozen = get_policy("frozen").configure(BASE)
    np.testing.assert_allclose(replay(s, fs, frozen).wrench, replay(src, fs, frozen).wrench,
                               atol=1e-3)
    assert "estimated_force_mean_N" in replay_metrics(r, s)


def test_cli_replay_subprocess(tmp_path):
    out, rep = tmp_path / "out.mcap", tmp_path / "rep"
    cfg = tmp_path / "p.toml"
    cfg.write_text("calibration_s = 3.0\n[gate]\nenter_sigma = 5.0\n")
    cmd = [sys.executable, "-m", "wrenchd", "replay", "sim:trocar-contact:8:1",
           "--policy", "ungated", "--config", str(cfg), "--seed", "1", "-o", str(out),
           "--report", str(rep)]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=240,
                         env={"OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert res.returncode == 0, res.stderr
    m = json.loads((rep / "metrics.json").read_text())
    assert m["policy"] == "ungated" and m["samples"] == 1600
    assert m["counters"]["offered"] > 0
    assert "force RMSE" in (rep / "metrics.md").read_text()
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        topics = {}
        for _, channel, _ in make_reader(f).iter_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
    assert topics[TOPIC_ESTIMATE] == 1600 and topics["/wrenchd/events"] > 0


def test_worker_adaptation_replays_the_inline_calls(fs, contact_session):
    """The forked worker replays exactly the inline backend's calls: with no result delay the
    outcome is the inline one to the bit; with the default delay, rounds serve later."""
    cfg = get_policy("gated").configure(BASE)
    inline = replay(contact_session, fs, cfg, adaptation="inline")
    worker = replay(contact_session, fs, cfg, adaptation="worker", result_delay_s=0.0)
    assert inline.status["counters"]["swaps"] > 0
    np.testing.assert_array_equal(inline.model_version, worker.model_version)
    np.testing.assert_array_equal(inline.wrench, worker.wrench)
    delayed = replay(contact_session, fs, cfg, adaptation="worker", result_delay_s=1.0)
    first = lambda r: r.t[np.argmax(r.model_version > 0)]  # noqa: E731
    assert first(delayed) >= first(inline) + 1.0 - 1e-9


@pytest.mark.parametrize("starved", [False, True])
def test_batched_step1_on_a_thread_equals_one_torch_call(fs, contact_session, monkeypatch,
                                                        starved):
    """Step 1 computed on a thread in chunks (LSTM states carried) is, bit for bit, one
    ``predict_sequence`` over each segment (between gaps and jumps); the replay waits for
    rows it needs. ``starved``: the idle-time thread gets no CPU (a busy machine), and a
    thread of normal priority takes over from where it got to, with the same numbers."""
    monkeypatch.setattr(replay_loop, "STEP1_CHUNK", 256)    # several chunks a segment
    if starved:
        monkeypatch.setattr(replay_loop, "STEP1_TAKEOVER_S", 0.05)
        monkeypatch.setattr(replay_loop, "idle_priority", lambda: time.sleep(1.0))
    js = contact_session.joint_states
    n = 16 * 256 + 60                                    # past a tile seam too
    t = np.arange(n) / 200.0
    t[n // 2:] += 1.0                                     # a gap: two segments
    feats = np.tile(np.concatenate([js.position, js.velocity], axis=1), (3, 1))[:n]
    effort = np.tile(js.effort, (3, 1))[:n]
    base = ArmPipeline("PSM1", fs, BASE).estimator
    est = BatchedEstimator(base, t, feats, effort, step1="torch")
    try:
        first = est.step_one(t[0], None, None, None)     # waits for its block's rows only
        est._wait_step1(n)
    finally:
        est.close()
    assert est.step1_taken_over == starved
    # the tiles' seams are position jumps: segments there too
    starts = segment_starts(t, BASE.estimator.max_gap_s, feats[:, :6], feats[:, 6:],
                            BASE.estimator.max_jump)
    assert n // 2 in starts and len(starts) > 2
    want = np.concatenate([fs.predict_sequence(feats[a:b]) for a, b in
                           zip(starts, np.append(starts[1:], n))]).astype(np.float32)
    np.testing.assert_array_equal(est.step1, want)
    np.testing.assert_array_equal(first.step1_torque, want[0].astype(np.float64))
    assert est.restarted[starts].all() and est.restarted.sum() == len(starts)
