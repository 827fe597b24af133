"""One BLAS thread per service process, whatever the environment and import order."""

import os
import subprocess
import sys


def test_one_compute_thread_limits_blas_after_numpy_was_imported():
    code = ("import numpy, threadpoolctl\n"
            "from wrenchd.service.runtime.scheduling import one_compute_thread\n"
            "before = max(i['num_threads'] for i in threadpoolctl.threadpool_info())\n"
            "one_compute_thread()\n"
            "after = {i['num_threads'] for i in threadpoolctl.threadpool_info()}\n"
            "print(before, sorted(after))\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True, timeout=120).stdout.split()
    assert int(out[0]) == os.cpu_count()        # what the daemon had before (one per core)
    assert out[1:] == ["[1]"]


def test_idle_priority_moves_the_calling_thread_alone():
    """A replay's step-1 thread takes only idle time; the thread that started it keeps its
    class (the pipeline must not run in SCHED_IDLE)."""
    import threading

    from wrenchd.service.runtime.scheduling import idle_priority, thread_scheduling

    seen = {}

    def worker():
        idle_priority()
        seen.update(thread_scheduling(threading.get_native_id()))

    before = thread_scheduling(threading.get_native_id())
    t = threading.Thread(target=worker)
    t.start()
    t.join()
    assert seen["class"] == "SCHED_IDLE"
    assert thread_scheduling(threading.get_native_id()) == before
    assert before["class"] != "SCHED_IDLE"
