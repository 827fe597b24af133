import numpy as np
import pytest

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.features import history_windows, joint_features, segment_starts, segments


def test_joint_features_orders_positions_then_velocities():
    q, dq = np.arange(6.0), np.arange(6.0) + 10
    assert joint_features(q, dq).tolist() == list(range(6)) + list(range(10, 16))
    assert joint_features(np.ones((4, 6)), np.zeros((4, 6))).shape == (4, 12)
    with pytest.raises(DataError):
        joint_features(np.ones(6), np.ones(5))


def test_segments_split_at_gaps_and_non_advancing_time():
    t = np.array([0.0, 0.005, 0.010, 0.200, 0.205, 0.205, 0.210])
    assert segment_starts(t, 0.05).tolist() == [0, 3, 5]
    assert segments(t, 0.05) == [slice(0, 3), slice(3, 5), slice(5, 7)]
    assert segments(np.array([0.0, 0.005]), 0.05) == [slice(0, 2)]


def test_history_windows_pad_with_first_sample_then_slide():
    x = np.arange(5.0)[:, None] * np.ones((1, 2))          # rows 0, 1, 2, 3, 4
    w = history_windows(x, 3)
    assert w.shape == (5, 3, 2)
    assert w[0, :, 0].tolist() == [0, 0, 0]
    assert w[1, :, 0].tolist() == [0, 0, 1]
    assert w[4, :, 0].tolist() == [2, 3, 4]
