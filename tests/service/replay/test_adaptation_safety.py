"""Adaptation safety: long contacts and an adversarial publisher must not spoil the model,
and it is the gate that keeps them out.

Each session is simulated ``trocar`` motion (seal and body wall at 12 mmHg) replayed through
the daemon's own pipeline (``wrenchd.service.replay.loop.replay``, adaptation rounds in
replay's worker with their nets serving 1 s of sample time later, as in the daemon;
deterministic on one machine): a contact-free calibration of ``CAL_S``, then from
``ATTACK_S`` on something the adaptation must not learn from:

* a **long contact**: the tip holds a grasped handle for 24 s (up to 8 N);
* a **replayed trajectory**: the publisher switches to a recording of another arm
  (``deploy/models/trocar-heavy-seal.json``: stiffer seal, higher pressure, a payload)
  grasping a handle for 24 s;
* a **second publisher** on the same key, interleaving that recording with the robot's
  samples 2.5 ms apart (what any process on an open zenoh network can do; the router's ACL in
  ``deploy/zenoh/router.json5`` is what forbids it);
* an **effort ramp**: the published efforts drift away from the truth by up to 0.15 N m on
  yaw and pitch and 0.6 N on insertion over 20 s, then stay off (a false tip force of about
  2 N through ``J^-T``; within every validation bound).

The model serving when the attack begins (``pre``) and at the end of the session (``post``)
are scored on a clean held-out ``trocar`` session (another trajectory): free-motion force
RMSE. **Bound**: ``post <= 1.2 * pre`` and ``post <= frozen`` (the net before any
adaptation). Each of the first three cases replays the same session twice, with the gated
policy (the daemon's) and with ``ungated`` (every sample trains): the gated model stays
within the bound and the ungated one leaves it, so the bound holds because of the gate.
Measured ``post / pre`` (``pytest -s`` prints them), gated / ungated: long contact 1.00 /
2.27, replayed trajectory 1.00 / 3.51, second publisher 1.00 / 1.69 (the ungated ratio of
the second publisher depends on the recording: 1.28, 1.69, 1.57 for recordings of seeds 8,
9, 10; this test uses 9). The gate protects by calling the attack a contact: no swap happens
after it. A contact longer than the gate's ``max_contact_s`` re-calibrates the gate, and
nothing is trainable for another ``max_contact_s`` after that: with 15 s the 24 s contact
offers no contact sample and the ratio stays 1.00.

The effort ramp does not show the gate's effect: the gate cannot tell a slow drift of the
published efforts from instrument wear, which it must follow. Gated 0.92, ungated 0.76 (a
ramp within the validation bounds helps a model calibrated for 20 s either way); three
times that ramp (about 6 N of false force) held for 20 s breaks both (gated 1.56, ungated
2.19, 65 s session, not in the suite). What keeps such a publisher out is the router's
access control.

Every case also checks that each model swap carries ``val_before`` and ``val_after`` with
``val_after < val_before``: a swap that raises validation error never happens.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from wrenchd.adapters.sim.scenarios import SCENARIOS, run_scenario
from wrenchd.models.estimator.correction import Corr
from wrenchd.models.estimator.estimator import TwoStepEstimator
from wrenchd.models.estimator.pretrained import load_pretrained
from wrenchd.models.physics.model import PhysicsModel
from wrenchd.models.series import JointStates, Session
from wrenchd.service.pipeline import PipelineConfig, PolicyConfig, initial_corr
from wrenchd.service.replay.loop import ReplayResult, replay

CAL_S, ATTACK_S, DURATION_S, SEED = 20.0, 25.0, 50.0, 7
BOUND = 1.2                            # post-attack held-out error / pre-attack, at most
RAMP = np.array([0.15, 0.15, 0.6, 0.0, 0.0, 0.0])     # [N m, N m, N, N m, N m, N m]
HEAVY = Path(__file__).resolve().parents[3] / "deploy" / "models" / "trocar-heavy-seal.json"


@pytest.fixture(scope="module")
def seal():
    return load_pretrained("seal")


@pytest.fixture(scope="module")
def clean() -> Session:
    """The held-out judge: contact-free trocar motion the sessions never saw."""
    return run_scenario("trocar", 30.0, 99)


@pytest.fixture(scope="module")
def robot() -> Session:
    return run_scenario("trocar", DURATION_S, SEED)


@pytest.fixture(scope="module")
def other_setup() -> Session:
    """Another trajectory on another set-up, grasping a handle for 24 s from ``ATTACK_S``:
    what the attacker replays."""
    grasp = {"name": "external_contact",
             "params": {"episodes": [[ATTACK_S, ATTACK_S + 24.0]]}}
    heavy = json.loads(HEAVY.read_text())
    heavy["effects"] = [e for e in heavy["effects"] if e["name"] != "external_contact"] + [grasp]
    return run_scenario("trocar", DURATION_S, SEED + 2, model=PhysicsModel.from_dict(heavy))


def config(policy: str = "gated", **gate) -> PipelineConfig:
    return PipelineConfig(calibration_s=CAL_S, gate=gate, policy=PolicyConfig(name=policy))


def run(session: Session, seal, cfg: PipelineConfig) -> tuple[ReplayResult, list]:
    """Replay; also every swapped-in Corr with the time [s] of the sample it came after."""
    swaps: list[tuple[float, object]] = []

    def record_swaps(pipeline):
        est = pipeline.estimator
        swap = est.swap_correction_state

        def recorded(state, kernel=None):
            corr = Corr.from_state(est.correction.config, state)
            swaps.append((float(est.t[est.cursor - 1]), corr))
            swap(state, kernel)
        est.swap_correction_state = recorded

    result = replay(session, seal, cfg, step1="torch", pipeline_hook=record_swaps)
    return result, swaps


def serving_at(swaps: list, t: float, cfg: PipelineConfig):
    corr = initial_corr(cfg.adaptation)
    for when, c in swaps:
        if when < t:
            corr = c
    return corr


def held_out_error(seal, corr, clean: Session, cfg: PipelineConfig) -> float:
    """Free-motion force RMSE [N] of step 1 + ``corr`` on the clean session."""
    out = TwoStepEstimator(seal, corr, cfg.estimator).predict_batch(clean.joint_states)
    err = out.wrench[:, :3] - clean.truth.external_wrench[:, :3]
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))


def judge(name: str, session: Session, seal, clean: Session, cfg: PipelineConfig):
    """Replay ``session``; the model before and after the attack on the clean session."""
    result, swaps = run(session, seal, cfg)
    models = [e.detail for e in result.events if e.kind == "model"]
    assert models and len(models) == result.status["counters"]["swaps"]
    for m in models:                                    # validated swaps only
        assert np.isfinite(m["val_before"]) and np.isfinite(m["val_after"]), m
        assert m["val_after"] < m["val_before"], m
    pre = held_out_error(seal, serving_at(swaps, ATTACK_S, cfg), clean, cfg)
    post = held_out_error(seal, serving_at(swaps, np.inf, cfg), clean, cfg)
    frozen = held_out_error(seal, initial_corr(cfg.adaptation), clean, cfg)
    print(f"{name}: held-out free-motion force RMSE before the attack {pre:.3f} N, after "
          f"{post:.3f} N (ratio {post / pre:.2f}), frozen {frozen:.3f} N; "
          f"{len(models)} swaps, {sum(w >= ATTACK_S for w, _ in swaps)} after the attack")
    return result, pre, post, frozen


def within_bound(pre: float, post: float, frozen: float) -> bool:
    return post <= BOUND * pre and post <= frozen


def gated_and_ungated(name: str, session: Session, seal, clean: Session) -> ReplayResult:
    """The gated model stays within the bound on ``session``; the ungated one, on the same
    session, leaves it. The gated replay's result."""
    result, pre, post, frozen = judge(f"{name}, gated", session, seal, clean, config())
    assert within_bound(pre, post, frozen), (pre, post, frozen)
    _, pre_u, post_u, frozen_u = judge(f"{name}, ungated", session, seal, clean,
                                       config("ungated"))
    assert not within_bound(pre_u, post_u, frozen_u), (pre_u, post_u, frozen_u)
    return result


def with_joint_states(session: Session, js: JointStates) -> Session:
    return dataclasses.replace(session, joint_states=js, truth=None)


@pytest.fixture(scope="module")
def long_contact() -> Session:
    """The robot's own motion with one 24 s grasp from ``ATTACK_S``."""
    effects = SCENARIOS["trocar"].effects(DURATION_S) + [{
        "name": "external_contact", "params": {"episodes": [[ATTACK_S, ATTACK_S + 24.0]]}}]
    model = PhysicsModel.from_dict({"description": "trocar with one 24 s contact",
                                    "effects": effects})
    return run_scenario("trocar", DURATION_S, SEED, model=model)


def test_a_long_contact_trains_only_without_the_gate(long_contact, seal, clean):
    session = long_contact
    result = gated_and_ungated("24 s contact", session, seal, clean)
    offered = np.searchsorted(session.joint_states.t, result.offered_t)
    assert session.truth.in_contact[offered].mean() < 0.01


def test_a_contact_longer_than_max_contact_s_stays_out_of_training(long_contact, seal, clean):
    """The gate re-calibrates 15 s into the 24 s contact; the rest of it is not trainable."""
    session = long_contact
    result, pre, post, frozen = judge("24 s contact, max_contact_s 15", session, seal, clean,
                                      config(max_contact_s=15.0))
    assert "gate_recalibrated" in [e.kind for e in result.events]
    offered = np.searchsorted(session.joint_states.t, result.offered_t)
    assert not session.truth.in_contact[offered].any()
    assert within_bound(pre, post, frozen), (pre, post, frozen)


def test_a_replayed_trajectory_trains_only_without_the_gate(robot, other_setup, seal, clean):
    js, other = robot.joint_states, other_setup.joint_states
    k = int(np.searchsorted(js.t, ATTACK_S))
    switched = JointStates(js.t, np.r_[js.position[:k], other.position[k:]],
                           np.r_[js.velocity[:k], other.velocity[k:]],
                           np.r_[js.effort[:k], other.effort[k:]], js.names)
    result = gated_and_ungated("replayed trajectory", with_joint_states(robot, switched), seal,
                               clean)
    assert result.status["counters"]["errors"] == 0          # plausible: nothing refused


def test_a_second_publisher_trains_only_without_the_gate(robot, other_setup, seal, clean):
    js, other = robot.joint_states, other_setup.joint_states
    k = int(np.searchsorted(js.t, ATTACK_S))
    t = np.r_[js.t, other.t[k:] + 0.0025]
    order = np.argsort(t, kind="stable")

    def merged(a, b):
        return np.r_[a, b[k:]][order]
    both = JointStates(t[order], merged(js.position, other.position),
                       merged(js.velocity, other.velocity), merged(js.effort, other.effort),
                       js.names)
    result = gated_and_ungated("second publisher", with_joint_states(robot, both), seal, clean)
    assert result.status["counters"]["estimated"] == len(both)    # all of it got through


def test_an_effort_ramp_does_not_spoil_the_gated_model(robot, seal, clean):
    """Not a test of the gate (see the module docstring): the bound on a slow drift of the
    published efforts, which adaptation follows as it follows instrument wear."""
    js = robot.joint_states
    ramp = np.clip((js.t - ATTACK_S) / 20.0, 0.0, 1.0)[:, None] * RAMP
    attacked = with_joint_states(robot, dataclasses.replace(js, effort=js.effort + ramp))
    result, pre, post, frozen = judge("effort ramp", attacked, seal, clean, config())
    assert result.status["counters"]["errors"] == 0          # plausible: nothing refused
    assert within_bound(pre, post, frozen), (pre, post, frozen)
