"""Table cells of the reproduction from per-trial scores, and the paper-scale targets.

A cell (:func:`summarise`) is the mean over training seeds and trials of one configuration
at one length, with a percentile-bootstrap 95 % interval for every reference and metric
(:func:`~wrenchd.service.studies.reproduction_scoring.mean_interval`), and its ratios to
the oracle floor. :func:`criteria` reads the run's targets off the cells like for like.
"""

from __future__ import annotations

import numpy as np

from wrenchd.service.studies.reproduction_results import (
    BestTwoStep,
    Cell,
    Criteria,
    Interval,
    PairedDifference,
    ReproductionResult,
    Step1Criterion,
    Summary,
)
from wrenchd.service.studies.reproduction_scoring import METRICS, TrialScores, mean_interval


def summary(rmse: np.ndarray, oracle: np.ndarray) -> Summary:
    """The summary of (trials, 6) RMSEs against the oracle's (trials, 6) RMSEs."""
    mean = rmse.mean(0)
    force = rmse[:, :3].mean(1)                    # mean force RMSE per trial [N]
    return Summary(rmse=mean.tolist(), ratio=(mean / oracle.mean(0)).tolist(),
                   force_rmse=float(force.mean()), force_rmse_std=float(force.std()),
                   force_ratio=float(force.mean() / oracle[:, :3].mean()))


def cell_stats(values: np.ndarray) -> Interval | None:
    """Mean and interval per axis and of the mean force of (seeds, trials, 6) values; trials
    with a NaN (no sample to score) are left out, None when none is left."""
    if np.isnan(values).any():
        keep = ~np.isnan(values).any(axis=(0, 2))
        values = values[:, keep]
        if values.shape[1] == 0:
            return None
    axes = [mean_interval(values[..., k]) for k in range(values.shape[-1])]
    force = mean_interval(values[..., :3].mean(-1))
    return Interval(mean=[a[0] for a in axes], ci95=[[a[1], a[2]] for a in axes],
                    force=force[0], force_ci95=[force[1], force[2]],
                    per_seed_force=values[..., :3].mean(-1).mean(-1).tolist())


def summarise(per_seed: list[TrialScores], floors: dict[str, TrialScores],
              filtered: bool) -> Cell:
    """A table cell from its per-seed scores ({reference: {metric: (trials, 6)}} per seed).

    The :class:`Summary` fields are the truth RMSE over every sample, the ratios against
    the floor of the same filtering; ``scores`` holds every reference and metric with
    intervals and ``force_ratio_raw_floor`` the ratio against the raw oracle.
    """
    rmse = np.stack([p["truth"]["rmse"] for p in per_seed])            # (S, T, 6)
    floor = floors["filtered" if filtered else "raw"]["truth"]["rmse"]
    raw = floors["raw"]["truth"]["rmse"]
    mean = rmse.mean(axis=(0, 1))
    force = rmse[..., :3].mean(-1)                                     # (S, T)
    unfiltered = {}
    if "truth_unfiltered" in per_seed[0]:
        unf = np.stack([p["truth_unfiltered"]["rmse"] for p in per_seed])[..., :3].mean()
        unfiltered = {"unfiltered_force_rmse": float(unf),
                      "unfiltered_force_ratio_raw_floor": float(unf / raw[:, :3].mean())}
    scores = {ref: {m: cell_stats(np.stack([p[ref][m] for p in per_seed])) for m in METRICS}
              for ref in per_seed[0]}
    return Cell(rmse=mean.tolist(), ratio=(mean / floor.mean(0)).tolist(),
                force_rmse=float(force.mean()), force_rmse_std=float(force.std()),
                force_ratio=float(force.mean() / floor[:, :3].mean()),
                force_ratio_raw_floor=float(force.mean() / raw[:, :3].mean()),
                seeds=len(per_seed), trials=int(rmse.shape[1]), scores=scores, **unfiltered)


def troc_minus(troc: list[TrialScores], other: list[TrialScores]) -> PairedDifference:
    """Troc's force RMSE (truth, mean of Fx, Fy, Fz) minus ``other``'s on the same trials,
    seed k of one against seed k of the other: the mean and interval of that (seeds, trials)
    table of differences (:func:`mean_interval`). Pairing by trial takes the trials' own
    spread of difficulty out of the comparison, which the two cells' intervals keep."""
    seeds = min(len(troc), len(other))
    a = np.stack([p["truth"]["rmse"] for p in troc[:seeds]])[..., :3].mean(-1)
    b = np.stack([p["truth"]["rmse"] for p in other[:seeds]])[..., :3].mean(-1)
    mean, lo, hi = mean_interval(a - b)
    return PairedDifference(mean=mean, ci95=[lo, hi])


def floor_summary(floor: TrialScores) -> Cell:
    """A floor in the layout of :func:`summarise` (one "seed": the oracle is deterministic)."""
    return summarise([floor], {"raw": floor, "filtered": floor}, filtered=False)


def like_for_like(cell: Cell) -> dict[str, float]:
    """A cell's force RMSE over the floor of the same filtering: ``raw`` (the estimate
    before any output filter over the raw oracle) and, with a filter, ``filtered`` (the
    filtered estimate over the filtered oracle)."""
    if cell.unfiltered_force_ratio_raw_floor is not None:
        return {"raw": cell.unfiltered_force_ratio_raw_floor, "filtered": cell.force_ratio}
    return {"raw": cell.force_ratio_raw_floor}


def criteria(result: ReproductionResult) -> Criteria:
    """The paper-scale run's targets, measured like for like (:func:`like_for_like`): the
    in-domain step-1 false force within 2x the oracle floor; the best two-step configuration
    (contact force RMSE at the longest length scored, unseen patients under patient variation)
    within 1.5x the raw oracle floor. The verdicts read the ``raw`` pairing."""
    step1 = None
    if result.step1_in_domain:
        ratios = {k: like_for_like(v) for k, v in result.step1_in_domain.items()}
        step1 = Step1Criterion(ratios=ratios, within_2x=bool(
            max(r["raw"] for r in ratios.values()) <= 2.0))
    last = result.lengths[-1]
    two_step = {k: like_for_like(result.contact[k][last])
                for k in ("Base+Corr", "Seal+Corr", "Seal+Xfer")}
    best = min(two_step, key=lambda k: two_step[k]["raw"])
    return Criteria(step1_in_domain=step1, best_two_step=BestTwoStep(
        config=best, ratios=two_step[best], unseen_patients=bool(result.patient_variation),
        within_1_5x=bool(two_step[best]["raw"] <= 1.5),
        length_s=None if last == float(result.config.lengths_s[-1]) else last))
