"""One compute thread per process for the service's hot paths.

NumPy's BLAS (OpenBLAS) starts a thread per core unless ``OMP_NUM_THREADS`` says otherwise,
and NumPy is imported before any command could set that variable. The daemon, its
adaptation worker and replay each run their own small matrix products on a machine whose
cores they share with each other: BLAS threads of their own busy-wait against them (the
default replay ran 3x slower: 2 743 vs 8 273 samples/s, ``wrenchd bench replay --duration
120`` without and with ``OMP_NUM_THREADS=1``). :func:`one_compute_thread` limits BLAS through
threadpoolctl, whatever was imported first, and torch to one intra-op thread.
"""

from __future__ import annotations


def one_compute_thread() -> None:
    """Limit NumPy's BLAS and torch to one thread in this process."""
    import torch
    from threadpoolctl import threadpool_limits

    torch.set_num_threads(1)
    threadpool_limits(1)
