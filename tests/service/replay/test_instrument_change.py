"""An instrument change announced to the pipeline, on real data: the WPI recording without a
load followed by the same trajectory with 105 g on the parallelogram (a payload appearing, as
when a heavier instrument is mounted). Both are free motion, so the estimated external torque
on joints 1-2 should be zero: its RMS in windows is the error. Step 1 is a quick hybrid fitted
on the first recording only.

Measured (this test's set-up): before the change 0.028 / 0.040 N m (joints 1 / 2, 15-30 s);
after it, announced: 0.092 / 0.090 (0-10 s), 0.031 / 0.042 (10-20 s), 0.032 / 0.044 (20-30 s),
first swap 1.7 s after the change. Not announced: the gate takes the payload for a lasting
contact, nothing is offered, and the drift detector, fed free samples only, does not fire.
Its tip-form check (``gate.tip_setup_s``) takes it for a set-up change 3.1 s after it (a
weight on a link is no force at the tip, and its tip force swings with the pose): 0.070 /
0.137, 0.054 / 0.090, 0.035 / 0.052, first swap 9.2 s after. Without that check the gate
waits for ``setup_contact_s``: found 10.1 s after, 0.071 / 0.137, 0.069 / 0.119, 0.047 /
0.086, first swap 16.1 s after.
"""

from __future__ import annotations

import numpy as np
import pytest

from wrenchd.adapters.csv_psm import read_wpi_csv
from wrenchd.models.estimator.hybrid import HybridConfig, ResidualNetConfig, fit_hybrid
from wrenchd.models.series import JointStates, Session
from wrenchd.service.pipeline import PipelineConfig
from wrenchd.service.replay.loop import replay

GAP_S = 0.1        # between the two recordings [s]


@pytest.fixture(scope="module")
def swap(wpi_data):
    """(step 1, session, time of the change [s])."""
    before, _ = read_wpi_csv(wpi_data / "one_no_weight.csv")
    after, _ = read_wpi_csv(wpi_data / "one_105g_parallel.csv")
    t_change = float(before.t[-1]) + GAP_S
    js = JointStates(np.concatenate([before.t, after.t + t_change]),
                     np.concatenate([before.position, after.position]),
                     np.concatenate([before.velocity, after.velocity]),
                     np.concatenate([before.effort, after.effort]))
    step1 = fit_hybrid([before], HybridConfig(residual=ResidualNetConfig(epochs=30)))
    return step1, Session(js, metadata={"source": "wpi one_no_weight + one_105g_parallel"}), \
        t_change


def windows(result, t_change: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """RMS [N m] of the estimated external torque on joints 1-2: 15 s before the change, and
    in 10 s windows after it."""
    ext = result.external[:, :2]

    def rms(a: float, b: float) -> np.ndarray:
        m = (result.t >= a) & (result.t < b)
        assert m.sum() > 1000
        return np.sqrt(np.mean(ext[m] ** 2, axis=0))

    return rms(t_change - 15.0, t_change), [rms(t_change + k, t_change + k + 10.0)
                                           for k in (0.0, 10.0, 20.0)]


def test_an_announced_instrument_change_recovers_within_thirty_seconds(swap):
    step1, session, t_change = swap
    config = PipelineConfig(calibration_s=10.0)
    silent = replay(session, step1, config, policy="gated")
    pre, post = windows(silent, t_change)
    assert np.all(pre < 0.06), pre
    for w in post[:2]:                   # the payload stays in the estimate: 2-3x
        assert np.all(w > 1.6 * pre), (pre, w)

    announced = replay(session, step1, config, policy="gated",
                       setup_changes=[(t_change, {"kind": "instrument", "note": "105 g"})])
    a_pre, a_post = windows(announced, t_change)
    np.testing.assert_allclose(a_pre, pre, rtol=1e-6)    # the same run up to the change
    for w in a_post[1:]:                 # back near the pre-change level 10-30 s after it
        assert np.all(w < 1.3 * pre), (pre, w)
    assert a_post[0][1] < 0.9 * post[0][1], (a_post[0], post[0])
    (change,) = [e for e in announced.events if e.kind == "setup_change"]
    assert change.t == pytest.approx(t_change) and change.detail["kind"] == "instrument"
    assert change.detail["carry_over"] is False
    calibrated = [e.t for e in announced.events if e.kind == "calibrated"]
    assert len(calibrated) == 2 and calibrated[1] == pytest.approx(t_change + 10.0, abs=0.1)
    # unannounced, the gate takes the lasting payload for a set-up change by its form within
    # seconds, by its swing alone once it has lasted setup_contact_s; the announced run trains
    # on the new instrument sooner still
    (found,) = [e for e in silent.events if e.kind == "gate_setup_change"]
    assert found.detail["tip_form"] and t_change < found.t <= t_change + 3 * config.gate.tip_setup_s
    swing_only = replay(session, step1, config.model_copy(update={
        "gate": config.gate.model_copy(update={"tip_setup_s": 0.0})}), policy="gated")
    (late,) = [e for e in swing_only.events if e.kind == "gate_setup_change"]
    assert not late.detail["tip_form"]
    assert t_change + config.gate.setup_contact_s <= late.t <= t_change + config.gate.setup_contact_s + 2

    def first_swap(r) -> float:
        return min(e.t for e in r.events if e.kind == "model" and e.t > t_change)
    assert first_swap(announced) < first_swap(silent) < first_swap(swing_only)
    _, slow = windows(swing_only, t_change)
    assert np.all(post[2] < slow[2]), (post[2], slow[2])


def test_an_unknown_kind_is_refused(swap):
    step1, session, t_change = swap
    short = Session(JointStates(*(a[:2400] for a in (session.joint_states.t,
                                                     session.joint_states.position,
                                                     session.joint_states.velocity,
                                                     session.joint_states.effort))))
    r = replay(short, step1, PipelineConfig(calibration_s=2.0), policy="gated",
               setup_changes=[(5.0, {"kind": "trocar"})])
    assert not [e for e in r.events if e.kind == "setup_change"]
    (err,) = [e for e in r.events if e.kind == "error" and e.detail.get("error") == "setup"]
    assert "trocar" in err.detail["reason"]
