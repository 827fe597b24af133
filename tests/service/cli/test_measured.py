"""``--measured``: identify and discrepancy read every recording ``wrenchd fit`` reads."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from tests.support import ros2_bag_from
from wrenchd.adapters.csv_psm import read_wpi_csv
from wrenchd.models.errors import ConfigError
from wrenchd.models.series import JointStates
from wrenchd.service.cli.measured import read_measured


@pytest.fixture(scope="module")
def short(wpi_data) -> JointStates:
    js, _ = read_wpi_csv(wpi_data / "one_no_weight.csv")
    n = 400
    return JointStates(js.t[:n], js.position[:n], js.velocity[:n], js.effort[:n])


def test_a_ros2_bag_reads_as_its_csv(short, wpi_data, tmp_path):
    bag = ros2_bag_from(short, tmp_path / "bag", topic="/PSM2/measured_js")
    js = read_measured(str(bag), topic="/PSM2/measured_js")
    np.testing.assert_array_equal(js.effort, short.effort)
    np.testing.assert_allclose(js.t - js.t[0], short.t - short.t[0], atol=1e-6)
    assert len(read_measured(str(bag), "mcap", topic="/PSM2/measured_js")) == len(short)


def test_formats(wpi_data, tmp_path):
    csv = wpi_data / "one_no_weight.csv"
    as_text = tmp_path / "one.txt"                     # a CSV layout named explicitly: any suffix
    shutil.copy(csv, as_text)
    np.testing.assert_array_equal(read_measured(str(as_text), "wpi").effort,
                                  read_measured(str(csv)).effort)
    with pytest.raises(ConfigError, match="CSV"):
        read_measured(str(csv), "mcap")
    with pytest.raises(ConfigError, match="unknown recording type"):
        read_measured(str(as_text))
    with pytest.raises(ConfigError, match="--format"):
        read_measured(str(csv), "xml")
