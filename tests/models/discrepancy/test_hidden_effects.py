"""The quick subset of the hidden-effect suite (the full table: reports/discrepancy/).

Each case simulates 30 s of free motion with an effect the given model lacks (random
magnitude in its realistic range, see service/hidden_effects.py) and requires: the effect
named first, its parameters within the stated tolerance, and the held-out gap shrunk by at
least half. With nothing hidden, nothing may be named; with two hidden, both.
"""

import json

import pytest

from wrenchd.models.discrepancy.workflow import run_discrepancy
from wrenchd.service.studies.hidden_effects import judge, make_case


def _run(hidden, seed):
    case = make_case(hidden, seed, 30.0)
    js = case.session.joint_states
    res = run_discrepancy(case.given, js.t, js.position, js.velocity, js.effort)
    return case, res, judge(case, res)


@pytest.mark.parametrize("hidden,seed", [
    (("payload_mass",), 101), (("seal_friction",), 102), (("drift",), 103),
])
def test_hidden_effect_is_named_first_with_its_parameters_and_the_gap_shrinks(hidden, seed):
    case, res, verdict = _run(hidden, seed)
    assert verdict["named"][:1] == list(hidden), verdict
    per = verdict["per_effect"][0]
    assert per["params_ok"], per["checks"]
    assert per["shrink"] >= 0.5, per
    out = res.to_json("model.json")
    assert out["effects"][0]["name"] == hidden[0]
    assert all(a <= b * 1.001 for a, b in zip(out["gap"]["after_rmse"], out["gap"]["before_rmse"]))
    json.dumps(out)                                   # the contract is JSON-serialisable
    # the updated model carries the named effect (in-sample it explains the hidden torque)
    motion = res.updated_model.motion(res.t, res.q, res.dq, res.ddq)
    tau = case.session.joint_states.effort - res.updated_model.torque(motion)
    assert all(x < 1.5 * f for x, f in zip((tau**2).mean(axis=0) ** 0.5, res.floor)), res.floor


def test_nothing_hidden_names_nothing():
    _, res, verdict = _run((), 106)
    assert verdict["named"] == [], verdict
    out = res.to_json(None)
    assert out["effects"] == [] and out["disagreements"] == []


def test_two_hidden_effects_are_both_named():
    _, _, verdict = _run(("payload_mass", "seal_friction"), 107)
    assert set(verdict["named"][:2]) == {"payload_mass", "seal_friction"}, verdict
    assert all(p["params_ok"] and p["shrink"] >= 0.5 for p in verdict["per_effect"]), verdict
