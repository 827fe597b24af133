"""Step 1 and the least-squares baseline on the real WPI recordings (skipped without them)."""

import os
from pathlib import Path

import numpy as np
import pytest

from service.real_data_cmd import evaluate, markdown


DATA = Path(os.environ.get("WRENCHD_WPI_DATA", Path(__file__).parents[3] / "shared/data/wpi-psm"))

@pytest.mark.skipif(not (DATA / "two.csv").is_file(), reason=f"WPI recordings absent ({DATA})")
def test_real_data_report_numbers():
    r = evaluate(str(DATA / "one_no_weight.csv"), str(DATA / "two.csv"), epochs=2)
    test = r["test_file"]
    std, ls = np.array(test["torque_std"]), np.array(test["ls_rmse"])
    # Rigid body + friction explains most of the torque of the big joints on another
    # trajectory (measured: 0.06/0.75, 0.14/0.62, 0.21/0.98 N m, N m, N).
    assert np.all(ls[:3] < 0.4 * std[:3]), (ls, std)
    assert r["lstm_epochs_run"] == 2 and np.all(np.isfinite(test["lstm_rmse"]))
    text = markdown(r, "cmd")
    assert "Test file (held out)" in text and text.count("outer_yaw") == 2
