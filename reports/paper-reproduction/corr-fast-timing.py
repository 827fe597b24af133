# Wall and CPU time of one corr-fast fit (Base+Corr, the 229 s training set of the report),
# step-1 pass included, one torch thread, three repeats:
# OMP_NUM_THREADS=1 .venv/bin/python reports/paper-reproduction/corr-fast-timing.py
import time

import torch

from models.estimator.pretrained import load_pretrained
from models.estimator.correction_training import fit_corr
from models.estimator.training import recipe
from service.reproduction import ReproductionConfig, training_set

torch.set_num_threads(1)
base = load_pretrained("base")
data = training_set(ReproductionConfig(), 229.0)
for _ in range(3):
    wall, cpu = time.perf_counter(), time.process_time()
    result = fit_corr(base, data, config=recipe("corr-fast"))
    print(f"corr-fast on {sum(len(j) for j in data) / 200:.0f} s: "
          f"{time.perf_counter() - wall:.2f} s wall, {time.process_time() - cpu:.2f} s CPU, "
          f"validation score {result.validation['score']:.4f}", flush=True)
