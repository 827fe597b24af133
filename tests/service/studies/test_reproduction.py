"""The reproduction's scoring: intervals, per-trial errors, the output filter, floors, and the
report of the committed results rendered as before."""

from pathlib import Path

import numpy as np
import pytest

from wrenchd.service.studies.reproduction import PAPER, ReproductionConfig, ReproductionResult
from wrenchd.service.studies.reproduction_scoring import (
    Scorer,
    lowpass,
    mean_interval,
    trial_errors,
)
from wrenchd.service.studies.reproduction_summary import summarise

ROOT = Path(__file__).resolve().parents[3]


def test_mean_interval_holds_the_mean_and_narrows_with_more_trials():
    rng = np.random.default_rng(1)
    few = rng.normal(1.0, 0.2, (3, 12))
    many = rng.normal(1.0, 0.2, (3, 92))
    m, lo, hi = mean_interval(few)
    assert m == pytest.approx(few.mean()) and lo < m < hi
    m2, lo2, hi2 = mean_interval(many)
    assert hi2 - lo2 < hi - lo
    # a spread between seeds widens the interval over the same trial noise
    shifted = many + np.array([[-0.3], [0.0], [0.3]])
    _, lo3, hi3 = mean_interval(shifted)
    assert hi3 - lo3 > 2 * (hi2 - lo2)
    assert mean_interval(np.full((2, 5), 0.7)) == pytest.approx((0.7, 0.7, 0.7))
    # about 95 % coverage of the true mean over repeated experiments (one seed, 30 trials)
    hits = sum(lo <= 0.0 <= hi for lo, hi in (mean_interval(rng.normal(0, 1, (1, 30)),
                                                             n_boot=400, seed=k)[1:]
                                              for k in range(200)))
    assert 0.88 <= hits / 200 <= 0.99


def test_trial_errors_rmse_contact_rmse_and_peak():
    ref = np.zeros((4, 6))
    est = np.zeros((4, 6))
    est[:, 0] = [1.0, -1.0, 3.0, 0.0]
    contact = np.array([False, False, True, True])
    e = trial_errors(est, ref, contact)
    assert e["rmse"][0] == pytest.approx(np.sqrt(11 / 4))
    assert e["contact_rmse"][0] == pytest.approx(np.sqrt(9 / 2))
    assert e["peak"][0] == 3.0 and e["peak"][1] == 0.0
    assert np.isnan(trial_errors(est, ref, np.zeros(4, bool))["contact_rmse"]).all()


def test_lowpass_is_causal_passes_the_level_and_cuts_the_noise():
    rate = 200.0
    x = np.zeros((400, 6))
    x[200:] = 1.0                                   # a step at sample 200
    y = lowpass(x, rate, 10.0)
    assert np.abs(y[:200]).max() == 0.0             # nothing before the step: causal
    assert y[-1] == pytest.approx(np.ones(6), abs=1e-6)
    noise = np.random.default_rng(0).normal(0, 1, (200_000, 6))
    ratio = lowpass(noise, rate, 10.0).std() / noise.std()
    # a 2nd-order Butterworth's noise bandwidth is ~1.11 fc: sqrt(1.11 * 10 / 100) = 0.33
    assert ratio == pytest.approx(0.333, rel=0.05)
    assert lowpass(x, rate, None) is x
    settled = lowpass(np.full((50, 6), 2.0), rate, 10.0)
    np.testing.assert_allclose(settled, 2.0, atol=1e-9)        # starts settled


@pytest.fixture(scope="module")
def contact_trials():
    from wrenchd.adapters.sim.scenarios import run_scenario

    return [run_scenario("trocar-contact", 20.0, seed=51000 + k) for k in range(2)]


def test_oracle_floors_filtered_below_raw_and_the_truth_oracle_scores_zero(contact_trials):
    from wrenchd.models.estimator.wrench import WrenchMap

    scorer = Scorer(contact_trials, WrenchMap(), 10.0)
    floors = scorer.floors()
    raw = floors["raw"]["truth"]["rmse"][:, :3].mean()
    filt = floors["filtered"]["truth"]["rmse"][:, :3].mean()
    assert 0.3 < filt / raw < 0.75                   # the filter takes most of the noise
    # the sensor channel adds its own noise to the reference: a little above the truth's
    assert floors["raw"]["sensor"]["rmse"][:, :3].mean() > raw
    # torques that explain the effort exactly leave the true wrench: error only where the
    # damped J^-T is not the inverse (near-singular samples)
    exact = [s.joint_states.effort - s.truth.external_torque for s in contact_trials]
    err = scorer.score(exact, filtered=False)["truth"]["rmse"]
    assert err[:, :3].mean() < 0.05 * raw
    cell = summarise([floors["filtered"]] * 2, floors, filtered=True)
    assert cell.force_ratio == pytest.approx(1.0)
    assert cell.force_ratio_raw_floor == pytest.approx(filt / raw)
    lo, hi = cell.scores["truth"]["contact_rmse"].force_ci95
    assert lo <= cell.scores["truth"]["contact_rmse"].force <= hi


def test_paper_config_is_the_papers_scale():
    assert PAPER.no_contact_trials == 92 and PAPER.contact_trials == 12
    assert len(PAPER.training_seeds) == 3 and PAPER.patient_variation
    assert PAPER.lengths_s == (229.0, 474.0, 874.0, 1013.0)
    assert PAPER.step1.duration_s >= 3600.0 and PAPER.recurrent_overrides == {}
    assert PAPER.validation_sessions > 0 and PAPER.corr_recipe == "corr"


@pytest.mark.parametrize("bad, named", [
    ({"lengths_s": (40.0, 20.0)}, "lengths_s"),
    ({"lengths_s": ()}, "lengths_s"),
    ({"corr_overrides": {"epochs": 0}}, "corr_recipe 'corr-fast': epochs"),
    ({"recurrent_overrides": {"windw": 20}}, "troc_recipe 'troc': windw"),
    ({"troc_recipe": "trok"}, "unknown recipe 'trok'"),
    ({"no_contact_trials": 1001}, "no_contact_trials"),
    ({"step1": {"overrides": {"lr": -1.0}}}, "recipe 'free-space': lr"),
])
def test_reproduction_config_names_a_bad_value_when_built(bad, named):
    with pytest.raises(ValueError, match=named):
        ReproductionConfig(**bad)


def test_committed_report_renders_as_it_was():
    from wrenchd.service.studies.reproduction_report import markdown

    folder = ROOT / "reports" / "paper-reproduction"
    r = ReproductionResult.read(folder / "results.json")     # a report before per-trial scores
    assert not r.scored and r.contact["Troc"][229.0].force_rmse > 0
    text = markdown(r, r.command, r.wall_seconds)
    committed = (folder / "README.md").read_text()
    # every table of the committed report comes out the same
    for title in ("## Table 2", "## Table 3"):
        block = text[text.index(title):].split("\n\n## ")[0]
        assert block in committed


def test_troc_minus_pairs_the_trials_so_a_small_steady_gap_is_told():
    from wrenchd.service.studies.reproduction_summary import troc_minus

    rng = np.random.default_rng(3)
    difficulty = rng.uniform(0.5, 2.0, 12)                 # trials differ far more than...
    scores = lambda gap: [{"truth": {"rmse": np.repeat(                    # noqa: E731
        (difficulty + gap + rng.normal(0, 0.01, 12))[:, None], 6, axis=1)}} for _ in range(3)]
    troc, other = scores(0.1), scores(0.0)                 # ...the configurations do
    d = troc_minus(troc, other)
    assert d.mean == pytest.approx(0.1, abs=0.02) and 0.0 < d.ci95[0] < d.mean < d.ci95[1]
    # the unpaired means' intervals overlap: they could not tell the gap
    _, lo_a, hi_a = mean_interval(np.stack([t["truth"]["rmse"][:, 0] for t in troc]))
    _, lo_b, hi_b = mean_interval(np.stack([t["truth"]["rmse"][:, 0] for t in other]))
    assert lo_a < hi_b
    assert troc_minus(other, troc).mean == pytest.approx(-d.mean)
