"""``wrenchd excite`` through the wrenchd command line's parser: the CSV, the ROS 2 bag (read by rosbags) and the
JSON agree, the set-points respect the limits, and the printed condition number fell."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from wrenchd.models.errors import ConfigError
from wrenchd.models.identification.excitation import ExcitationConfig
from wrenchd.service.cli import build_parser


def _run(argv: list[str]) -> int:
    args = build_parser().parse_args(["excite", *argv])
    return args.func(args)


def test_excite_writes_csv_bag_and_json(tmp_path, capsys):
    out = tmp_path / "excite"
    assert _run(["--out", str(out), "--quick", "--periods", "2", "--seed", "3"]) == 0
    printed = capsys.readouterr().out
    match = re.search(r"regressor condition number: ([\d.]+) initial \(seed 3\) -> ([\d.]+) "
                      r"optimised \((\d+) parameters", printed)
    assert match, printed
    before, after = float(match[1]), float(match[2])
    assert after < before

    table = np.loadtxt(out / "excitation.csv", delimiter=",", skiprows=1)
    assert (out / "excitation.csv").read_text().splitlines()[0] == (
        "t,q1,q2,q3,q4,q5,q6,dq1,dq2,dq3,dq4,dq5,dq6")
    assert table.shape == (2 * 2000 + 1, 13)
    t, q, dq = table[:, 0], table[:, 1:7], table[:, 7:]
    np.testing.assert_allclose(np.diff(t), 1 / 200, rtol=1e-9)
    limits = ExcitationConfig()
    assert np.all(q >= np.array(limits.lower)) and np.all(q <= np.array(limits.upper))
    assert np.all(np.abs(dq) <= np.array(limits.max_velocity))
    assert np.ptp(q[:, :3], axis=0).min() > 0 and not np.ptp(q[:, 3:], axis=0).any()

    store = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(out / "setpoints") as reader:
        assert [(c.topic, c.msgtype) for c in reader.connections] == [
            ("/PSM1/servo_jp", "sensor_msgs/msg/JointState")]
        msgs = [(log, store.deserialize_cdr(raw, "sensor_msgs/msg/JointState"))
                for _, log, raw in reader.messages()]
    assert len(msgs) == len(t)
    np.testing.assert_array_equal(np.stack([m.position for _, m in msgs]), q)
    np.testing.assert_array_equal(np.stack([m.velocity for _, m in msgs]), dq)
    assert [log for log, _ in msgs][:3] == [0, 5_000_000, 10_000_000]
    assert list(msgs[0][1].name)[:3] == ["outer_yaw", "outer_pitch", "outer_insertion"]

    saved = json.loads((out / "excitation.json").read_text())
    assert saved["condition_number"]["optimised"] == pytest.approx(after, abs=0.05)
    assert saved["config"]["seed"] == 3 and saved["config"]["iterations"] == 10
    assert np.array(saved["a"]).shape == (6, 5)

    with pytest.raises(ConfigError, match="already holds"):
        _run(["--out", str(out), "--quick"])


def test_excite_refuses_bad_joints(tmp_path):
    with pytest.raises(ConfigError, match="joints must be distinct numbers in 1..6"):
        _run(["--out", str(tmp_path / "x"), "--quick", "--joints", "1,7"])
    assert not (tmp_path / "x").exists()
