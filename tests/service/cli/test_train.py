"""`wrenchd train` end to end: a real subprocess, tiny recipes, checkpoints read back."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.checkpoint import load_checkpoint
from wrenchd.service.studies.training import read_train_config

WRENCHD = [sys.executable, "-m", "wrenchd"]
ENV = {**os.environ, "OMP_NUM_THREADS": "1"}


def _run(*args):
    return subprocess.run([*WRENCHD, *args], capture_output=True, text=True, env=ENV,
                          timeout=120)


def test_train_base_then_corr_as_subprocesses(tmp_path):
    base_cfg = tmp_path / "base.toml"
    base_cfg.write_text(f"""
configuration = "base"
seed = 3
output = "{tmp_path / 'base.pt'}"
description = "test"
[overrides]
epochs = 2
window = 20
lane_windows = 2
batch_size = 8
[[data]]
scenario = "free-space"
duration_s = 12
seed = 5
""")
    done = _run("train", "--config", str(base_cfg), "--threads", "1", "--device", "cpu")
    assert done.returncode == 0, done.stderr
    assert "train base" in done.stderr                      # the tqdm bar
    summary = json.loads(done.stdout)
    assert summary["kind"] == "free_space" and summary["epochs_run"] == 2
    ckpt = load_checkpoint(tmp_path / "base.pt")
    assert ckpt.kind == "free_space" and ckpt.version == 1
    assert ckpt.train_config.epochs == 2 and ckpt.train_config.seed == 3
    assert ckpt.data["series"] == [{"source": "simulator", "scenario": "free-space",
                                    "duration_s": 12.0, "seed": 5}]
    assert ckpt.data["n_samples"] == 2400 and ckpt.data["device"] == "cpu"
    assert np.isfinite(ckpt.validation["score"]) and len(ckpt.validation["rmse"]) == 6

    corr_cfg = tmp_path / "corr.json"
    corr_cfg.write_text(json.dumps({
        "configuration": "corr", "recipe": "corr-fast", "overrides": {"epochs": 2},
        "base_checkpoint": str(tmp_path / "base.pt"), "output": str(tmp_path / "unused.pt"),
        "data": [{"scenario": "trocar", "duration_s": 8, "seed": s} for s in (1, 2)]}))
    done = _run("train", "--config", str(corr_cfg), "--output", str(tmp_path / "corr.pt"),
                "--no-progress")
    assert done.returncode == 0, done.stderr
    ckpt = load_checkpoint(tmp_path / "corr.pt")
    assert ckpt.kind == "corr" and ckpt.data["recipe"] == "corr-fast"
    assert ckpt.validation["epochs_run"] <= 2
    assert not (tmp_path / "unused.pt").exists()


def test_bad_configs_are_refused(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('configuration = "corr"\noutput = "x.pt"\n'
                   '[[data]]\nscenario = "trocar"\nduration_s = 5\n')
    with pytest.raises(ConfigError, match="base_checkpoint"):
        read_train_config(bad)
    done = _run("train", "--config", str(bad))
    assert done.returncode == 2 and "base_checkpoint" in done.stderr
    bad.write_text('configuration = "base"\noutput = "x.pt"\ndata = []\n')
    with pytest.raises(ConfigError, match="data"):
        read_train_config(bad)
    bad.write_text("configuration = ")
    with pytest.raises(ConfigError, match="TOML"):
        read_train_config(bad)
