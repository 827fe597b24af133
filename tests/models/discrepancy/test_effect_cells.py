"""The effect-cell study's quick subset (the full confusion table: reports/discrepancy/).

The places the hidden-effect study did not reach: a load on the insertion stage and a spring
along the insertion are named there, with their size; a load on the yaw link is named on the
parallelogram; where two kinds make the same torque (wrist friction and the cable coupling)
the workflow says so.
"""

import json

import numpy as np
import pytest

from wrenchd.models.discrepancy.workflow import run_discrepancy
from wrenchd.service.studies.effect_cells import (
    CLASSES,
    classify,
    effect_cell_study,
    make_cell_case,
)
from wrenchd.service.studies.hidden_effects import NOISE_STD


def _run(kind, place, multiple, seed=9000):
    case = make_cell_case(kind, place, multiple, seed)
    js = case.session.joint_states
    res = run_discrepancy(case.given, js.t, js.position, js.velocity, js.effort, seed=seed)
    return case, res, classify(case, res)


def test_a_cell_is_sized_in_noise_floors_on_its_strongest_joint():
    case = make_cell_case("spring", 3, 5.0, 9001)
    rms = np.sqrt(np.mean(case.effect_torque**2, axis=0)) / NOISE_STD
    assert case.strongest_joint == 2 and rms[2] == pytest.approx(5.0, rel=1e-9)
    assert np.all(rms[[0, 1, 3, 4, 5]] == 0.0)


@pytest.mark.parametrize("kind,place", [("payload_mass", 3), ("spring", 3)])
def test_insertion_stage_load_and_insertion_spring_are_named_with_their_size(kind, place):
    case, res, row = _run(kind, place, 5.0)
    assert row["class"] == "right", row
    assert row["named"][0] == ("payload_mass@link3" if kind == "payload_mass" else "spring")
    assert row["named_size"] == pytest.approx(case.value, rel=0.05)
    assert row["told_apart"] is True


def test_a_load_on_the_yaw_link_is_named_on_the_parallelogram():
    """The yaw link is no payload site (candidates.PAYLOAD_SITES says why): its load is
    named on link 2, a wrong place the cell table counts."""
    _, _, row = _run("payload_mass", 1, 5.0)
    assert row["class"] == "wrong place" and row["named_place"] == 2, row


def test_friction_on_the_wrist_pitch_is_named_and_flagged_as_the_cable_coupling_alike():
    """Coulomb friction on wrist pitch alone and the cable-coupled motor friction make the
    same torque on this motion: the per-joint candidate, counted by its supported column, is
    named, and the workflow says it cannot tell it from the coupling."""
    _, res, row = _run("coulomb_friction", 5, 5.0)
    assert row["class"] == "right", row
    first = res.to_json(None)["effects"][0]
    assert first["told_apart"] is False
    assert [a["label"] for a in first["alternatives"] if a["indistinguishable"]] == ["cable_coupling"]


def test_the_study_writes_its_confusion_table(tmp_path):
    data = effect_cell_study(tmp_path, 1, 30.0, cells=[("joint_offset", 2)], multiples=(5.0,),
                             log=lambda _: None)
    assert data["summary"]["controls"] == 1                 # one per seed and multiple
    assert data["summary"]["controls_named_something"] == 0
    saved = json.loads((tmp_path / "effect-cells.json").read_text())
    assert saved["confusion"] == data["confusion"]
    counts = data["confusion"]["joint_offset@2"]["5"]
    assert set(counts) == set(CLASSES) and sum(counts.values()) == 1
    text = (tmp_path / "effect-cells.md").read_text()
    assert "| joint_offset@2 |" in text and "--cells --seeds 1" in text
