"""`wrenchd reproduce --quick` as a real subprocess: tables, plot and numbers written."""

import json
import os
import shutil
import subprocess
import sys

import pytest

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.checkpoint import load_checkpoint
from wrenchd.service.studies.reproduction import AXES, CONFIGS, ReproductionResult


def test_quick_reproduction_writes_the_report(tmp_path):
    out = tmp_path / "repro"
    done = subprocess.run([sys.executable, "-m", "wrenchd", "reproduce", "--quick",
                           "--out", str(out), "--threads", "1"], capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300)
    assert done.returncode == 0, done.stderr
    text = (out / "README.md").read_text()
    for title in ("Table 1: training time", "Table 2: no-contact RMSE",
                  "Table 3: contact RMSE", "Fast Corr recipe beside the paper's",
                  "Do the two-step configurations beat Base and Seal?"):
        assert title in text
    png = (out / "force-rmse-vs-length.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    r = json.loads((out / "results.json").read_text())
    assert set(r["no_contact"]) == set(CONFIGS) and r["axes"] == list(AXES)
    oracle = r["oracle"]["contact"]["force_rmse"]
    for name in CONFIGS:
        for length in ("20.0", "40.0"):
            summary = r["contact"][name][length]
            # Nothing predicts the internal torque better than the simulator's own noise-free
            # value: every configuration sits above the oracle floor (noise only) on every
            # axis, forces and torques (measured 2.9-21x on the quick run). A configuration
            # that saw the true torques would sit on the floor (1.0) and fail here.
            assert len(summary["rmse"]) == len(summary["ratio"]) == 6
            assert min(summary["ratio"]) > 1.0, (name, length, summary["ratio"])
            assert summary["force_rmse"] > oracle, (name, length, summary["force_rmse"])
            # and the mean force's ratio is that RMSE over the floor's
            assert summary["force_ratio"] == pytest.approx(summary["force_rmse"] / oracle,
                                                           rel=1e-9)
    # The floor is the effort noise through J^-T: well under a newton on these trials.
    assert 0.0 < oracle < 0.5
    assert r["fast_vs_paper"]["fast"]["train_seconds"] > 0
    # the typed result reads the file back and writes it out unchanged, key order included
    again = ReproductionResult.read(out / "results.json").to_json()
    assert json.dumps(again) == json.dumps(r)


def test_paper_quick_records_patients_trials_seeds_intervals_and_both_floors(tmp_path):
    """The paper-scale pipeline at toy sizes: step 1 trained here, held-out early stopping,
    patient variation, two seeds, the sensor channel and the filtered floor."""
    out = tmp_path / "paper"
    done = subprocess.run([sys.executable, "-m", "wrenchd", "reproduce", "--paper-quick",
                           "--out", str(out), "--threads", "1"], capture_output=True, text=True,
                          env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300)
    assert done.returncode == 0, done.stderr
    r = json.loads((out / "results.json").read_text())
    assert r["patient_variation"] is True and r["patient_draws_disjoint"] is True
    assert r["trials"]["no_contact"] == 3 and r["trials"]["contact"] == 2
    assert r["seeds"]["training"] == [0, 1]
    # step 1 trained once (the first seed's networks serve under both seeds)
    assert len(r["step1"]["per_seed"]) == 1 and r["step1"]["held_out_sessions"] == 1
    assert r["output_filter"]["cutoff_hz"] == 10.0
    raw, filt = r["oracle"]["contact"]["force_rmse"], r["oracle_filtered"]["contact"]["force_rmse"]
    assert 0.0 < filt < raw
    for name in CONFIGS:
        cell = r["contact"][name]["40.0"]
        seeds = 1 if name in ("Base", "Seal") else 2
        assert cell["seeds"] == seeds and cell["trials"] == 2, name
        for ref in ("truth", "sensor"):
            for metric in ("rmse", "contact_rmse", "peak"):
                c = cell["scores"][ref][metric]
                assert c["force_ci95"][0] <= c["force"] <= c["force_ci95"][1], (name, ref)
                assert len(c["per_seed_force"]) == seeds
        # the RMSE over contact samples is an RMSE over fewer samples than the whole trial's,
        # the peak error at least the RMSE
        truth = cell["scores"]["truth"]
        assert truth["peak"]["force"] >= truth["rmse"]["force"]
        assert cell["force_ratio_raw_floor"] < cell["force_ratio"]     # filtered floor lower
    assert set(r["step1_in_domain"]) == {"Base", "Seal"}
    best = r["criteria"]["best_two_step"]
    assert best["within_1_5x"] == (best["ratios"]["raw"] <= 1.5)
    cell = r["contact"][best["config"]]["40.0"]
    # like for like: the unfiltered estimate over the raw floor, the filtered one over the
    # filtered floor
    assert best["ratios"]["raw"] == cell["unfiltered_force_ratio_raw_floor"]
    assert best["ratios"]["filtered"] == cell["force_ratio"]
    assert cell["unfiltered_force_ratio_raw_floor"] == pytest.approx(
        cell["unfiltered_force_rmse"] / raw, rel=1e-9)
    assert set(r["criteria"]["step1_in_domain"]["ratios"]) == {"Base", "Seal"}
    text = (out / "README.md").read_text()
    for title in ("Table 1: training time", "Table 2: no-contact RMSE",
                  "Table 3: contact RMSE", "Step 1 in domain", "## Targets",
                  "What differs from the paper, and why",
                  "oracle (filtered)", "sensor: force RMSE", "before the filter"):
        assert title in text
    # every recurrent network's training was saved; the same command again resumes from the
    # files (each at its end) and scores the same networks
    saved = sorted(p.name for p in (out / "checkpoints").glob("*.pt"))
    lengths = [f"{float(x):g}s-" for x in r["contact"]["Troc"]]
    assert saved == sorted([f"{n}-seed0.pt" for n in ("Base", "Seal")]
                           + [f"{n}-{tail}seed{k}.pt" for k in (0, 1)
                              for n in ("Troc", "Xfer", "Base+Corr", "Seal+Corr")
                              for tail in lengths])
    # the trained step-1 models are written as checkpoints a --model option takes
    from wrenchd.service.pipeline.step1 import load_step1

    for name in ("Base", "Seal"):
        step1 = load_step1(str(out / "weights" / f"{name}-seed0.pt"))
        ck = load_checkpoint(out / "weights" / f"{name}-seed0.pt")
        assert ck.kind == "free_space" and step1.model.config == ck.model.config
        assert ck.validation["score"] == pytest.approx(r["step1"]["per_seed"][0][name]["score"])
        assert ck.validation["converged"] == (ck.validation["epochs_run"] < ck.train_config.epochs)
    again = subprocess.run([sys.executable, "-m", "wrenchd", "reproduce", "--paper-quick",
                            "--out", str(out), "--threads", "1"], capture_output=True,
                           text=True, env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300)
    assert again.returncode == 0, again.stderr
    r2 = json.loads((out / "results.json").read_text())
    assert [s["Base"]["score"] for s in r2["step1"]["per_seed"]] == [
        s["Base"]["score"] for s in r["step1"]["per_seed"]]
    # Corr, which keeps no per-epoch checkpoint, is read back finished, not trained again
    for name in ("Troc", "Seal+Xfer", "Base+Corr", "Seal+Corr"):
        assert (r2["contact"][name]["40.0"]["scores"]["truth"]["rmse"]["force"]
                == r["contact"][name]["40.0"]["scores"]["truth"]["rmse"]["force"])
    assert r2["train_seconds"]["Base+Corr"] == r["train_seconds"]["Base+Corr"]
    assert "progress" not in r2                                  # a complete run has none
    # a fresh clone: the checkpoints and weights are gone (never committed), the cells are
    # there, and a finished step-1 training is found elsewhere (here a copy of the weights,
    # as the shipped paper-scale ones are for --paper): nothing is trained again, every
    # figure is the same
    cells = sorted(p.name for p in (out / "cells").glob("*.npz"))
    assert cells == [f"seed{k}-L{float(x):g}.npz" for k in (0, 1) for x in r["contact"]["Troc"]]
    kept = tmp_path / "kept"
    shutil.copytree(out / "weights", kept)
    shutil.rmtree(out / "checkpoints")
    shutil.rmtree(out / "weights")
    from wrenchd.service.studies.reproduction import PAPER_QUICK, run_reproduction
    from wrenchd.service.studies.reproduction_cells import fingerprint

    import torch

    logged: list[str] = []
    threads = torch.get_num_threads()
    torch.set_num_threads(1)                      # as the command's --threads 1
    try:
        r3 = run_reproduction(PAPER_QUICK, log=logged.append, checkpoints=out / "checkpoints",
                              weights=out / "weights", cells=out / "cells",
                              finished=lambda name, seed: [kept / f"{name}-seed{seed}.pt"])
    finally:
        torch.set_num_threads(threads)
    assert not list((out / "checkpoints").glob("*.pt"))              # nothing trained
    assert sum("not trained again" in m for m in logged) == len(cells) + 2   # + Base, Seal
    assert sorted(p.name for p in (out / "weights").glob("*.pt")) == ["Base-seed0.pt",
                                                                       "Seal-seed0.pt"]
    for name in ("Troc", "Seal+Xfer", "Base+Corr", "Seal+Corr", "Base", "Seal"):
        was = r["contact"][name]["40.0"]["scores"]["truth"]["rmse"]
        now = r3.contact[name][40.0].scores["truth"]["rmse"]
        assert now.force == pytest.approx(was["force"], rel=1e-9), name
        assert now.force_ci95 == pytest.approx(was["force_ci95"], rel=1e-9), name
    # the weights name the configuration that trained them; a cell of another
    # configuration is refused, not mixed in
    assert load_checkpoint(kept / "Base-seed0.pt").data["reproduction"] == fingerprint(PAPER_QUICK)
    other: list[str] = []
    with pytest.raises(DataError, match="another configuration"):
        run_reproduction(PAPER_QUICK.model_copy(update={"contact_trials": 3}), log=other.append,
                         cells=out / "cells",
                         finished=lambda name, seed: [kept / f"{name}-seed{seed}.pt"])
    assert not any("finished training read" in m for m in other)   # its step 1 trained anew


def test_a_run_writes_its_figures_after_every_cell_and_marks_them_partial(tmp_path):
    """``progress``: after each (training seed, length) cell the result so far, whose
    tables hold the lengths every configuration has reached and whose report says it is
    partial; the run's last result has no progress record."""
    import torch

    from wrenchd.service.studies.reproduction import PAPER_QUICK, run_reproduction
    from wrenchd.service.studies.reproduction_report import markdown

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        calls = []
        final = run_reproduction(PAPER_QUICK, checkpoints=tmp_path / "ck", log=lambda m: None,
                                 progress=calls.append)
    finally:
        torch.set_num_threads(threads)
    assert [c.progress.done for c in calls] == [[(0, 20.0)], [(0, 20.0), (0, 40.0)],
                                                [(0, 20.0), (0, 40.0), (1, 20.0)]]
    assert {c.progress.planned for c in calls} == {4}
    first = calls[0]
    assert first.lengths == [20.0] and set(first.contact["Troc"]) == {20.0}
    # the targets are judged at the longest length scored so far, and say so
    assert first.criteria.best_two_step.length_s == 20.0
    # no trained configuration has reached the longest length: its no-contact table is step 1's
    assert set(first.no_contact) == {"Base", "Seal"}
    text = markdown(first, "wrenchd reproduce --paper-quick", 1.0)
    assert "**Partial run: 1 of 4 (training seed, length) cells done** (seed 0 at 20 s)" in text
    assert "at 20 s (" in text and "### 40 s of trocar training data" not in text
    second = calls[1]
    assert second.lengths == [20.0, 40.0] and second.criteria.best_two_step.length_s is None
    assert set(second.no_contact) == set(CONFIGS)
    # the third holds seed 1 at 20 s only: the 40 s cells are still seed 0's alone
    third = calls[2]
    assert third.contact["Troc"][20.0].seeds == 2 and third.contact["Troc"][40.0].seeds == 1
    assert final.progress is None and final.lengths == [20.0, 40.0]
    assert final.contact["Troc"][40.0].seeds == 2
    assert "Partial run" not in markdown(final, "wrenchd reproduce --paper-quick", 1.0)


def test_a_damaged_or_foreign_cell_file_is_refused_with_its_path(tmp_path):
    """A cell file cut short, or an ``.npz`` that is not a cell, is refused with a DataError
    that names it; a missing one is simply not there (None)."""
    import numpy as np

    from wrenchd.service.studies.reproduction import PAPER_QUICK
    from wrenchd.service.studies.reproduction_cells import cell_path, load_cell

    assert load_cell(tmp_path, PAPER_QUICK, 0, 20.0) is None
    path = cell_path(tmp_path, 0, 20.0)
    path.write_bytes(b"PK\x03\x04 cut short")
    with pytest.raises(DataError, match=str(path.name)):
        load_cell(tmp_path, PAPER_QUICK, 0, 20.0)
    np.savez(path, x=np.zeros(3))
    with pytest.raises(DataError, match="not a reproduction cell"):
        load_cell(tmp_path, PAPER_QUICK, 0, 20.0)
