"""Bad input, fuzzed, through one arm's pipeline (``wrenchd.service.pipeline.arm.ArmPipeline``).

A plausible 200 Hz PSM stream (shipped ``seal`` step-1 weights) is interleaved, at places and
in numbers hypothesis chooses, with bad samples: NaN/Inf in one field, absurd magnitudes,
five or seven joints, time going backwards, duplicate stamps, gaps, and undecodable payloads
(the daemon's ``reject`` path). Properties:

* ``process`` never raises; a bad sample returns no estimate and exactly one ``error`` event
  whose kind names the defect, and is counted (``errors``, ``error_kinds``);
* a good sample is estimated (finite wrench); after a gap the LSTM restarts (``gap`` event,
  ``restarted``);
* no bad sample reaches the training data: the ``on_offer`` hook sees only good samples' times,
  each once (ungated: all of them; gated with no release delay: a subset).

Bugs the fuzzing found are kept as plain tests at the end, with the exact input.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wrenchd.adapters.messages import decode_joint_state
from wrenchd.models.series import JointSample
from wrenchd.models.errors import DataError
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.models.gate import GateConfig
from wrenchd.service.pipeline import ArmPipeline, PipelineConfig, PolicyConfig

NS = 1_000_000_000
STEP_NS = 5_000_000                  # 200 Hz
T0_NS = 1_000 * NS
MAX_GAP_NS = 50_000_000              # EstimatorConfig.max_gap_s default
FUZZ = settings(max_examples=25, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

POLICIES = {"ungated": PolicyConfig(name="ungated"),
            "gated-no-delay": PolicyConfig(name="gated", release_delay_s=0.0)}


@functools.cache
def seal_model():
    return load_pretrained("seal")


#: The synthetic stream's efforts are not what the seal model predicts (its residual is
#: ~0.1-1 N m), so the gate's noise floor is raised to that level: these tests are about
#: defects never reaching training, not about the gate's calibration. Nor about weak
#: contacts: that residual is a steady model error a tip force explains, which the weak-contact
#: watch would hold back for its first seconds.
WIDE_FLOOR = (1.0, 1.0, 5.0, 0.5, 0.5, 0.5)


def make_pipeline(policy: str) -> tuple[ArmPipeline, list[float]]:
    # no calibration phase and a 200-sample gate warm-up, so short streams reach the gate
    pipeline = ArmPipeline("PSM1", seal_model(), PipelineConfig(
        policy=POLICIES[policy], calibration_s=0.0,
        gate=GateConfig(warmup_samples=200, min_std=WIDE_FLOOR, weak_contact_s=0.0)))
    offered: list[float] = []
    pipeline.on_offer = lambda times: offered.extend(float(t) for t in times)
    return pipeline, offered


def good_state(stamp_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A smooth, in-bounds PSM state at ``stamp_ns``: positions [rad; m], velocities, efforts."""
    t = (stamp_ns - T0_NS) / NS
    w = np.array([0.7, 0.9, 0.5, 1.1, 1.3, 1.7])            # rad/s
    amp = np.array([0.3, 0.2, 0.03, 0.5, 0.3, 0.3])
    q = amp * np.sin(w * t) + np.array([0.0, 0.0, 0.12, 0.0, 0.0, 0.0])
    dq = amp * w * np.cos(w * t)
    effort = np.array([0.05, 0.3, 1.5, 0.01, 0.02, 0.02]) + 0.2 * np.sin(w * t + 0.3) * \
        np.array([0.2, 0.5, 2.0, 0.01, 0.02, 0.02])
    return q, dq, effort


def message(stamp_ns: int, q, dq, effort) -> JointSample:
    return JointSample(stamp_ns, "psm_base", (), np.asarray(q, dtype=float),
                         np.asarray(dq, dtype=float), np.asarray(effort, dtype=float))


# one action per sample: a good sample, a gap then a good sample, or one kind of bad sample
GOOD, GAP = "good", "gap"
BAD_KINDS = {"nan": "invalid", "inf": "invalid", "absurd": "invalid", "joints5": "invalid",
             "joints7": "invalid", "backwards": "time_backwards", "duplicate": "duplicate",
             "garbage": "decode"}
action = st.one_of(
    st.just((GOOD, 0, 0.0)),
    st.tuples(st.just(GAP), st.integers(0, 5), st.floats(0.06, 30.0)),
    st.tuples(st.sampled_from(sorted(BAD_KINDS)), st.integers(0, 17),
              st.sampled_from([1e3, 1e6, 1e300, -1e12])))
streams = st.lists(st.one_of(st.just((GOOD, 0, 0.0)), action), min_size=20, max_size=90)


def bad_sample(kind: str, where: int, scale: float, last_ns: int, serial: int):
    """A bad sample of ``kind`` after the good sample at ``last_ns``; stamps of bad samples
    other than duplicates are off the good 5 ms grid (``serial`` keeps them distinct)."""
    off_grid = last_ns + STEP_NS // 2 + 1_000 * serial + 7
    q, dq, effort = (v.copy() for v in good_state(last_ns + STEP_NS))
    field = (q, dq, effort)[where // 6]
    j = where % 6
    if kind == "nan":
        field[j] = np.nan
        return message(off_grid, q, dq, effort)
    if kind == "inf":
        field[j] = -np.inf if where % 2 else np.inf
        return message(off_grid, q, dq, effort)
    if kind == "absurd":
        field[j] = scale
        return message(off_grid, q, dq, effort)
    if kind in ("joints5", "joints7"):
        n = 5 if kind == "joints5" else 7
        return message(off_grid, *(np.resize(v, n) for v in (q, dq, effort)))
    if kind == "backwards":
        back = 1 + int(abs(scale) % 10.0 * NS) + 1_000 * serial
        q, dq, effort = good_state(last_ns - back)
        return message(last_ns - back - 3, q, dq, effort)
    if kind == "duplicate":
        q, dq, effort = good_state(last_ns)
        return message(last_ns, q, dq, effort + 0.01)
    raise AssertionError(kind)


def run_stream(policy: str, actions) -> None:
    pipeline, offered = make_pipeline(policy)
    now = T0_NS
    good_times: list[float] = []
    bad_times: list[float] = []
    duplicates: list[float] = []
    expected_kinds: dict[str, int] = {}
    last_ns = None
    for serial, (kind, where, scale) in enumerate(actions):
        before = pipeline.counters.errors
        if kind in (GOOD, GAP) or last_ns is None:
            if kind == GAP:
                now += int(scale * NS) + where
            else:
                now += STEP_NS
            est, events = pipeline.process(message(now, *good_state(now)))
            assert est is not None, events
            assert not [e for e in events if e.kind == "error"], events
            assert np.isfinite(est.wrench).all() and est.wrench.shape == (6,)
            assert isinstance(est.free, bool)
            gapped = last_ns is not None and now - last_ns > MAX_GAP_NS
            assert any(e.kind == "gap" for e in events) == gapped
            if gapped:
                assert est.restarted
            good_times.append(now / NS)
            last_ns = now
            continue
        expected = BAD_KINDS[kind]
        if kind == "garbage":
            t = (last_ns + STEP_NS // 2 + 1_000 * serial + 7) / NS
            event = pipeline.reject(t, "decode", "not JSON")
            events, est = [event], None
        else:
            msg = bad_sample(kind, where, scale, last_ns, serial)
            t = msg.stamp_ns / NS
            est, events = pipeline.process(msg)
        assert est is None
        assert [e.kind for e in events] == ["error"], events
        assert events[0].detail["error"] == expected and events[0].detail["reason"]
        assert pipeline.counters.errors == before + 1
        expected_kinds[expected] = expected_kinds.get(expected, 0) + 1
        (duplicates if kind == "duplicate" else bad_times).append(t)
    c = pipeline.counters
    assert c.error_kinds == expected_kinds
    assert c.errors == sum(expected_kinds.values())
    assert c.estimated == len(good_times)
    assert c.received == len(actions)
    # nothing bad was offered for training; each good sample at most once
    assert len(offered) == len(set(offered)) == c.offered
    assert set(offered) <= set(good_times)
    assert not set(offered) & set(bad_times)
    if policy == "ungated":
        assert offered == good_times
    pipeline.close()
    return pipeline


@pytest.mark.parametrize("policy", sorted(POLICIES))
@FUZZ
@given(actions=streams)
def test_bad_samples_are_errors_and_never_offered(policy, actions):
    run_stream(policy, actions)


def test_long_stream_with_every_defect_gated():
    """One deterministic 700-sample stream past the gate's warm-up (200 samples), a defect of
    each kind every 25 samples: the gate calibrates and the gated policy offers free samples
    (fewer than the 600 an adaptation round needs, to stay quick), none of them bad."""
    kinds = sorted(BAD_KINDS)
    actions = []
    for i in range(700):
        if i % 25 == 24:
            actions.append((kinds[(i // 25) % len(kinds)], i % 18, 1e6))
        elif i % 300 == 299:
            actions.append((GAP, 0, 0.2))
        else:
            actions.append((GOOD, 0, 0.0))
    pipeline = run_stream("gated-no-delay", actions)
    assert pipeline.gate.calibrated and pipeline.counters.offered > 300


# -- the daemon's path: payload -> decode -> reject or process ----------------------------
def handle(pipeline: ArmPipeline, payload: bytes, t_arrival: float):
    """What ``wrenchd.service.runtime.daemon`` does with one payload (decode errors are rejected)."""
    try:
        msg = decode_joint_state("json", payload)
    except DataError as exc:
        return None, [pipeline.reject(t_arrival, "decode", str(exc))]
    return pipeline.process(msg)


json_numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                         st.integers(-(2 ** 63), 2 ** 63))
json_junk = st.one_of(st.none(), json_numbers, st.text(max_size=5), st.booleans(),
                      st.lists(json_numbers, max_size=8))


@FUZZ
@given(edits=st.lists(st.tuples(st.integers(0, 59), st.sampled_from(
    ["position", "velocity", "effort", "name", "header", "sec", "nanosec", "raw"]),
    json_junk, st.binary(max_size=40)), max_size=15))
def test_daemon_path_never_raises_and_never_trains_on_bad_payloads(edits):
    pipeline, offered = make_pipeline("ungated")
    edits_at = {i: (f, v, raw) for i, f, v, raw in edits}
    clean: list[float] = []
    estimated: set[float] = set()
    for i in range(60):
        stamp = T0_NS + i * STEP_NS
        q, dq, effort = good_state(stamp)
        body = {"header": {"stamp": {"sec": stamp // NS, "nanosec": stamp % NS},
                           "frame_id": "psm_base"},
                "name": [f"j{k}" for k in range(6)], "position": q.tolist(),
                "velocity": dq.tolist(), "effort": effort.tolist()}
        edited = i in edits_at
        if edited:
            field, value, raw = edits_at[i]
            if field in ("position", "velocity", "effort", "name", "header"):
                body[field] = value
            elif field in ("sec", "nanosec"):
                body["header"]["stamp"][field] = value
        payload = raw if edited and field == "raw" else json.dumps(body).encode()
        before = pipeline.counters.errors
        est, events = handle(pipeline, payload, stamp / NS)
        errors = [e for e in events if e.kind == "error"]
        # a sample is refused with one error, or estimated without one; except the sample that
        # ends a run of resync_after refused ones: its error comes with a clock_reset and it
        # is estimated on the new timeline (a far-future first stamp makes every later one
        # "time going backwards" until then)
        reset = any(e.kind == "clock_reset" for e in events)
        assert (est is None) == (bool(errors) and not reset) and len(errors) <= 1
        assert pipeline.counters.errors == before + len(errors)
        if est is not None:
            assert np.isfinite(est.wrench).all()
            estimated.add(est.t)
            if not edited:
                clean.append(est.t)
    # an edit that left a valid, in-bounds sample may be estimated and offered; a refused one
    # never is (every offered time is an estimated sample's), and nothing is offered twice
    assert len(offered) == len(set(offered)) == pipeline.counters.offered
    assert set(offered) <= estimated
    assert set(clean) <= set(offered)
    assert pipeline.counters.received == 60


# -- bugs found by the fuzzing above (fixed) -----------------------------------------
@pytest.mark.parametrize("lengths", [(6, 5, 6), (6, 6, 7)], ids=["velocity5", "effort7"])
def test_unequal_lengths_are_an_error_event(lengths):
    pipeline, offered = make_pipeline("ungated")
    for i in range(5):
        pipeline.process(message(T0_NS + i * STEP_NS, *good_state(T0_NS + i * STEP_NS)))
    stamp = T0_NS + 5 * STEP_NS
    q, dq, effort = good_state(stamp)
    est, events = pipeline.process(message(stamp, np.resize(q, lengths[0]),
                                           np.resize(dq, lengths[1]),
                                           np.resize(effort, lengths[2])))
    assert est is None and [e.kind for e in events] == ["error"]
    assert stamp / NS not in offered


def test_refused_sample_does_not_move_the_clock():
    pipeline, _ = make_pipeline("ungated")
    pipeline.process(message(T0_NS, *good_state(T0_NS)))
    q, dq, effort = good_state(T0_NS + 2 * STEP_NS)
    est, _ = pipeline.process(message(T0_NS + 2 * STEP_NS, q, dq[:1], effort))  # broadcasts
    assert est is None
    est, events = pipeline.process(message(T0_NS + STEP_NS, *good_state(T0_NS + STEP_NS)))
    assert est is not None, events


def test_one_far_future_stamp_does_not_stop_estimation():
    pipeline, _ = make_pipeline("ungated")
    for i in range(10):
        pipeline.process(message(T0_NS + i * STEP_NS, *good_state(T0_NS + i * STEP_NS)))
    glitch = T0_NS + 3600 * NS
    pipeline.process(message(glitch, *good_state(T0_NS + 10 * STEP_NS)))
    estimated = 0
    for i in range(11, 411):                 # the next 2 s of a healthy stream
        est, _ = pipeline.process(message(T0_NS + i * STEP_NS, *good_state(T0_NS + i * STEP_NS)))
        estimated += est is not None
    # a bound to argue about: estimation resumes within 1 s (200 samples)
    assert estimated >= 200, f"{estimated} of 400 samples estimated after the glitch"
