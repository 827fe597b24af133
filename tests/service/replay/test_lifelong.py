"""Lifelong adaptation on the simulator's insufflation change.

``insufflation-change`` (220 s, seed 3): a contact-free 60 s calibration, contacts every ~20 s
after it, the pressure steps 12 -> 20 mmHg at 88 s. Replayed through the daemon's pipeline
(gated policy; replay's default adaptation: rounds in a forked worker, in sample time) and
with the ``frozen`` policy.

What these tests hold: no offered sample is truly in contact; adaptation makes the
free-motion error after the change clearly lower than the frozen net's (and the change is
real: the frozen error grows); 60 s after the change the error is within 1.20x its level
before it from the data alone, and within 1.10x when the change is announced (the daemon's
``setup`` key: the adapter carries its buffer over to the body wall stiffness it measures).
The bounds leave a margin over one machine's figures, since adapted nets differ between
machines in their last bits; the figures over scenario seeds 3-8 and three adaptation seeds
come from ``wrenchd recovery`` (docs/results.md).
"""

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import run_scenario
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.service.pipeline import PipelineConfig, PolicyConfig
from wrenchd.service.replay.loop import replay
from wrenchd.service.replay.metrics import recovery_levels

DURATION, SEED = 220.0, 3
CHANGE_S = 0.4 * DURATION


@pytest.fixture(scope="module")
def session():
    return run_scenario("insufflation-change", DURATION, SEED)


def levels(session, result) -> tuple[float, float]:
    return recovery_levels(result, session, CHANGE_S)


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
    assert post < 1.20 * pre, (pre, post)                  # target 1.10: see the docstring

    idx = np.searchsorted(session.joint_states.t, gated.offered_t)
    np.testing.assert_allclose(session.joint_states.t[idx], gated.offered_t, atol=1e-9)
    assert len(idx) > 10_000
    assert not session.truth.in_contact[idx].any(), int(session.truth.in_contact[idx].sum())


def test_an_announced_change_is_recovered_within_ten_percent(session):
    """Back within 10 % when the daemon is told of the change (its ``setup`` key; here the
    replay announces the scenario's step at its time): the adapter carries its buffer over to
    the body wall stiffness it measures after the change (models/body_wall_tracker.py).
    Seeds 3-8: ``wrenchd recovery --settled --announce`` (docs/results.md)."""
    from wrenchd.service.replay.source import announced_changes

    changes = announced_changes(session)
    assert [t for t, _ in changes] == [pytest.approx(CHANGE_S)]
    seal = load_pretrained("seal")
    r = replay(session, seal, PipelineConfig(), step1="torch", setup_changes=changes)
    pre, post = levels(session, r)
    assert post <= 1.10 * pre, (pre, post)
    assert r.status["counters"]["setup_changes"] == 1
    assert [e.t for e in r.events if e.kind == "setup_change"] == [pytest.approx(CHANGE_S)]
    # the tracker saw the wall stiffen (truth: 580 -> 900 N/m; its level is biased by the
    # free-space net's misfit, the step much less). The gate takes a 2.3 N grasp at 205 s for
    # a set-up change by its form (gate.tip_setup_s; docs/results.md), which starts a third
    # segment after the two compared here
    before, after = r.status["body_wall"]["stiffness_n_per_m"][:2]
    assert 150.0 < after - before < 600.0, (before, after)
    idx = np.searchsorted(session.joint_states.t, r.offered_t)
    assert not session.truth.in_contact[idx].any(), int(session.truth.in_contact[idx].sum())
