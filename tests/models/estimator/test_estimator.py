import copy

import numpy as np
import pytest
import torch

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.correction import Xfer
from wrenchd.models.estimator.estimator import EstimatorConfig, TwoStepEstimator
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.series import JointStates


def _with_gap(session, n=300, gap_at=120, gap_s=0.5):
    """The first ``n`` samples, with the clock jumping ``gap_s`` at ``gap_at``."""
    js = session.joint_states.slice(0, n)
    t = js.t.copy()
    t[gap_at:] += gap_s
    return JointStates(t, js.position, js.velocity, js.effort)


def _stream(est, js):
    est.reset_state()
    outs = [est.step_one(t, q, dq, e) for t, q, dq, e in
            zip(js.t, js.position, js.velocity, js.effort)]
    return {name: np.array([getattr(o, name) for o in outs])
            for name in ("predicted_torque", "external_torque", "wrench", "restarted")}


@pytest.mark.parametrize("mode", ["base", "corr", "xfer"])
def test_streaming_equals_batch(mode, models_f64, free_space_session):
    fs, corr, xfer = models_f64
    est = TwoStepEstimator(fs, {"base": None, "corr": corr, "xfer": xfer}[mode])
    assert est.mode == mode
    js = _with_gap(free_space_session)
    batch = est.predict_batch(js)
    streamed = _stream(est, js)
    assert streamed["restarted"].nonzero()[0].tolist() == [0, 120]
    np.testing.assert_array_equal(streamed["restarted"], batch.restarted)
    for name in ("predicted_torque", "external_torque"):
        np.testing.assert_allclose(streamed[name], getattr(batch, name), rtol=0, atol=1e-10)
    np.testing.assert_allclose(streamed["wrench"], batch.wrench, rtol=0, atol=1e-8)
    np.testing.assert_allclose(batch.external_torque, js.effort - batch.predicted_torque)


def test_streaming_equals_batch_float32(models_f32, free_space_session):
    fs, corr, _ = models_f32
    est = TwoStepEstimator(fs, corr)
    js = _with_gap(free_space_session)
    batch, streamed = est.predict_batch(js), _stream(est, js)
    scale = np.abs(batch.predicted_torque).max(axis=0)
    assert np.all(np.abs(streamed["predicted_torque"] - batch.predicted_torque) <= 1e-5 * scale)


def test_the_gap_restart_matters(models_f64, free_space_session):
    """Without the restart the state after the gap differs: the test above could fail."""
    fs, corr, _ = models_f64
    js = _with_gap(free_space_session)
    restarted = TwoStepEstimator(fs, corr).predict_batch(js).predicted_torque
    carried = TwoStepEstimator(fs, corr, EstimatorConfig(max_gap_s=1.0, max_jump=None)
                               ).predict_batch(js)
    assert not carried.restarted[120]
    assert np.abs(restarted[120:130] - carried.predicted_torque[120:130]).max() > 1e-4


def _spliced(session, n=300, at=150, by=0.3):
    """The first ``n`` samples, the first joint's position moved ``by`` [rad] from ``at`` on:
    two recordings played one after the other, or an encoder re-zeroed."""
    js = session.joint_states.slice(0, n)
    q = js.position.copy()
    q[at:, 0] += by
    return JointStates(js.t, q, js.velocity, js.effort)


@pytest.mark.parametrize("mode", ["base", "corr"])
def test_a_position_jump_restarts_streaming_and_batch_alike(mode, models_f64,
                                                             free_space_session):
    fs, corr, _ = models_f64
    est = TwoStepEstimator(fs, corr if mode == "corr" else None)
    js = _spliced(free_space_session)
    batch = est.predict_batch(js)
    streamed = _stream(est, js)
    assert streamed["restarted"].nonzero()[0].tolist() == [0, 150]
    np.testing.assert_array_equal(streamed["restarted"], batch.restarted)
    np.testing.assert_allclose(streamed["predicted_torque"], batch.predicted_torque, atol=1e-10)
    many = est.step_many(js.t[:200], js.position[:200], js.velocity[:200], js.effort[:200])
    assert [o.restarted for o in many].index(True, 1) == 150
    off = TwoStepEstimator(fs, None, EstimatorConfig(max_jump=None)).predict_batch(js)
    assert not off.restarted[150]
    # a jump under the bound is motion: the recording's own steps never restart
    assert not TwoStepEstimator(fs).predict_batch(_spliced(free_space_session, by=0.01)
                                                  ).restarted[1:].any()


def test_reset_state_and_time_going_back_restart(models_f64, free_space_session):
    fs, corr, _ = models_f64
    est = TwoStepEstimator(fs, corr)
    js = free_space_session.joint_states.slice(0, 40)
    first = _stream(est, js)["predicted_torque"]
    for t, q, dq, e in zip(js.t, js.position, js.velocity, js.effort):
        est.step_one(t, q, dq, e)
    again = est.step_one(js.t[0], js.position[0], js.velocity[0], js.effort[0])
    assert again.restarted
    np.testing.assert_array_equal(again.predicted_torque, first[0])


def test_rejects_bad_input_and_mismatched_xfer(models_f64):
    fs, _, _ = models_f64
    est = TwoStepEstimator(fs)
    with pytest.raises(DataError):
        est.step_one(0.0, np.zeros(6), np.zeros(5), np.zeros(6))
    with pytest.raises(DataError):
        est.step_one(0.0, np.full(6, np.nan), np.zeros(6), np.zeros(6))
    with pytest.raises(ConfigError):
        TwoStepEstimator(fs, Xfer(base=FreeSpaceModel()))
    with pytest.raises(ConfigError):
        TwoStepEstimator(fs, "corr")



def test_shared_step1_kernel_keeps_streams_apart(models_f64, free_space_session):
    """Two estimators streaming different data through one shared step-1 kernel, interleaved,
    give what each gives alone (the kernel holds weights only; each keeps its own state)."""
    fs, corr, xfer = models_f64
    js = free_space_session.joint_states.slice(0, 120)
    other = free_space_session.joint_states.slice(200, 320)
    alone = _stream(TwoStepEstimator(fs, corr), js)
    a, b = TwoStepEstimator(fs, corr), TwoStepEstimator(fs, corr)
    b.share_step1(a)
    out = []
    for i in range(len(js)):
        out.append(a.step_one(js.t[i], js.position[i], js.velocity[i], js.effort[i]).wrench)
        b.step_one(other.t[i], other.position[i], other.velocity[i], other.effort[i])
    np.testing.assert_array_equal(np.array(out), alone["wrench"])
    with pytest.raises(ConfigError):
        TwoStepEstimator(fs, xfer).share_step1(a)


def test_swapping_a_state_dict_serves_like_swapping_the_module(models_f64, free_space_session):
    """The daemon swaps the adaptation worker's weights as NumPy arrays (no torch module on
    the estimating thread); the estimates must be those of a swapped-in module, and the
    module, asked for, must be that net."""
    fs, corr, _ = models_f64
    other = copy.deepcopy(corr)
    with torch.no_grad():
        for p in other.parameters():
            p.mul_(0.5)
    state = {k: v.detach().numpy().copy() for k, v in other.state_dict().items()}
    js = free_space_session.joint_states.slice(0, 60)
    by_module, by_state = TwoStepEstimator(fs, corr), TwoStepEstimator(fs, corr)
    outs = []
    for est, swap in ((by_module, lambda e: e.swap_correction(other)),
                      (by_state, lambda e: e.swap_correction_state(state))):
        est.reset_state()
        rows = []
        for i, (t, q, dq, e) in enumerate(zip(js.t, js.position, js.velocity, js.effort)):
            if i == 30:
                swap(est)                                   # mid-stream: the state carries on
            rows.append(est.step_one(t, q, dq, e).predicted_torque)
        outs.append(np.array(rows))
    np.testing.assert_array_equal(outs[0], outs[1])
    # the swap changed the estimates from its sample on, and only from there
    unswapped = _stream(TwoStepEstimator(fs, corr), js)["predicted_torque"]
    np.testing.assert_array_equal(outs[0][:30], unswapped[:30])
    assert (outs[0][30:] != unswapped[30:]).any(axis=1).all()
    assert by_state.mode == "corr"
    for k, v in by_state.correction.state_dict().items():
        np.testing.assert_array_equal(v.numpy(), state[k])
    with pytest.raises(ConfigError):
        TwoStepEstimator(fs).swap_correction_state(state)


def test_streams_stepped_together_one_sample_each_get_what_each_gets_alone(
        models_f64, free_space_session):
    """Three streams sharing one step-1 kernel, a sample each per step (the daemon's arms at
    one rate): the first sample of a stream joining late, a gap on one, a position jump on
    another and a step one stream takes alone in between restart as they would alone, and
    every output is the lone stream's."""
    fs, corr, _ = models_f64
    js = [_with_gap(free_space_session, n=160, gap_at=60), _spliced(free_space_session),
          free_space_session.joint_states.slice(300, 460)]
    alone = [_stream(TwoStepEstimator(fs, corr), s) for s in js]
    ests = [TwoStepEstimator(fs, corr) for _ in js]
    for e in ests[1:]:
        e.share_step1(ests[0])
    got = [[] for _ in js]
    for i in range(160):
        active = [k for k in range(3) if not (k == 2 and i < 30)]     # the third joins at 30
        if i == 100:                                   # one step of stream 0 on its own
            got[0].append(ests[0].step_one(js[0].t[i], js[0].position[i], js[0].velocity[i],
                                           js[0].effort[i]))
            active = [1, 2]
        outs = TwoStepEstimator.step_many_joint(
            [ests[k] for k in active],
            [(js[k].t[i:i + 1], js[k].position[i:i + 1], js[k].velocity[i:i + 1],
              js[k].effort[i:i + 1]) for k in active])
        for k, out in zip(active, outs):
            got[k].append(out[0])
    for k, lone in enumerate(alone):
        first = 30 if k == 2 else 0
        restarted = np.array([o.restarted for o in got[k]])
        expected = lone["restarted"][:160].copy()
        if k == 2:                                     # its first step is a fresh start
            expected = np.r_[True, _stream(TwoStepEstimator(fs, corr), js[2].slice(30, 160)
                                           )["restarted"][1:]]
            lone = _stream(TwoStepEstimator(fs, corr), js[2].slice(30, 160))
        np.testing.assert_array_equal(restarted, expected)
        wrench = np.array([o.wrench for o in got[k]])
        # the joint path hands Corr its step-1 torques in float32: equal to its rounding
        np.testing.assert_allclose(wrench, lone["wrench"][:160 - first], rtol=1e-5, atol=1e-5)
    assert restarted.sum() == 1 and np.array([o.restarted for o in got[0]]).sum() == 2
    assert np.array([o.restarted for o in got[1]]).sum() == 2


def test_the_jump_check_is_numpys_formula(models_f64):
    """The streaming jump check in Python floats decides as the array formula does."""
    est = TwoStepEstimator(models_f64[0])
    limit = np.asarray(est.config.max_jump)
    rng = np.random.default_rng(7)
    for _ in range(2000):
        est._t_last, t = 1.0, 1.0 + rng.uniform(1e-4, 0.05)
        est._q_last, est._dq_last = rng.normal(size=6) * 0.5, rng.normal(size=6)
        dq = rng.normal(size=6)
        q = est._q_last + (dq + est._dq_last) * 0.5 * (t - 1.0) + rng.normal(size=6) * limit
        moved = q - est._q_last - (dq + est._dq_last) * (0.5 * (t - est._t_last))
        assert est._jumped(t, q, dq) == bool((np.abs(moved) > limit).any())
