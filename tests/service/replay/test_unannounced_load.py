"""An unannounced load on a real arm (205 g on the parallel link, recordings played one after
another): the gate takes the lasting residual for a set-up change within seconds, training
resumes, and the gated policy's free-motion tip force after the change ends far under the
frozen model's (which never adapts)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from wrenchd.service.pipeline import PipelineConfig
from wrenchd.service.pipeline.step1 import load_free_space
from wrenchd.service.replay.loop import replay
from wrenchd.service.replay.metrics import replay_metrics
from wrenchd.service.replay.policies import get_policy
from wrenchd.service.replay.source import load_session

CHANGE_S = 90.0                        # three unloaded recordings of 30 s, then the load


@pytest.fixture(scope="module")
def bundle(wpi_data, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("fit") / "bundle"
    done = subprocess.run([sys.executable, "-m", "wrenchd", "fit",
                           str(wpi_data / "one_no_weight.csv"), "-o", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    return out


def test_an_unannounced_load_is_taken_for_a_set_up_change_and_learnt(bundle, wpi_data):
    session = load_session(f"concat:{wpi_data / 'one_no_weight.csv'}*3,"
                           f"{wpi_data / 'one_205g_parallel.csv'}*4")
    free_space = load_free_space(str(bundle))
    runs = {p: replay(session, free_space, get_policy(p).configure(PipelineConfig()), policy=p)
            for p in ("gated", "frozen")}
    gated = runs["gated"]
    (change,) = [e.t for e in gated.events if e.kind == "gate_setup_change"]
    cfg = PipelineConfig().gate
    assert CHANGE_S < change <= CHANGE_S + cfg.setup_contact_s + 2.0
    # training resumes within seconds of it (probation, then the delay line)
    resumed = gated.offered_t[gated.offered_t > CHANGE_S]
    assert len(resumed) and resumed[0] < change + cfg.setup_probation_s + 4.0
    after = {p: replay_metrics(r, session)["setup_changes"][0]["after_N"]
             for p, r in runs.items()}
    assert after["gated"] < 0.5 * after["frozen"], after
    # no recording-long false contact after it: the gate calls most free motion free
    late = gated.t > change + 10.0
    assert np.mean(gated.free[late]) > 0.9
