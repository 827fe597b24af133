"""Lifelong adaptation on the simulator's insufflation change.

``insufflation-change`` (220 s, seed 3): 60 s contact-free calibration, contacts every ~20 s
after it, the pressure steps 12 -> 20 mmHg at 88 s. Replayed through the daemon's pipeline
(gated policy, inline adaptation in sample time) and with the ``frozen`` policy.

The daemon issue asks for more than this test checks, and wrenchd does not meet it yet
(measured, see the issue note): the free-motion error 60 s after the change is back within
10 % of its level before the change (measured: ~1.5x), and *no* contact sample ever trains
(measured: 0 to ~0.5 % of the offered samples, from contacts whose joint-torque signature
stays under the gate's bound). What this test holds the pipeline to: adaptation makes the
free-motion error after the change clearly lower than the frozen net's, the change is real
(the frozen error grows), and contamination stays under 1 % of the offered samples.
"""

import numpy as np
import pytest

from adapters.sim.scenarios import run_scenario
from models.estimator.pretrained import load_pretrained
from service.pipeline import PipelineConfig, PolicyConfig
from service.replay import replay

DURATION, SEED = 220.0, 3
CHANGE_S = 0.4 * DURATION


@pytest.fixture(scope="module")
def session():
    return run_scenario("insufflation-change", DURATION, SEED)


def levels(session, result) -> tuple[float, float]:
    truth = session.truth
    t = result.t
    err = np.linalg.norm(result.wrench[:, :3] - truth.external_wrench[result.sample, :3], axis=1)
    free = ~truth.in_contact[result.sample]
    pre = free & (t >= CHANGE_S - 40.0) & (t < CHANGE_S)
    after = np.flatnonzero(free & (t >= CHANGE_S))
    t60 = t[after[60 * 200]]                       # 60 s of free motion after the change
    post = free & (t >= t60) & (t < t60 + 40.0)
    rms = lambda m: float(np.sqrt(np.mean(err[m] ** 2)))  # noqa: E731
    return rms(pre), rms(post)


def test_gated_adaptation_recovers_from_the_insufflation_change(session):
    seal = load_pretrained("seal")
    frozen = replay(session, seal, PipelineConfig(policy=PolicyConfig(name="frozen")),
                    step1="torch")
    f_pre, f_post = levels(session, frozen)
    assert f_post > 1.1 * f_pre, (f_pre, f_post)          # the change matters

    gated = replay(session, seal, PipelineConfig(), step1="torch")
    pre, post = levels(session, gated)
    assert post < 0.7 * f_post, (post, f_post)             # adaptation pays after the change
    assert pre < 0.7 * f_pre, (pre, f_pre)                 # and before it (calibration)
    assert gated.status["counters"]["swaps"] > 0

    idx = np.searchsorted(session.joint_states.t, gated.offered_t)
    np.testing.assert_allclose(session.joint_states.t[idx], gated.offered_t, atol=1e-9)
    assert len(idx) > 10_000
    assert session.truth.in_contact[idx].mean() < 0.01
