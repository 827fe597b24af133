"""The adaptation worker as a real process: rounds come back, a failing round is reported
and the worker (and the last good model) carry on, and it stops cleanly."""

import importlib.util
import os
import time

import numpy as np

from wrenchd.models.adaptation import AdaptationConfig
from wrenchd.service.runtime.worker import ProcessAdaptation, WorkerProcess
from tests.models.adaptation.test_adapter import samples


def collect(backend: ProcessAdaptation, until, timeout: float = 60.0):
    results = []
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        results += backend.tick(0.0)
        if until(results):
            return results
        time.sleep(0.05)
    raise AssertionError(f"timed out; got {[r.summary() for r in results]}, "
                         f"errors {backend.errors}")


def test_worker_rounds_errors_and_stop(tmp_path):
    cfg = AdaptationConfig(min_train_samples=200, interval_s=0.2, round_steps=10)
    worker = WorkerProcess({"PSM1": cfg}, str(tmp_path / "models"), max_cpu_fraction=0.5)
    try:
        backend = ProcessAdaptation(worker, "PSM1")
        backend.offer(*samples(2000))
        time.sleep(0.3)                                  # past the batch interval
        results = collect(backend, lambda rs: any(r.accepted for r in rs))
        accepted = [r for r in results if r.accepted]
        assert accepted[0].version == 1 and accepted[0].state_dict is not None
        # the worker builds kernels without numba (it never streams); the daemon's copy of
        # one compiles where numba is installed
        maps = open(f"/proc/{worker.process.pid}/maps").read()
        assert "llvmlite" not in maps and "numba" not in maps
        kernel = accepted[0].kernel
        assert (kernel._compiled is not None) == (importlib.util.find_spec("numba") is not None)
        assert (tmp_path / "models" / "PSM1" / "corr-v0001.pt").exists()
        worker.send("fail", "PSM1")                      # the next round throws
        deadline = time.monotonic() + 30
        while not backend.errors and time.monotonic() < deadline:
            backend.tick(0.0)
            time.sleep(0.05)
        assert backend.errors and "injected adaptation failure" in backend.errors[0]
        assert worker.alive
        version = max(r.version for r in results)
        more = collect(backend, lambda rs: len(rs) >= 2)  # rounds go on after the failure
        assert all(r.version >= version for r in more)
    finally:
        worker.close()
    assert not worker.alive
    assert np.isfinite(accepted[0].val_after)


def test_the_worker_keeps_the_newest_checkpoints_and_the_served_one(tmp_path):
    """keep_checkpoints = 2: older versions go at each save, but never the one the pipeline
    serves, one it has not swapped to yet, nor the configured corr_checkpoint."""
    models = tmp_path / "models" / "PSM1"
    models.mkdir(parents=True)
    day_ago = time.time() - 86400
    earlier = models / "corr-v0007.pt"                   # an earlier run's version
    pinned = models / "corr-v0003.pt"                    # the arm's corr_checkpoint
    for path in (earlier, pinned):
        path.write_bytes(b"an earlier run's checkpoint")
        os.utime(path, (day_ago, day_ago))
    cfg = AdaptationConfig(min_train_samples=200, interval_s=0.2, round_steps=10)
    worker = WorkerProcess({"PSM1": cfg}, str(tmp_path / "models"), max_cpu_fraction=0.5,
                           keep_checkpoints=2, pinned_checkpoints={"PSM1": str(pinned)})

    def versions() -> set[int]:
        return {int(p.stem.removeprefix("corr-v")) for p in models.glob("corr-v*.pt")}

    try:
        backend = ProcessAdaptation(worker, "PSM1")
        backend.offer(*samples(2000))
        time.sleep(0.3)
        served = max(r.version for r in collect(backend, lambda rs: any(r.accepted
                                                                        for r in rs))
                     if r.accepted)                      # ticked: the pipeline serves it
        # the pipeline lags (no tick): the served version stays, and those saved since
        deadline = time.monotonic() + 30
        while max(versions() - {3, 7}, default=0) < served + 2:
            assert time.monotonic() < deadline, versions()
            time.sleep(0.05)
        saved = max(versions() - {3, 7})
        assert set(range(served, saved + 1)) <= versions()
        # it catches up, and new samples make new versions: the newest two and the served
        backend.offer(*samples(2000))
        latest = max(r.version for r in collect(backend, lambda rs: any(
            r.accepted and r.version > saved + 1 for r in rs)) if r.accepted)
    finally:
        worker.close()
    left = versions()
    assert 3 in left and 7 not in left and not earlier.exists()
    assert len(left - {3}) <= 3 and latest in left, left  # the newest two and the served one
