"""Step 1 and the least-squares baseline on the real WPI recordings (skipped without them)."""


import numpy as np

from wrenchd.service.cli.real_data import evaluate, markdown


def test_real_data_report_numbers(wpi_data):
    r = evaluate(str(wpi_data / "one_no_weight.csv"), str(wpi_data / "two.csv"), epochs=2)
    test = r["test_file"]
    std, ls = np.array(test["torque_std"]), np.array(test["ls_rmse"])
    # Rigid body + friction explains most of the torque of the big joints on another
    # trajectory (measured: 0.06/0.75, 0.14/0.62, 0.21/0.98 N m, N m, N).
    assert np.all(ls[:3] < 0.4 * std[:3]), (ls, std)
    assert r["lstm_epochs_run"] == 2 and np.all(np.isfinite(test["lstm_rmse"]))
    text = markdown(r, "cmd")
    assert "Test file (held out)" in text and text.count("outer_yaw") == 2
