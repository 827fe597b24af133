"""The examples in the docstrings of the core streaming classes run as written.

pytest's ``--doctest-modules`` imports files by path, which the one import name (``wrenchd``,
mapped onto ``models/``, ``adapters/``, ``service/``) refuses, so the modules are imported by
name here and handed to :mod:`doctest`.
"""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = (
    "wrenchd.models.gate",
    "wrenchd.models.residual_scale",
    "wrenchd.models.contact_hysteresis",
    "wrenchd.models.weak_contact",
    "wrenchd.service.pipeline.mechanisms",
    "wrenchd.models.estimator.estimator",
    "wrenchd.service.pipeline.arm",
    "wrenchd.service.replay.detector",
    "wrenchd.models.drift_detector",
    "wrenchd.models.adaptation.adapter",
    "wrenchd.models.series",
)


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name: str) -> None:
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has no example"
    assert result.failed == 0
