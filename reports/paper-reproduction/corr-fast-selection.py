# Choosing the corr-fast recipe on contact trials the report never tests (seeds 52000-52002):
# OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python reports/paper-reproduction/corr-fast-selection.py
# Output (2026-11-21, shared 2-core machine) in corr-fast-selection.txt.
import time, torch, numpy as np
torch.set_num_threads(1)
from adapters.sim.scenarios import run_scenario
from models.estimator.pretrained import load_pretrained
from models.estimator.correction_training import fit_corr
from models.estimator.training import recipe
from models.estimator.wrench import WrenchMap
from service.reproduction import ReproductionConfig, training_set, predicted_torques, wrench_rmse
base = load_pretrained("base")
data = training_set(ReproductionConfig(), 229.0)
val = [run_scenario("trocar-contact", 45.0, 52000 + k) for k in range(3)]
wm = WrenchMap()
cands = {"paper": recipe("corr"), "fast16": recipe("corr-fast"),
         "fast32": recipe("corr-fast", epochs=32, lr_halving_epochs=8),
         "fast24s2": recipe("corr-fast", epochs=24, sample_stride=2, lr_halving_epochs=6)}
for name, cfg in cands.items():
    c0 = time.process_time()
    r = fit_corr(base, data, config=cfg)
    cpu = time.process_time() - c0
    rm = wrench_rmse(predicted_torques(base, r.model, val), val, wm)
    print(name, f"cpu {cpu:.2f}", r.validation["epochs_run"], f"force {rm[:, :3].mean():.4f}", np.round(rm.mean(0), 4), flush=True)
