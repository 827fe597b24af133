"""The free-motion residual's scale, per joint: what one unit of the gate's score is.

The residual (measured minus predicted joint torque) of free motion is noise plus whatever
the model has not learned yet. :class:`ResidualScale` keeps a slow running RMS about zero per
joint (``river``'s exponentially weighted mean of the squared residual, time constant tens of
seconds) of the samples the gate called free, and normalises each sample by it
(``z_j = r_j / scale_j``). It is centred on zero, not on a running mean: a contact's force
builds up over a second or more and a fast mean would follow it; a bias is the correction
net's job.

Rules that keep a contact from widening the bounds that detect it (all in
:class:`~wrenchd.models.gate.GateConfig`):

* a warm-up of ``warmup_samples`` learns every sample (plain mean), optionally its robust
  part only (``robust_warmup``, :func:`warmup_mean_square`); a ``prior`` scale bounds it;
* afterwards only free samples scoring under ``learn_sigma`` teach it, and it never exceeds
  ``max_growth`` times its warm-up value; ``min_std`` floors it;
* a training scale learns beside it from the plain warm-up (which free samples may train);
* :class:`ReversalSpread`: soon after a joint's velocity reversed, friction is hardest to
  model and the residual several times wider: each joint's spread there is learnt apart.

Cost: squared scores are summed per sample and handed to ``river`` once per ``learn_block``
samples (fading factor ``1 - (1 - alpha)^k``: the same exponential memory).
"""

from __future__ import annotations

import bisect
import copy
import math
from typing import TYPE_CHECKING

import numpy as np
from river import stats

from wrenchd.models.errors import DataError
from wrenchd.models.series import N_JOINTS

if TYPE_CHECKING:
    from wrenchd.models.gate import GateConfig

#: pseudo-samples of spread 1 (the steady scale) a reversal bin starts with: a bin's first
#: few samples cannot widen it alone
REVERSAL_PRIOR_COUNT = 20


def warmup_mean_square(residuals: np.ndarray, within_sigma: float) -> np.ndarray:
    """Mean square per joint of the free samples among warm-up residuals.

    A sample counts as free when every joint's |residual| is within ``within_sigma`` robust
    sigmas of zero (sigma: 1.4826 x the joint's median |residual|, which a contact filling
    less than half the window hardly moves); a contact loads several joints far beyond that.

    Args:
        residuals: (N, 6) residual torques [N m; N on insertion].
        within_sigma: bound in robust sigmas.
    Returns:
        (6,) mean square [N^2 m^2; N^2], of all samples when none is within the bound.

    >>> r = np.full((10, 6), 0.1); r[0] = 5.0          # one contact-like row among ten
    >>> warmup_mean_square(r, 6.0).round(4).tolist()
    [0.01, 0.01, 0.01, 0.01, 0.01, 0.01]
    """
    r = np.asarray(residuals, dtype=float)
    sigma = 1.4826 * np.median(np.abs(r), axis=0)
    keep = (np.abs(r) <= within_sigma * sigma).all(axis=1)
    return np.mean((r[keep] if keep.any() else r) ** 2, axis=0)


class ReversalSpread:
    """How much wider each joint's free-motion residual is soon after its velocity reversed.

    A joint is *reversing* while its speed is under ``slow`` or its velocity's sign has just
    changed; each sample falls in the first bin whose upper edge (``edges``, seconds since
    the joint last reversed) it is under, or in the steady bin. Each reversal bin learns its
    mean square score on the steady scale (plain mean over its first samples, then fading
    with weight ``alpha``); its spread factor is the root of that, between 1 and
    ``max_factor``. On the simulated PSM the insertion's residual is 3-7 times its usual
    spread in the first 50 ms after a reversal, the wrist joints' about twice over 100-200 ms.
    """

    def __init__(self, edges: tuple[float, ...], slow: tuple[float, ...], alpha: float,
                 max_factor: float) -> None:
        self._edges, self._slow = list(edges), list(slow)
        self._alpha, self._max_sq = alpha, max_factor * max_factor
        k = len(edges)
        self._msq = [[1.0] * N_JOINTS for _ in range(k)]
        self._n = [[float(REVERSAL_PRIOR_COUNT)] * N_JOINTS for _ in range(k)]
        self._factor_sq = [[1.0] * N_JOINTS for _ in range(k + 1)]   # last: steady motion
        self._sign = [0] * N_JOINTS
        self._since = [-math.inf] * N_JOINTS
        self._bins = [k] * N_JOINTS

    def reversed_within(self, t: float, within_s: float) -> list[bool]:
        """Per joint: did it reverse (or crawl under ``slow``) less than ``within_s`` before
        ``t`` [s], as of the last :meth:`factors_sq`."""
        return [t - since < within_s for since in self._since]

    def factors_sq(self, t: float, velocity) -> list[float]:
        """Each joint's squared spread factor for a sample at ``t`` [s] with joint
        velocities ``velocity`` (6,) [rad/s; m/s] (remembered for :meth:`learn`)."""
        out = []
        for j, v in enumerate(velocity):
            lim = self._slow[j]
            s = 1 if v > lim else (-1 if v < -lim else 0)
            if s == 0:
                self._since[j] = t
            elif s != self._sign[j]:
                if self._sign[j]:                # not a joint's first motion seen
                    self._since[j] = t
                self._sign[j] = s
            b = bisect.bisect_left(self._edges, t - self._since[j])
            self._bins[j] = b
            out.append(self._factor_sq[b][j])
        return out

    def learn(self, zsq_steady: list[float]) -> None:
        """Learn the last sample's squared scores on the steady scale (6,)."""
        k = len(self._edges)
        for j, b in enumerate(self._bins):
            if b < k:
                n = self._n[b][j] + 1.0
                self._n[b][j] = n
                m = self._msq[b][j]
                m += max(self._alpha, 1.0 / n) * (zsq_steady[j] - m)
                self._msq[b][j] = m
                self._factor_sq[b][j] = min(max(m, 1.0), self._max_sq)

    def factors(self) -> np.ndarray:
        """(bins + 1, 6) spread factors, the steady bin last."""
        return np.sqrt(np.asarray(self._factor_sq))


class ResidualScale:
    """Per-joint scale of the free-motion residual [N m; N on insertion] (module docstring).

    >>> from wrenchd.models.gate import GateConfig
    >>> scale = ResidualScale(GateConfig(warmup_samples=20, learn_block=5, reversal_bins_s=()))
    >>> for _ in range(20):
    ...     zsq, steady = scale.squared_scores([0.2] * 6)
    ...     scale.warm([0.2] * 6, steady, zsq)
    >>> scale.calibrated, scale.std.round(3).tolist()
    (True, [0.2, 0.2, 0.2, 0.2, 0.2, 0.2])
    """

    def __init__(self, config: GateConfig) -> None:
        c = self.config = config
        if len(c.min_std) != N_JOINTS:
            raise DataError(f"min_std needs {N_JOINTS} values")
        self.floor = np.asarray(c.min_std, dtype=float)
        self._block_fading = 1.0 - (1.0 - c.alpha) ** c.learn_block
        self.reset()

    def reset(self, prior: np.ndarray | None = None) -> None:
        """Forget everything; ``prior`` (6,) [N m; N] bounds the warm-up's scale to between
        1 and ``max_growth`` times it (floored by ``min_std``)."""
        if prior is None:
            self._prior = None
        else:
            prior = np.asarray(prior, dtype=float)
            if prior.shape != (N_JOINTS,) or not np.isfinite(prior).all():
                raise DataError(f"a gate's prior scale needs {N_JOINTS} finite values, "
                                f"got {prior!r}")
            lo = np.maximum(prior, self.floor)
            self._prior = (lo ** 2, (self.config.max_growth * lo) ** 2)
        c = self.config
        self._msq = [stats.EWMean(fading_factor=self._block_fading) for _ in range(N_JOINTS)]
        self._warm = [stats.Mean() for _ in range(N_JOINTS)]     # plain mean while warming up
        self._warm_buf = (np.empty((c.warmup_samples, N_JOINTS)) if c.robust_warmup else None)
        self.reversal = (ReversalSpread(c.reversal_bins_s, c.slow_velocity, c.reversal_alpha,
                                        c.max_reversal_factor) if c.reversal_bins_s else None)
        self._acc = [0.0] * N_JOINTS           # sum of squared scores not yet learned
        self._n_acc = 0
        self.seen = 0
        self._cap = np.full(N_JOINTS, np.inf)
        self._msq_train = [stats.EWMean(fading_factor=self._block_fading) for _ in range(N_JOINTS)]
        self._cap_train = np.full(N_JOINTS, np.inf)
        self.std = self.floor.copy()
        self._inv_var = (1.0 / self.std ** 2).tolist()
        self._inv_var_train = self._inv_var
        self._motion: ReversalSpread | None = None

    @property
    def calibrated(self) -> bool:
        return self.seen >= self.config.warmup_samples

    def seed(self, std: np.ndarray) -> None:
        """Start calibrated at RMS ``std`` (6,) [N m; N] (floored), growing up to
        ``max_growth`` times it."""
        std = np.asarray(std, dtype=float)
        if std.shape != (N_JOINTS,) or not np.isfinite(std).all():
            raise DataError(f"a gate's seed scale needs {N_JOINTS} finite values, got {std!r}")
        self.reset()
        c = self.config
        rms = np.maximum(std, self.floor)
        for j in range(N_JOINTS):
            self._warm[j].update(float(rms[j]) ** 2)
            self._msq[j].update(float(rms[j]) ** 2)
            self._cap[j] = c.max_growth * float(rms[j])
            self._msq_train[j].update(float(rms[j]) ** 2)
            self._cap_train[j] = self._cap[j]
        self.seen = c.warmup_samples
        self._refresh()

    def rescale(self, std: np.ndarray) -> None:
        """Move a calibrated scale to RMS ``std`` (6,) [N m; N] (floored)."""
        std = np.asarray(std, dtype=float)
        if std.shape != (N_JOINTS,) or not np.isfinite(std).all():
            raise DataError(f"a gate's scale needs {N_JOINTS} finite values, got {std!r}")
        if not self.calibrated:
            raise DataError("only a calibrated (warmed-up or seeded) gate can be rescaled")
        rms = np.maximum(std, self.floor)
        self._acc = [0.0] * N_JOINTS
        self._n_acc = 0
        for j in range(N_JOINTS):
            self._restart(j, float(rms[j]) ** 2, self.config.max_growth * float(rms[j]))
        self._refresh()

    def relearn(self, rows: np.ndarray, r: list[float], widen: float = 1.0,
                at_least: np.ndarray | None = None) -> None:
        """Restart on residuals ``rows`` (n, 6) (their mean square within
        ``warmup_trim_sigma`` robust sigmas), on the residual ``r`` (6,) when n < 6; their
        RMS times ``widen``, and no narrower than RMS ``at_least`` (6,) where given."""
        msq = (warmup_mean_square(rows, self.config.warmup_trim_sigma)
               if len(rows) >= N_JOINTS else np.asarray(r) ** 2) * (widen * widen)
        if at_least is not None:
            msq = np.maximum(msq, np.asarray(at_least, dtype=float) ** 2)
        self._acc = [0.0] * N_JOINTS
        self._n_acc = 0
        for j in range(N_JOINTS):
            rms = math.sqrt(float(msq[j]))
            self._restart(j, float(msq[j]), self.config.max_growth * max(rms, self.floor[j]))
        self._refresh()

    def snapshot(self) -> dict:
        """The learnt level of a calibrated scale (the statistics of the scale and the
        training scale, their bounds and what is summed toward them; not the reversal
        spread), for :meth:`restore`."""
        return copy.deepcopy({k: getattr(self, k) for k in self._LEVEL})

    def restore(self, snapshot: dict) -> None:
        """Go back to a level taken by :meth:`snapshot` (the reversal spread goes on); the
        scales follow from it."""
        for k, v in snapshot.items():
            setattr(self, k, v)
        self._refresh()

    _LEVEL = ("_msq", "_msq_train", "_cap", "_cap_train", "_acc", "_n_acc")

    def _restart(self, j: int, mean_square: float, cap: float) -> None:
        """Joint ``j``'s scale and training scale start afresh at ``mean_square``, bound
        ``cap``."""
        for msq in (self._msq, self._msq_train):
            msq[j] = stats.EWMean(fading_factor=self._block_fading)
            msq[j].update(mean_square)
        self._cap[j] = self._cap_train[j] = cap

    def squared_scores(self, r: list[float], t: float = 0.0,
                       velocity=None) -> tuple[list[float], list[float]]:
        """``(zsq, steady)``: squared scores (6,) of residual ``r``, on the steady scale
        widened where a joint just reversed (with ``velocity`` (6,)), and on the steady
        scale alone."""
        steady = [a * a * b for a, b in zip(r, self._inv_var)]
        motion = self._motion = self.reversal if velocity is not None else None
        if motion is None:
            return steady, steady
        v = velocity.tolist() if isinstance(velocity, np.ndarray) else velocity
        return [z / f for z, f in zip(steady, motion.factors_sq(t, v))], steady

    def warm(self, r: list[float], steady: list[float], zsq: list[float]) -> None:
        """Learn a warm-up sample (the last one scored)."""
        if self._warm_buf is not None:
            self._warm_buf[self.seen] = r
        self.learn(steady, zsq)

    def learn(self, steady: list[float], zsq: list[float]) -> None:
        """Learn the last sample scored, as free motion."""
        if self._motion is not None:
            self._motion.learn(steady)
        self._acc = [a + x for a, x in zip(self._acc, zsq)]
        self._n_acc += 1
        self.seen += 1
        c = self.config
        if self.seen <= c.warmup_samples:
            if self._n_acc >= c.learn_block or self.seen == c.warmup_samples:
                self._flush()
        elif self._n_acc >= c.learn_block:
            self._flush()

    def train_score(self, r: list[float]) -> float:
        """Peak score of ``r`` on the training scale (plain warm-up, not widened)."""
        return math.sqrt(max(a * a * b for a, b in zip(r, self._inv_var_train)))

    def _refresh(self) -> None:
        if self.seen < self.config.warmup_samples:
            rms = np.sqrt(np.array([m.get() for m in self._warm]))
        else:
            rms = np.minimum(np.sqrt(np.array([m.get() for m in self._msq])), self._cap)
        self.std = np.maximum(rms, self.floor)
        self._inv_var = (1.0 / self.std ** 2).tolist()
        if self.seen >= self.config.warmup_samples and self._msq_train[0].get():
            rt = np.minimum(np.sqrt(np.array([m.get() for m in self._msq_train])),
                            self._cap_train)
            self._inv_var_train = (1.0 / np.maximum(rt, self.floor) ** 2).tolist()
        else:
            self._inv_var_train = self._inv_var

    def _flush(self) -> None:
        """Hand the summed squares to the river statistics and refresh the scale."""
        n, c = self._n_acc, self.config
        if n == 0:
            return
        # the block summed z^2 = r^2 / scale^2 under one scale: back to r^2
        var = (self.std ** 2).tolist()
        mean_sq = [a * v / n for a, v in zip(self._acc, var)]
        if self.seen <= c.warmup_samples:              # this block ends in the warm-up
            for j in range(N_JOINTS):
                self._warm[j].update(mean_sq[j], n)
            if self.seen == c.warmup_samples:
                self._end_warmup()
        else:
            for j in range(N_JOINTS):
                self._msq[j].update(mean_sq[j])
                self._msq_train[j].update(mean_sq[j])
        self._acc = [0.0] * N_JOINTS
        self._n_acc = 0
        self._refresh()

    def _end_warmup(self) -> None:
        """Seed the slow averages and their caps from the warm-up (trimmed with
        ``robust_warmup``; within the prior's bounds when there is one)."""
        c = self.config
        trimmed = (None if self._warm_buf is None
                   else warmup_mean_square(self._warm_buf, c.warmup_trim_sigma))
        for j in range(N_JOINTS):
            warm = self._warm[j].get() if trimmed is None else float(trimmed[j])
            plain = self._warm[j].get()
            if self._prior is not None:
                lo, hi = self._prior[0][j], self._prior[1][j]
                warm, plain = min(max(warm, lo), hi), min(max(plain, lo), hi)
            self._msq[j] = stats.EWMean(fading_factor=self._block_fading)
            self._msq[j].update(warm)
            self._cap[j] = c.max_growth * max(math.sqrt(warm), self.floor[j])
            self._msq_train[j] = stats.EWMean(fading_factor=self._block_fading)
            self._msq_train[j].update(plain)
            self._cap_train[j] = c.max_growth * max(math.sqrt(plain), self.floor[j])
