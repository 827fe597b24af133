"""Suite-wide set-up: one torch thread, and the one rule for tests on the real recordings.

Two torch threads on a 2-core machine that also runs zenoh, subprocesses and NumPy made some
tests ten times slower; the estimator's figures are single-threaded anyway.

Real-data tests take the ``wpi_data`` fixture. Without the recordings they skip, saying why;
with ``WRENCHD_REQUIRE_REAL_DATA=1`` (set by ``.ci/run``) a missing recording fails the test
instead, so CI cannot pass by skipping them.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

torch.set_num_threads(1)

WPI_DATA_ENV = "WRENCHD_WPI_DATA"
REQUIRE_REAL_DATA_ENV = "WRENCHD_REQUIRE_REAL_DATA"
WPI_FILES = ("one_no_weight.csv", "two.csv", "one_105g_parallel.csv", "one_205g_parallel.csv")


@pytest.fixture(scope="session")
def wpi_data() -> Path:
    """The folder of the real WPI PSM recordings (``$WRENCHD_WPI_DATA``)."""
    value = os.environ.get(WPI_DATA_ENV, "")
    missing = [name for name in WPI_FILES if not (Path(value) / name).is_file()] if value else None
    if value and not missing:
        return Path(value)
    reason = (f"{WPI_DATA_ENV} is not set" if missing is None
              else f"{WPI_DATA_ENV}={value} lacks {', '.join(missing)}")
    reason += "; point it at shared/data/wpi-psm to run the real-data tests"
    if os.environ.get(REQUIRE_REAL_DATA_ENV) == "1":
        pytest.fail(f"real-data test cannot run: {reason}")
    pytest.skip(reason)
