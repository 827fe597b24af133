"""Suite-wide set-up: one torch thread.

Two torch threads on a 2-core machine that also runs zenoh, subprocesses and NumPy made some
tests ten times slower (measured); the estimator's figures are single-threaded anyway.
"""

import torch

torch.set_num_threads(1)
