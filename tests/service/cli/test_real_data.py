"""``wrenchd real-data`` on the real WPI recordings (skipped without them), and its parts."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from wrenchd.models.errors import ConfigError
from wrenchd.models.series import JointStates
from wrenchd.service.cli.real_data import MODEL_NAMES
from wrenchd.service.studies.real_data import MODELS, Source, repeatability


def test_split_experiment_and_loads(wpi_data, tmp_path):
    """Trained on one_no_weight + the first 18 s of two, tested on the last 12 s of two."""
    out = tmp_path / "split.md"
    d = str(wpi_data)
    cmd = [sys.executable, "-m", "wrenchd", "real-data", "--models", "ls,hybrid",
           "--hybrid-epochs", "40", "--threads", "1",
           "--train", f"{d}/one_no_weight.csv", "--train", f"{d}/two.csv:0:18",
           "--test", f"{d}/two.csv:18:30", "--load", f"{d}/one_105g_parallel.csv",
           "--load", f"{d}/one_205g_parallel.csv", "--lookahead-ms", "25", "--out", str(out)]
    done = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    r = json.loads(out.with_suffix(".json").read_text())
    test = r["test_file"]
    ls, hyb = np.array(test["ls_rmse"]), np.array(test["hybrid_rmse"])
    # The test window repeats the trained first 18 s: the residual applies almost everywhere
    # (with some trust on every sample, full trust on 88 %) and takes yaw and pitch far below
    # least squares.
    assert test["coverage"]["share_any"] > 0.95 and test["coverage"]["share_full"] > 0.75
    assert np.all(hyb[:2] < 0.8 * ls[:2]), (hyb, ls)
    assert np.all(hyb < 1.02 * ls), (hyb, ls)
    # The same hybrid with an acceleration reading 25 ms ahead (offline) is a hybrid too.
    ahead = np.array(test["hybrid_lookahead_25ms_rmse"])
    assert np.all(ahead[:2] < 0.8 * ls[:2]), (ahead, ls)
    assert test["repeatability"]["period_s"] == pytest.approx(6.48, abs=0.05)
    # The loaded recordings repeat trajectory one: the fitted load moment grows with the mass
    # (105 g and 205 g: measured ratio 1.97).
    ratio = r["loads"]["ratios"]["hybrid"]["moment"]
    assert 1.75 < ratio < 2.15, ratio
    assert r["loads"]["ratios"]["truth"] == pytest.approx(205 / 105)
    assert r["train"][1].endswith("two.csv:0:18") and "provenance" in r
    text = out.read_text()
    assert text.count("outer_yaw") >= 3 and "--train" in text and "Load ratio" in text
    assert "--lookahead-ms 25" in text and "25 ms ahead (offline)" in text


def test_sources_parse():
    assert Source.parse("a/two.csv") == Source("a/two.csv")
    assert Source.parse("a/two.csv:0:18") == Source("a/two.csv", 0.0, 18.0)
    assert Source.parse("two.csv:18:") == Source("two.csv", 18.0, None)
    assert Source.parse("two.csv:18:30").label == "two.csv:18:30"
    with pytest.raises(ConfigError):
        Source.parse("two.csv:18:10")
    assert MODEL_NAMES == MODELS


def test_repeatability_of_a_periodic_recording():
    rng = np.random.default_rng(0)
    t = np.arange(4000) * 0.005                               # 20 s, period 5 s
    q = np.zeros((len(t), 6))
    q[:, :3] = np.sin(2 * np.pi * t / 5.0)[:, None] * [0.3, 0.2, 0.05]
    tau = np.sin(2 * np.pi * t / 5.0)[:, None] + rng.normal(0.0, 0.01, (len(t), 6))
    rep = repeatability(JointStates(t, q, np.zeros_like(q), tau))
    assert rep["period_s"] == pytest.approx(5.0)
    assert rep["position_rms"] < 1e-9
    np.testing.assert_allclose(rep["floor_rmse"], 0.01, rtol=0.1)
    noise = JointStates(t, rng.normal(size=q.shape), np.zeros_like(q), tau)
    assert repeatability(noise) is None


def test_newtons_at_the_tip_and_known_loads(wpi_data, tmp_path):
    """Least squares on one_no_weight: the free-motion tip force of two.csv in newtons beside
    the dVRK's own J^-T effort, and the parallelogram loads' masses with their point held."""
    out = tmp_path / "loads.md"
    d = str(wpi_data)
    loads = [f"{d}/one_105g_parallel.csv:0.105:parallel_upper:0.165,-0.020,0",
             f"{d}/one_205g_parallel.csv:0.205:parallel_upper:0.165,-0.023,0",
             f"{d}/one_slow_205g_parallel.csv:0.205:parallel_upper:0.165,-0.023,0"]
    cmd = [sys.executable, "-m", "wrenchd", "real-data", "--models", "ls", "--threads", "1",
           "--train", f"{d}/one_no_weight.csv", "--test", f"{d}/two.csv", "--out", str(out)]
    cmd += [a for spec in loads for a in ("--known-load", spec)]
    done = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    r = json.loads(out.with_suffix(".json").read_text())
    tip = r["test_file"]["tip_force_N"]
    # Least squares is deterministic: measured 1.56 N on two.csv, the raw effort 9.6 N, the
    # floor 0.34 N; tolerances cover BLAS differences, not a different model.
    assert tip["ls"]["rms"] == pytest.approx(1.563, rel=0.02)
    assert tip["measured_cf"]["rms"] == pytest.approx(9.59, rel=0.01)
    assert r["test_file"]["tip_force_floor_N"]["rms"] == pytest.approx(0.336, rel=0.02)
    assert tip["ls"]["p95"] > tip["ls"]["rms"] and set(tip) >= {"ls_plain",
                                                                "measured_cf_minus_gravity"}
    assert r["train_file"]["tip_force_N"]["ls"]["rms"] < tip["ls"]["rms"]
    fast105, fast205, slow205 = r["known_loads"]
    assert fast105["joints"] == [1, 2] and fast105["rate_hz"] == pytest.approx(200.0)
    # The half-speed run is a 100 Hz recording (its velocity column says so).
    assert slow205["rate_hz"] == pytest.approx(100.0)
    for rec, low, high in ((fast105, 0.085, 0.105), (fast205, 0.195, 0.225),
                           (slow205, 0.170, 0.200)):
        assert low < rec["fitted_mass_kg"] < high, (rec["file"], rec["fitted_mass_kg"])
        assert rec["force_error_N"]["rms"] < 1.5
        # The point read off a tape to a centimetre: moving it changes the mass both ways.
        moved = rec["fitted_mass_point_moved_kg"]
        assert set(moved) == {"x-1cm", "x+1cm", "y-1cm", "y+1cm"}
        assert min(moved.values()) < rec["fitted_mass_kg"] < max(moved.values())
    # The two full-speed runs follow one path: their difference needs no model (measured
    # 117.7 g with the efforts alone, 116.8 g through least squares, for 100 g).
    (pair,) = r["known_load_pairs"]
    assert [Path(f).name for f in pair["files"]] == ["one_105g_parallel.csv",
                                                     "one_205g_parallel.csv"]
    fit = pair["fitted_difference_kg"]
    assert fit["effort"] == pytest.approx(0.1177, rel=0.01)
    assert fit["ls"] == pytest.approx(fit["effort"], abs=0.003)
    # no hybrid in this run: the served figure is the efforts' own
    assert pair["served"] == "effort"
    assert pair["per_run_kg"] == pytest.approx(abs(fit["effort"] - 0.1) / np.sqrt(2), rel=1e-6)
    text = out.read_text()
    assert "Newtons at the tip" in text and "Known loads" in text and "Run to run" in text


def test_run_to_run_recovers_a_known_difference_and_pairs_only_one_path():
    """Two synthetic runs of one path, loads 0.1 and 0.25 kg, the second with a 2 mN m pitch
    offset: the fit returns the difference the offset makes, model or no model; a third run on
    another path is paired with neither."""
    from wrenchd.service.studies.newtons import KnownLoad, LoadRun, run_to_run

    rng = np.random.default_rng(0)
    t = np.arange(2000) * 0.005
    q = np.zeros((t.size, 6))
    q[:, 0], q[:, 1] = 0.5 * np.sin(t), 0.3 * np.cos(0.7 * t)
    per_kg = np.zeros((t.size, 6))
    per_kg[:, 0], per_kg[:, 1] = 0.1 * np.sin(q[:, 0]), 1.6 * np.cos(q[:, 1])
    base = rng.normal(0.0, 0.05, (t.size, 6))

    def run(mass, position, offset=0.0):
        effort = base + mass * per_kg + rng.normal(0.0, 0.01, (t.size, 6))
        effort[:, 1] += offset
        load = KnownLoad.parse(f"x.csv:{mass}:parallel_upper:0.165,-0.02,0")
        js = JointStates(t, position, np.zeros_like(q), effort)
        return LoadRun(load, js, 200.0, per_kg, {"model": effort - 0.5 * base})

    other = q.copy()
    other[:, 1] += 0.05
    pairs = run_to_run([run(0.1, q), run(0.25, q, offset=0.002), run(0.2, other)])
    (pair,) = pairs
    assert pair["masses_kg"] == [0.1, 0.25]
    # least squares of the offset on per_kg's pitch column adds offset * mean / mean square
    bias = 0.002 * per_kg[:, 1].sum() / (per_kg[:, :2] ** 2).sum()
    for key in ("effort", "model"):
        assert pair["fitted_difference_kg"][key] == pytest.approx(0.15 + bias, abs=0.002)
    assert pair["served"] == "effort" and pair["error_kg"] == pytest.approx(bias, abs=0.002)


def test_known_load_specs_are_validated():
    from wrenchd.service.studies.newtons import KnownLoad

    load = KnownLoad.parse("a/one.csv:0:10:0.105:parallel_upper:0.165,-0.02,0")
    assert load.source == Source("a/one.csv", 0.0, 10.0) and load.point == (0.165, -0.02, 0.0)
    for bad, match in (("one.csv:0.1:parallel_upper", "expected FILE"),
                       ("one.csv:-1:parallel_upper:0,0,0", "positive mass"),
                       ("one.csv:0.1:forearm:0,0,0", "LINK one of"),
                       ("one.csv:0.1:outer_yaw:0,0", "three finite coordinates"),
                       ("one.csv:0.1:outer_yaw:0,0,x", "must be numbers"),
                       ("one.csv:heavy:outer_yaw:0,0,0", "must be a number")):
        with pytest.raises(ConfigError, match=match):
            KnownLoad.parse(bad)


def test_the_half_speed_run_is_outside_the_hybrids_coverage(wpi_data):
    """The half-speed run passes trajectory one's positions at velocities the full-speed run
    also has elsewhere on the path, but at a quarter of its accelerations: with accelerations
    in the coverage (the default) its residual is not trusted there (without them it was on
    about half the samples, mean trust 0.14); the full-speed loaded run stays inside."""
    from wrenchd.models.estimator.hybrid import HybridConfig, ResidualNetConfig, fit_hybrid
    from wrenchd.service.studies.real_data import at_rate, features

    hybrid = fit_hybrid([Source(str(wpi_data / "one_no_weight.csv")).load()],
                        HybridConfig(residual=ResidualNetConfig(epochs=5)))
    assert hybrid.coverage.width == 18
    fast = Source(str(wpi_data / "one_205g_parallel.csv")).load()
    slow = at_rate(Source(str(wpi_data / "one_slow_205g_parallel.csv")).load(),
                   hybrid.acceleration.dt_s)
    assert slow.rate_hz == pytest.approx(200.0)
    assert hybrid.parts(features(fast)).weight.mean() > 0.8
    assert hybrid.parts(features(slow)).weight.mean() < 0.06
