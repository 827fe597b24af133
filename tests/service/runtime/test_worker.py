"""The adaptation worker as a real process: rounds come back, a failing round is reported
and the worker (and the last good model) carry on, and it stops cleanly."""

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
