"""The gated policy's delay line against a plain list of what should wait: release after
``release_delay_s``, a contact's onset dropped from ``onset_margin_s`` before it, through the
arrays' moves and growth."""

import numpy as np

from wrenchd.service.pipeline.config import PolicyConfig
from wrenchd.service.pipeline.delay_line import DelayLine

RATE_HZ = 1000.0


def _sample(i: int):
    t = i / RATE_HZ
    return t, np.full((3, 12), float(i)), np.full(6, i + 0.5), np.full(6, -float(i))


def test_samples_wait_their_delay_and_a_contact_takes_its_onset_with_it():
    policy = PolicyConfig(release_delay_s=0.05, onset_margin_s=0.01)
    line = DelayLine(policy, capacity=8)          # small: the arrays move and grow
    model: list[int] = []                         # indices waiting, the reference
    released: list[int] = []
    rng = np.random.default_rng(0)
    for i in range(3000):
        t = i / RATE_HZ
        line.estimated_at(t)
        if rng.random() < 0.01 and model:          # a contact found, its onset 0-40 ms ago
            onset = max(i - int(rng.integers(0, 40)), 0)
            cutoff = onset / RATE_HZ - policy.onset_margin_s
            dropped = line.drop_onset(onset)
            kept = [j for j in model if j / RATE_HZ < cutoff]
            assert dropped == len(model) - len(kept)
            model = kept
            continue
        line.push(*_sample(i))
        model.append(i)
        ready = line.release(t)
        due = [j for j in model if t - j / RATE_HZ >= policy.release_delay_s]
        model = model[len(due):]
        if ready is None:
            assert not due
            continue
        assert [int(v) for v in ready.window[:, 0, 0]] == due
        np.testing.assert_array_equal(ready.t, [j / RATE_HZ for j in due])
        np.testing.assert_array_equal(ready.step1[:, 0], [j + 0.5 for j in due])
        np.testing.assert_array_equal(ready.measured[:, 0], [-float(j) for j in due])
        released += due
        assert line.waiting == len(model)
    assert len(released) > 2000
    np.testing.assert_array_equal(line.waiting_times(), [j / RATE_HZ for j in model])


def test_a_released_batch_stays_as_it_was_and_an_unknown_onset_drops_everything():
    line = DelayLine(PolicyConfig(release_delay_s=0.01), history=4, capacity=2)
    for i in range(30):
        line.estimated_at(i / RATE_HZ)
        line.push(*_sample(i))
    ready = line.release(0.025)                   # 0..15 have waited 10 ms
    assert len(ready.t) == 16
    for i in range(30, 40):                       # the arrays move under it
        line.estimated_at(i / RATE_HZ)
        line.push(*_sample(i))
    assert [int(v) for v in ready.window[:, 0, 0]] == list(range(16))
    assert line.waiting == 24
    assert line.drop_onset(0) == 24               # index 0 left the 4-sample history
    assert line.waiting == 0
    line.push(*_sample(40))
    line.clear()
    assert line.waiting == 0 and line.release(10.0) is None
    for i in range(41, 45):                       # after a clear, nothing released is reused
        line.push(*_sample(i))
    last = line.release(10.0)
    assert [int(v) for v in last.window[:, 0, 0]] == [41, 42, 43, 44]
    assert [int(v) for v in ready.window[:, 0, 0]] == list(range(16))
    np.testing.assert_array_equal(ready.measured[:, 0], -np.arange(16.0))
