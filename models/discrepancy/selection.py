"""Name: which candidate effects have real support in the residual.

The discrepancy workflow must name the effect a model lacks without naming noise, or an
effect real but too small to matter, or the same effect twice. Candidates
(:mod:`~wrenchd.models.discrepancy.candidates`) are judged on the residual [N m; N on
insertion] whitened per joint by its noise floor, so every joint counts by its own noise, by
three tests: a held-out Bayesian information criterion on contiguous folds (Schwarz, "Estimating
the dimension of a model", Ann. Statist. 6(2), 1978; the threshold is "strong" on the scale of
Kass and Raftery, "Bayes factors", JASA 90(430), 1995), the stability of the fitted effect
under a moving-block bootstrap (Kunsch, Ann. Statist. 17(3), 1989), and its size against the
noise floor. Forward selection is greedy, and every named effect is re-tested against the
others at the end. Fits are statsmodels OLS, folds scikit-learn ``KFold``. The steps and their
thresholds are in :func:`select`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import statsmodels.api as sm
from sklearn.model_selection import KFold

from wrenchd.models.discrepancy.candidates import Candidate

N_FOLDS = 5
MIN_DELTA_BIC = 10.0          # "strong" on the Kass-Raftery scale
MIN_FOLDS = 4
MIN_STABILITY = 0.9
MIN_SIZE = 0.3                # effect RMS on its strongest joint, in noise floors
BOOT_REPLICATES = 20
BOOT_BLOCK_S = 1.0
DUPLICATE_R2 = 0.99
MAX_EFFECTS = 4
#: A column of a per-joint candidate counts only where its coefficient's t statistic reaches
#: this (:func:`_supported`).
MIN_T = 3.0
#: Another candidate is listed as an alternative to a named effect when it reproduces that
#: effect's fitted torque with this whitened R^2 or more (:func:`alternatives`).
ALTERNATIVE_R2 = 0.9


@dataclass
class Evidence:
    delta_bic: float
    folds_in_favour: int
    stability: float
    size: float                       # max over joints of effect RMS / floor
    entry_delta_bic: float = 0.0


@dataclass
class Named:
    """A named effect: candidate, kept columns, coefficients, evidence."""

    candidate: Candidate
    keep: np.ndarray                   # indices of the candidate's columns used
    evidence: Evidence
    beta: np.ndarray = field(default_factory=lambda: np.zeros(0))
    bse: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def full_beta(self) -> np.ndarray:
        """Coefficients for all the candidate's columns (dropped ones are 0)."""
        out = np.zeros(self.candidate.columns.shape[2])
        out[self.keep] = self.beta
        return out


class Stacked:
    """Whitened, stacked residual and columns; fold and bootstrap row sets."""

    def __init__(self, residual: np.ndarray, floor: np.ndarray, t: np.ndarray, seed: int = 0):
        self.n = residual.shape[0]
        self.sw = 1.0 / floor
        self.y = (residual * self.sw).reshape(-1)
        self.folds = [(self.rows(tr), self.rows(te)) for tr, te in
                      KFold(N_FOLDS, shuffle=False).split(np.arange(self.n))]
        self.dt = float(np.median(np.diff(t)))
        self.rng = np.random.default_rng(seed)

    @staticmethod
    def rows(samples: np.ndarray) -> np.ndarray:
        return (samples[:, None] * 6 + np.arange(6)).reshape(-1)

    def x(self, cand: Candidate, keep: np.ndarray | None = None) -> np.ndarray:
        cols = cand.columns if keep is None else cand.columns[:, :, keep]
        return (cols * self.sw[None, :, None]).reshape(self.n * 6, -1)

    def boot_rows(self) -> np.ndarray:
        block = max(int(round(BOOT_BLOCK_S / self.dt)), 1)
        starts = self.rng.integers(0, max(self.n - block, 1), int(np.ceil(self.n / block)))
        samples = (starts[:, None] + np.arange(block)).reshape(-1)[: self.n]
        return self.rows(samples)


def _heldout_bic(st: Stacked, x: np.ndarray | None) -> np.ndarray:
    """Held-out BIC per fold of the regression of ``st.y`` on ``x`` (None: no regressor)."""
    out = np.empty(len(st.folds))
    for f, (tr, te) in enumerate(st.folds):
        if x is None or x.shape[1] == 0:
            ll = sm.OLS(st.y[te], np.zeros((te.size, 1))).loglike(np.zeros(1))
            k = 0
        else:
            params = sm.OLS(st.y[tr], x[tr], hasconst=False).fit().params
            ll = sm.OLS(st.y[te], x[te], hasconst=False).loglike(params)
            k = x.shape[1]
        out[f] = -2.0 * ll + k * np.log(te.size)
    return out


def _new_columns(st: Stacked, cand: Candidate, xa: np.ndarray | None) -> np.ndarray:
    """Columns of ``cand`` that are non-zero and not already spanned by ``xa``."""
    xc = st.x(cand)
    keep = []
    for i in range(xc.shape[1]):
        c = xc[:, i]
        cc = c @ c
        if cc <= 1e-18 * st.n:
            continue
        if xa is not None and xa.shape[1]:
            coef, *_ = np.linalg.lstsq(xa, c, rcond=None)
            res = c - xa @ coef
            if 1.0 - (res @ res) / cc > DUPLICATE_R2:
                continue
        keep.append(i)
    return np.asarray(keep, dtype=int)


def _supported(st: Stacked, xa: np.ndarray | None, cand: Candidate, keep: np.ndarray
               ) -> np.ndarray:
    """``keep`` less the columns of a per-joint candidate whose coefficient has no support in
    the full-data fit (``|t| < MIN_T``; the best one stays if none has): a per-joint effect
    acting on one joint is then scored as one parameter, not six, and competes fairly with a
    smaller candidate of another kind that explains the same torque."""
    if keep.size <= 1 or not cand.per_column:
        return keep
    xc = st.x(cand, keep)
    x = xc if xa is None else np.hstack([xa, xc])
    fit = sm.OLS(st.y, x, hasconst=False).fit()
    t = np.abs(fit.tvalues[-keep.size:])
    pruned = keep[t >= MIN_T]
    return pruned if pruned.size else keep[[int(np.argmax(t))]]


def _stability(st: Stacked, xa: np.ndarray | None, xc: np.ndarray) -> float:
    x = xc if xa is None else np.hstack([xa, xc])
    k = xc.shape[1]
    full = xc @ sm.OLS(st.y, x, hasconst=False).fit().params[-k:]
    if not np.any(full):
        return 0.0
    good = 0
    for _ in range(BOOT_REPLICATES):
        rows = st.boot_rows()
        beta = sm.OLS(st.y[rows], x[rows], hasconst=False).fit().params[-k:]
        boot = xc @ beta
        if np.std(boot) > 0 and np.corrcoef(full, boot)[0, 1] > 0.9:
            good += 1
    return good / BOOT_REPLICATES


def _size(st: Stacked, xc: np.ndarray, beta: np.ndarray) -> float:
    """Max over joints of the effect's whitened RMS (= RMS in noise floors)."""
    tau = (xc @ beta).reshape(st.n, 6)
    return float(np.max(np.sqrt(np.mean(tau**2, axis=0))))


def _stack(st: Stacked, named: list[Named], skip: int | None = None) -> np.ndarray | None:
    parts = [st.x(nm.candidate, nm.keep) for i, nm in enumerate(named) if i != skip]
    return np.hstack(parts) if parts else None


def select(st: Stacked, candidates: list[Candidate]) -> tuple[list[Named], list[dict]]:
    """Greedy forward selection with held-out BIC, bootstrap stability and size.

    The residual ``r`` (N, 6) is whitened per joint by the noise floor (rows of joint ``j``
    divided by ``floor_j``, so the insertion force and the wrist torques count by their own
    noise) and stacked to one vector; a candidate's columns are whitened the same way. Then,
    greedily:

    1. **Held-out information criterion.** Time series: five *contiguous* folds
       (scikit-learn ``KFold`` without shuffling). In each fold both nested models (the effects
       accepted so far, with and without the candidate) are fitted on the other folds with
       statsmodels OLS, and scored on the held-out fold by ``BIC = -2 loglike + k log n`` with
       statsmodels' log-likelihood of the held-out rows at the training parameters.
       ``delta_bic`` is the sum over folds of ``BIC(with) - BIC(without)``: negative means the
       candidate predicts data it never saw better than its extra parameters cost.
    2. **Stability.** A moving-block bootstrap (1 s blocks) refits the model with the candidate;
       ``stability`` is the fraction of replicates whose fitted effect torque correlates above
       0.9 with the full-data one. An effect fitted to noise changes shape from replicate to
       replicate; a real one does not.
       Every remaining candidate is re-scored at every step: one without support alone may
       have it once another effect is named (a viscous term under a large unexplained offset);
       shapes profiled on the residual (Stribeck velocities, seal travel and static ratio) are
       re-profiled on what the named effects leave.
    3. **Size.** The effect's fitted torque must reach ``MIN_SIZE`` of the noise floor on at least
       one joint: with tens of thousands of rows a criterion can favour an effect that is real but
       too small to matter.

    A candidate is named when ``delta_bic < -MIN_DELTA_BIC`` with at least 4 of 5 folds in favour,
    ``stability >= MIN_STABILITY`` and the size test pass. Columns of a candidate already spanned
    by accepted effects (R^2 > 0.99) are removed first, so collinear duplicates (a spring's
    constant after an offset, a seal's Coulomb term after Coulomb friction) cannot be named twice.
    Finally every named effect is re-tested against all the others (drop-one ``delta_bic``) and
    the list is ordered by that evidence.

    Last, the named effects are fitted together; an effect whose coefficients turn unphysical
    there (a free-position payload whose mass goes negative once an offset takes the constant
    part it had absorbed) is refused and the selection runs again without it.

    Returns:
        (named effects ordered by evidence, the score table of every candidate at each step).
    """
    refused: list[dict] = []
    pool = list(candidates)
    while True:
        named, table = _select(st, pool)
        bad = _unphysical_together(st, named)
        if bad is None:
            return named, table + refused
        nm, why = bad
        refused.append({"step": "joint fit", "candidate": nm.candidate.label, "delta_bic": None,
                        "note": f"{why} once fitted with the other named effects; "
                                "selected again without it"})
        pool = [c for c in pool if c is not nm.candidate]


def _inadmissible(st: Stacked, cand: Candidate, keep: np.ndarray, beta: np.ndarray,
                  bse: np.ndarray) -> str | None:
    """:meth:`Candidate.inadmissible` of coefficients fitted on the columns ``keep``."""
    full_b, full_s = np.zeros(cand.columns.shape[2]), np.zeros(cand.columns.shape[2])
    full_b[keep], full_s[keep] = beta, bse
    unit = np.zeros(cand.columns.shape[2])          # torque RMS per unit, floors
    unit[keep] = np.sqrt(np.sum(st.x(cand, keep) ** 2, axis=0) / st.n)
    return cand.inadmissible(full_b, full_s, unit)


def _unphysical_together(st: Stacked, named: list[Named]) -> tuple[Named, str] | None:
    """The first named effect whose jointly fitted coefficients are inadmissible, and why."""
    for nm in named:
        why = _inadmissible(st, nm.candidate, nm.keep, nm.beta, nm.bse)
        if why:
            return nm, why
    return None


def _select(st: Stacked, candidates: list[Candidate]) -> tuple[list[Named], list[dict]]:
    """:func:`select`'s greedy forward pass, its re-check and the joint fit."""
    named: list[Named] = []
    table: list[dict] = []
    pool = list(candidates)          # not named yet, all re-scored at every step
    for step in range(MAX_EFFECTS):
        if named:
            # shapes profiled on the residual are re-profiled on what the named effects leave
            xa = _stack(st, named)
            left = (st.y - xa @ sm.OLS(st.y, xa, hasconst=False).fit().params).reshape(st.n, 6) / st.sw
            pool = [c.rebuild(left) if c.rebuild is not None else c for c in pool]
        accepted, _ = _step(st, named, pool, step, table)
        if accepted is None:
            break
        named.append(accepted)
        pool = [c for c in pool if c is not accepted.candidate]
    named = _recheck(st, named)
    _fit(st, named)
    return named, table


def _step(st: Stacked, named: list[Named], active: list[Candidate], step: int,
          table: list[dict]) -> tuple[Named | None, list]:
    """Score ``active`` candidates given ``named``; the first that passes every test, if any."""
    xa = _stack(st, named)
    base = _heldout_bic(st, xa)
    scored = []
    for cand in active:
        keep = _new_columns(st, cand, xa)
        if keep.size == 0:
            table.append({"step": step + 1, "candidate": cand.label, "delta_bic": None,
                          "note": "spanned by effects already named"})
            continue
        keep = _supported(st, xa, cand, keep)
        xc = st.x(cand, keep)
        per_fold = _heldout_bic(st, xc if xa is None else np.hstack([xa, xc])) - base
        scored.append((float(per_fold.sum()), int(np.sum(per_fold < 0)), cand, keep, xc))
    scored.sort(key=lambda s: s[0])
    accepted = None
    for dbic, folds, cand, keep, xc in scored:
        row = {"step": step + 1, "candidate": cand.label, "delta_bic": dbic,
               "folds_in_favour": folds}
        table.append(row)
        if accepted is not None or dbic > -MIN_DELTA_BIC or folds < MIN_FOLDS:
            continue
        x = xc if xa is None else np.hstack([xa, xc])
        fit = sm.OLS(st.y, x, hasconst=False).fit()
        beta, bse = fit.params[-xc.shape[1]:], fit.bse[-xc.shape[1]:]
        why = _inadmissible(st, cand, keep, beta, bse)
        if why:
            row["note"] = why
            continue
        size = _size(st, xc, beta)
        row["size"] = size
        if size < MIN_SIZE:
            row["note"] = f"too small ({size:.2f} noise floors)"
            continue
        stab = _stability(st, xa, xc)
        row["stability"] = stab
        if stab < MIN_STABILITY:
            row["note"] = f"unstable under bootstrap ({stab:.2f})"
            continue
        row["note"] = "named"
        accepted = Named(cand, keep, Evidence(dbic, folds, stab, size, dbic))
    return accepted, scored


def _recheck(st: Stacked, named: list[Named]) -> list[Named]:
    """Drop-one held-out BIC of each named effect given the others; drop the unsupported."""
    changed = True
    while changed and named:
        changed = False
        xall = _stack(st, named)
        full = _heldout_bic(st, xall)
        for i, nm in enumerate(named):
            without = _heldout_bic(st, _stack(st, named, skip=i))
            per_fold = full - without
            nm.evidence.delta_bic = float(per_fold.sum())
            nm.evidence.folds_in_favour = int(np.sum(per_fold < 0))
        worst = max(range(len(named)), key=lambda i: named[i].evidence.delta_bic)
        if len(named) > 1 and (named[worst].evidence.delta_bic > -MIN_DELTA_BIC
                               or named[worst].evidence.folds_in_favour < MIN_FOLDS):
            named.pop(worst)
            changed = True
    named.sort(key=lambda nm: nm.evidence.delta_bic)
    return named


def _fit(st: Stacked, named: list[Named]) -> None:
    """Joint full-data fit of all named effects; fills beta and bse."""
    if not named:
        return
    res = sm.OLS(st.y, _stack(st, named), hasconst=False).fit()
    i = 0
    for nm in named:
        k = nm.keep.size
        nm.beta, nm.bse = res.params[i:i + k], res.bse[i:i + k]
        i += k


def heldout_prediction(st: Stacked, named: list[Named]) -> np.ndarray:
    """Out-of-fold prediction (N, 6) of the named effects' torque [physical units]."""
    pred = np.zeros(st.n * 6)
    if named:
        x = _stack(st, named)
        for tr, te in st.folds:
            pred[te] = x[te] @ sm.OLS(st.y[tr], x[tr], hasconst=False).fit().params
    return pred.reshape(st.n, 6) / st.sw


@dataclass(frozen=True)
class Alternative:
    """Another candidate's best fit of a named effect's torque: ``r2`` (whitened) and
    ``misfit`` (what it leaves of the effect, RMS in noise floors on its worst joint)."""

    label: str
    r2: float
    misfit: float

    @property
    def indistinguishable(self) -> bool:
        """The alternative leaves less of the effect than an effect must reach to be named
        (``MIN_SIZE`` noise floors): on this motion the data cannot tell the two apart."""
        return self.misfit < MIN_SIZE


def alternatives(st: Stacked, named: list[Named], candidates: list[Candidate]
                 ) -> dict[str, list[Alternative]]:
    """For each named effect, the other candidates that reproduce its fitted torque with a
    whitened ``R^2 >= ALTERNATIVE_R2``, best first: where the workflow names one place or
    kind, these say which others the motion barely tells it from (Coulomb friction on a
    wrist joint from the cable coupling; viscous friction on the insertion from the seal).
    """
    out: dict[str, list[Alternative]] = {}
    for nm in named:
        target = st.x(nm.candidate, nm.keep) @ nm.beta
        total = float(target @ target)
        found = []
        for cand in candidates:
            if cand.label == nm.candidate.label or total <= 0.0:
                continue
            x = st.x(cand)
            x = x[:, np.any(x != 0.0, axis=0)]
            if x.shape[1] == 0:
                continue
            coef, *_ = np.linalg.lstsq(x, target, rcond=None)
            left = target - x @ coef
            r2 = 1.0 - float(left @ left) / total
            if r2 >= ALTERNATIVE_R2:
                misfit = float(np.max(np.sqrt(np.mean(left.reshape(st.n, 6) ** 2, axis=0))))
                found.append(Alternative(cand.label, r2, misfit))
        out[nm.candidate.label] = sorted(found, key=lambda a: -a.r2)
    return out
