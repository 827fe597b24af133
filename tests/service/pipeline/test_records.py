"""Event kinds are one enum whose members read as the strings logs carry."""

import json

import pytest

from wrenchd.service.pipeline.records import Event, EventKind


def test_a_kind_read_back_as_a_string_becomes_the_enum_and_serialises_as_the_string():
    e = Event(1.5, "drift", {"arm": "PSM1"})
    assert e.kind is EventKind.DRIFT and e.kind == "drift"
    assert json.loads(json.dumps(e.to_json())) == {"t": 1.5, "kind": "drift", "arm": "PSM1"}


def test_an_unknown_kind_is_refused():
    with pytest.raises(ValueError, match="'drfit'"):
        Event(0.0, "drfit", {})
