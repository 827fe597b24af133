"""The kind of an announced set-up change: its message, and what the adapter does with it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from wrenchd.adapters.messages import decode_setup_change, encode_setup_change
from wrenchd.models.adaptation import Adapter, AdaptationConfig
from wrenchd.models.errors import DataError


def test_kind_round_trip_and_refusals():
    assert decode_setup_change(encode_setup_change(kind="instrument")) == \
        (None, {"kind": "instrument"})
    stamp, detail = decode_setup_change(encode_setup_change(2_000_000_000, instrument="LND"))
    assert stamp == 2_000_000_000 and detail == {"kind": "instrument", "instrument": "LND"}
    assert decode_setup_change(b'{"kind": "pressure", "pressure_mmhg": 12}')[1] == \
        {"kind": "pressure", "pressure_mmhg": 12.0}
    assert json.loads(encode_setup_change(pressure_mmhg=8)) == {"pressure_mmhg": 8.0}
    for payload, reason in [(b'{"kind": "trocar"}', "kind must be one of"),
                            (b'{"kind": 3}', "kind must be one of"),
                            (b'{"kind": "pressure", "instrument": "LND"}', "instrument is named"),
                            (b'{"instrument": 5}', "instrument must be text"),
                            (json.dumps({"instrument": "x" * 101}).encode(), "instrument")]:
        with pytest.raises(DataError, match=reason):
            decode_setup_change(payload)


def _offered(adapter: Adapter, n: int, t0: float) -> None:
    rng = np.random.default_rng(0)
    w = adapter.config.window
    adapter.add(rng.normal(size=(n, w, 12)), rng.normal(size=(n, 6)), rng.normal(size=(n, 6)),
                t0 + 0.005 * np.arange(n))


def test_an_instrument_change_restarts_the_training_data_a_pressure_change_keeps_it():
    pressure = Adapter(AdaptationConfig())
    instrument = Adapter(AdaptationConfig())
    for a in (pressure, instrument):
        _offered(a, 600, 0.0)
    held = len(pressure.holdout)
    assert held > 0 and pressure.recent.n > 0
    pressure.on_setup_change(3.0, kind="pressure")
    instrument.on_setup_change(3.0, kind="instrument")
    assert len(pressure.holdout) == held and pressure.recent.n > 0
    assert len(instrument.holdout) == 0 and instrument.recent.n == instrument.reservoir.n == 0
    assert instrument.eager(3.5) and pressure.eager(3.5)
    _offered(instrument, 100, 3.0)                     # the new instrument's samples train
    assert instrument.recent.n + len(instrument.holdout) == 100
    with pytest.raises(ValueError, match="kind"):
        instrument.on_setup_change(4.0, kind="trocar")
