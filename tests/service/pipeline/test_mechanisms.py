"""Each policy name the config accepts has its mechanism, and each mechanism's rule holds."""

import typing

import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.service.pipeline.config import POLICIES, PolicyConfig
from wrenchd.service.pipeline.mechanisms import MECHANISMS, mechanism


def test_the_config_accepts_exactly_the_mechanisms():
    accepted = typing.get_args(PolicyConfig.model_fields["name"].annotation)
    assert set(accepted) == set(MECHANISMS) == set(POLICIES)


def test_an_unknown_mechanism_is_named():
    with pytest.raises(ConfigError, match="'sometimes'"):
        mechanism("sometimes")


def test_drift_triggered_offers_only_while_eager_or_calibrating():
    m = mechanism("drift-triggered")
    assert m.may_offer(10.0, eager_until=20.0, calibrating=False)
    assert not m.may_offer(30.0, eager_until=20.0, calibrating=False)
    assert m.may_offer(30.0, eager_until=20.0, calibrating=True)
    assert mechanism("gated").may_offer(30.0, eager_until=20.0, calibrating=False)


def test_periodic_reset_is_due_every_period_from_its_first_tick():
    m = mechanism("periodic-reset")
    due = [t for t in range(0, 250, 5) if m.reset_due(float(t), 60.0)]
    assert due == [60, 120, 180, 240]
    assert not any(mechanism("gated").reset_due(float(t), 60.0) for t in range(0, 250, 5))
    assert not mechanism("frozen").adapts and mechanism("ungated").offers_everything
