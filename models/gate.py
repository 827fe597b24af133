"""Free-motion gate: is this sample's residual torque small enough to call it free motion?

The residual (measured minus predicted joint torque) of free motion is noise plus whatever
the model has not learned yet; a contact adds ``J^T w`` on top. The gate keeps a slow running
scale of the residual of the samples it judged free (``river`` exponentially weighted mean of
the squared residual per joint, i.e. an RMS about zero) and normalises each sample's residual
by it (``z_j = r_j / scale_j``). Two scores, two ways into a contact:

* the **peak** score ``max_j |z_j|``: a contact that loads one joint hard (a push along the
  shaft) starts when it exceeds ``enter_sigma`` on ``enter_samples`` consecutive samples;
* the **joint** score ``sqrt(mean_j z_j^2)``: a weak contact loads several joints at once,
  each under the peak bound (a lateral grasp of a few N at shallow insertion can hold four
  joints at 2-3 scale units for over a second, unseen by the peak score). It starts a
  contact when it exceeds ``joint_sigma`` on ``joint_samples`` consecutive samples. Free
  motion's model error is mostly in one joint at a time, so the joint score stays low there
  (mostly under 2).

A contact ends when, for ``exit_s``, the peak score stays under ``exit_sigma`` and the joint
score has not been over ``joint_exit_sigma`` for ``joint_samples`` samples in a row
(hysteresis: a contact whose force passes through zero is not chopped into pieces; a run
length, not single samples, for the joint score, whose free-motion noise often exceeds 1).
With ``joint_without_peak`` (off by default) the joint score leaves out the peak joint, so a
spike on one joint (the insertion's friction at a velocity reversal) cannot start a contact
through it; on the simulated drift scenarios that raised precision but cost recall (weak
contacts are often carried by one joint more than the others).

Free-motion model error is not spread evenly in time: friction is hardest to model where a
joint turns round, and its residual there is several times its usual size for a few tens of
milliseconds (the simulated insertion: 3-7 times in the first 50 ms after a reversal; the
wrist joints about twice for 100-200 ms). Given the joint velocities, the gate learns each
joint's spread apart for samples soon after its velocity reversed or while it is slow
(``reversal_bins_s``, ``slow_velocity``; :class:`ReversalSpread`) and scores those samples
against it; the scale itself learns from the samples brought back to the steady spread.
Which free samples may train is still judged on the steady scale: a reversal's spike is
free motion, not a sample to learn from. Without velocities, one spread for all samples.

The hysteresis protects training; the published flag need not wait for it. With
``release_free`` a contact is *released* at its first sample under both exit bounds: from
there its samples are published free (the force is gone: the release ramp is over in a few
tenths of a second, ``exit_s`` later the contact would end) but stay the contact's
(``contact_started`` set, never ``trainable``) until it ends; a released contact is published
again only on a new entry (the enter bounds held for their run), not at every sample over an
exit bound (free-motion noise crosses 3 on one joint often enough to chop the release into
flickers).

The statistics only learn from free samples scoring under ``learn_sigma``, and the scale may
never grow beyond ``max_growth`` times its warm-up value, so a contact, even one that starts
too gently to be seen, cannot widen the bounds that detect it (without these two rules,
contacts that slip through widen the scale until contacts of several N are called free).
``trainable`` is stricter than ``free``: a free sample whose peak score is over ``train_sigma``
is published as free but kept out of training. The scale is centred on zero, not on a running
mean, and slow (``alpha``: a time constant of tens of seconds): a contact's force builds up
over a second or more, and a fast running mean would follow it up and never see it (with a
2.5 s mean, contacts of several N score about 2 sigma). A bias of the residual is the correction
net's job, not the gate's. A floor ``min_std`` (per joint, N m or N) keeps the bounds from
collapsing onto the noise of a perfectly adapted model. A gate stuck in contact for longer than
``max_contact_s`` is re-calibrated (its scale moves to the present residual): a lasting change
of the set-up (a new insufflation pressure) must not look like an endless contact; the pipeline
reports it.

A lasting change of the set-up (a load on a link, a heavier instrument) adds a torque that
depends on the pose; a contact at the tip adds ``J^T f`` with a force ``f`` that changes with
the tissue, not with the pose. Given the tip force estimate, a contact that has lasted
``setup_contact_s`` is judged on the force implied at the tip over that time: a tip contact
keeps its direction (``|mean f| / RMS |f|`` near 1), a set-up change seen through ``J^-T``
swings with the pose (the ratio well under 1). Under ``steady_force_ratio``, and no larger
than a load or an instrument changes the tip force by (``setup_max_force_n``: a grasp of
several newtons is a contact whatever its direction does, and learning one silently is the
costly mistake; a larger change is announced, or waits for ``max_contact_s``), the contact is
taken for a set-up change: the gate re-learns its scale on the contact's residual and lets
training resume after ``setup_probation_s`` (the new set-up is free motion to learn, not a
contact to wait out); over it, the contact goes on and is judged again after as long
again. Contacts that follow one another within ``setup_gap_s`` (a residual hovering about
the exit bounds is ended and found again every few seconds) count as one lasting contact
here. Either re-learning (this one, or ``max_contact_s``'s) takes the scale from the
contact's residual sampled every ``SETUP_STRIDE`` samples (the mean square of the samples
within ``warmup_trim_sigma`` robust sigmas, so a spike at its start or a contact inside it
does not widen the new scale), not from the present sample alone. The contact's samples are
buffered every ``SETUP_STRIDE`` samples and judged once per ``setup_contact_s``: the hot path
gains a counter and, now and then, one row written.

The warm-up learns every sample: the pipeline's calibration guard judges them meanwhile, and a
contact in the warm-up would otherwise be learnt as free motion, widening the scale several
times for tens of seconds (and ``max_growth`` caps nothing then: the cap is set from the
warm-up). With ``robust_warmup`` the warm-up's scale is the RMS of its samples that lie within
``warmup_trim_sigma`` robust sigmas (1.4826 x median |residual|) on every joint: a contact
filling less than half the window hardly moves the median and loads its joints far beyond
that bound, while the free-motion residual's heavy tail (friction spikes at a velocity
reversal) mostly stays inside it. Learning after the warm-up is unchanged. Which free samples
may train (``train_sigma``) is still judged on the plain warm-up's scale, kept beside it and
learning the same samples: on the narrower scale, fewer free samples trained after a set-up
change and the recovery from it suffered. Off by default until more seeds confirm it
(docs/results.md).

A prior scale (``reset(prior=...)``: the pipeline's calibration, the residual RMS of the
samples its guard called free) keeps the warm-up's scale within 1 and ``max_growth`` times it:
a warm-up of a few seconds that falls on a contact would otherwise start the gate two to four
times too wide, for the minute or more the slow scale takes to come down.

A gate that starts judging (its warm-up over: in the pipeline, where it takes over from the
calibration guard; :meth:`FreeMotionGate.settle`) makes nothing trainable for ``exit_s``: a
contact too weak for its enter bounds may be in progress then, and must show the quiet that
ends a contact the gate found before its samples may train.

Cost: the squared residuals of learning samples are summed in NumPy and handed to the river
statistics once per ``learn_block`` samples (as their mean, with the per-sample fading factor
compounded over the block, ``1 - (1 - alpha)^k``: the same exponential memory), and the scale
is recomputed only then; the per-sample work is a few NumPy operations on six numbers.

Besides the flag, the gate gives the pipeline what it needs to keep contact out of training:
the sample index at which the current contact began, so samples buffered before that moment
(the onset, when the force was still under the bound) can be dropped.
"""

from __future__ import annotations

import bisect
import math
from typing import NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from river import stats

from wrenchd.models.errors import DataError
from wrenchd.models.series import N_JOINTS


class GateConfig(BaseModel):
    """Bounds and hysteresis of the free-motion gate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enter_sigma: float = Field(default=5.0, gt=0.0,
                               description="peak score that starts a contact [scale units]")
    enter_samples: int = Field(default=10, ge=1,
                               description="consecutive samples above enter_sigma")
    joint_sigma: float = Field(default=1.5, gt=0.0,
                               description="joint (RMS over joints) score that starts a contact")
    joint_samples: int = Field(default=20, ge=1,
                               description="consecutive samples above joint_sigma")
    exit_sigma: float = Field(default=3.0, gt=0.0,
                              description="peak score under which a contact may end")
    joint_exit_sigma: float = Field(default=1.0, gt=0.0,
                                    description="joint score a contact must not keep "
                                                "(joint_samples in a row) to end")
    exit_s: float = Field(default=0.5, ge=0.0, description="time below exit to end a contact [s]")
    alpha: float = Field(default=2e-4, gt=0.0, lt=1.0,
                         description="weight of a new free sample in the running RMS")
    learn_block: int = Field(default=20, ge=1,
                             description="learning samples summed before the statistics update")
    warmup_samples: int = Field(default=1000, ge=1,
                                description="samples before the gate may call anything free")
    min_std: tuple[float, ...] = Field(
        default=(0.02, 0.02, 0.1, 0.002, 0.002, 0.002),
        description="floor of each joint's residual std [N m; N on insertion]")
    max_contact_s: float = Field(
        default=60.0, gt=0.0,
        description="a longer contact re-calibrates the gate [s]; for as long again after it, "
                    "nothing is trainable (the rest of a very long contact must not train)")
    setup_contact_s: float = Field(
        default=10.0, ge=0.0,
        description="a contact this long is judged for a set-up change, on the tip force "
                    "(given) over it, and again after as long again [s]; 0: never")
    setup_gap_s: float = Field(
        default=0.5, ge=0.0,
        description="contacts less than this apart (one's end to the next one's start) count "
                    "as one for setup_contact_s [s]: a set-up change the gate keeps ending "
                    "and finding again is one lasting contact")
    steady_force_ratio: float = Field(
        default=0.8, gt=0.0, le=1.0,
        description="a tip force whose |mean| / RMS over setup_contact_s is under this swings "
                    "with the pose: a set-up change, its scale re-learnt")
    setup_max_force_n: float = Field(
        default=5.0, gt=0.0,
        description="a lasting contact whose tip force RMS is over this is never taken for "
                    "a set-up change [N] (a grasp of several N held for seconds is a contact "
                    "whatever its direction does; a larger change must be announced)")
    setup_probation_s: float = Field(
        default=2.0, ge=0.0,
        description="nothing is trainable for this long after a set-up change re-learnt [s]")
    learn_sigma: float = Field(default=4.0, gt=0.0,
                               description="only samples scoring below this teach the scale")
    train_sigma: float = Field(default=2.0, gt=0.0,
                               description="only free samples scoring below this may train")
    max_growth: float = Field(default=2.0, ge=1.0,
                              description="the scale never exceeds this x its warm-up value")
    robust_warmup: bool = Field(
        default=False,
        description="the warm-up's scale is the RMS of its samples within warmup_trim_sigma "
                    "robust sigmas (1.4826 x median |residual|) on every joint, not of all of "
                    "them (a contact in the warm-up is not learnt as free motion); which free "
                    "samples may train is still judged on the plain warm-up's scale "
                    "(docs/results.md)")
    warmup_trim_sigma: float = Field(
        default=6.0, gt=0.0,
        description="robust_warmup's bound [robust sigmas]")
    joint_without_peak: bool = Field(
        default=False,
        description="the joint score leaves out the joint with the peak score (one joint's "
                    "spike is the peak score's to judge)")
    reversal_bins_s: tuple[float, ...] = Field(
        default=(0.05, 0.1, 0.2, 0.4),
        description="with velocities given, each joint's residual spread is learnt apart for "
                    "samples this soon after its velocity reversed or was under slow_velocity "
                    "[s, increasing upper bin edges]; empty: one spread for all samples")
    slow_velocity: tuple[float, ...] = Field(
        default=(0.02, 0.02, 0.002, 0.04, 0.04, 0.04),
        description="a joint this slow counts as reversing [rad/s; m/s on insertion]")
    reversal_alpha: float = Field(
        default=2e-3, gt=0.0, lt=1.0,
        description="least weight of a new sample in a reversal bin's mean square (the first "
                    "ones are averaged plainly)")
    max_reversal_factor: float = Field(
        default=10.0, ge=1.0,
        description="a reversal bin's spread is between 1 and this x the joint's scale")
    release_free: bool = Field(
        default=True,
        description="while a contact's exit is pending (under the exit bounds, exit_s not yet "
                    "over) publish the sample free; it stays out of training")


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
    """
    r = np.asarray(residuals, dtype=float)
    sigma = 1.4826 * np.median(np.abs(r), axis=0)
    keep = (np.abs(r) <= within_sigma * sigma).all(axis=1)
    return np.mean((r[keep] if keep.any() else r) ** 2, axis=0)


#: a contact's residual and tip force are buffered every this many samples (the set-up check
#: and the re-learnt scale read them), in a ring of ``SETUP_RING`` rows
SETUP_STRIDE, SETUP_RING = 10, 1024


#: pseudo-samples of spread 1 (the steady scale) a reversal bin starts with: a bin's first
#: few samples cannot widen it alone
REVERSAL_PRIOR_COUNT = 20


class ReversalSpread:
    """How much wider each joint's free-motion residual is soon after its velocity reversed.

    Friction is hardest to model where a joint turns round (pre-sliding, Stribeck): on the
    simulated PSM the insertion joint's free-motion residual is 3-7 times its usual spread in
    the first 50 ms after a reversal and the wrist joints' about twice, over 100-200 ms;
    a contact does not prefer those moments. A joint is *reversing* while its speed is
    under ``slow`` or its velocity's sign has just changed; each sample falls in the first
    bin whose upper edge (``edges``, seconds since the joint last reversed) it is under, or
    in the steady bin. Each reversal bin learns its mean square score on the steady scale
    (plain mean over its first samples, then fading with weight ``alpha``), and its spread
    factor is the root of that, between 1 and ``max_factor``.
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


class GateDecision(NamedTuple):
    """One sample's verdict (an immutable named tuple: cheap to make once per sample).

    Attributes:
        free: free motion (published with the estimate); with ``release_free`` also a
            released contact's samples, which keep ``contact_started`` (the pipeline keeps
            them out of training and drift as contact).
        score: peak score, largest per-joint |residual| / scale [scale units].
        contact_started: sample index where the current contact began (-1 when free; at the
            sample that ends a contact, still that contact's onset).
        recalibrated: the gate re-calibrated at this sample (stuck in contact too long, or
            a set-up change).
        trainable: free and quiet enough to train on.
        setup_change: the contact ending at this sample was taken for a set-up change (the
            tip force swung with the pose); ``recalibrated`` is set too.
    """

    free: bool
    score: float
    contact_started: int
    recalibrated: bool = False
    trainable: bool = False
    setup_change: bool = False


class FreeMotionGate:
    """Running-statistics residual gate with hysteresis (see the module docstring)."""

    def __init__(self, config: GateConfig | None = None) -> None:
        self.config = c = config if config is not None else GateConfig()
        if len(c.min_std) != N_JOINTS:
            raise DataError(f"min_std needs {N_JOINTS} values")
        if c.exit_sigma > c.enter_sigma or c.joint_exit_sigma > c.joint_sigma:
            raise DataError("an exit bound must not exceed its enter bound")
        if len(c.slow_velocity) != N_JOINTS:
            raise DataError(f"slow_velocity needs {N_JOINTS} values")
        if any(b <= a for a, b in zip((0.0,) + c.reversal_bins_s, c.reversal_bins_s)):
            raise DataError(f"reversal_bins_s must be positive and increasing, "
                            f"got {c.reversal_bins_s}")
        self._floor = np.asarray(c.min_std, dtype=float)
        self._block_fading = 1.0 - (1.0 - c.alpha) ** c.learn_block
        self.reset()

    def reset(self, prior: np.ndarray | None = None) -> None:
        """Forget the statistics (a new set-up).

        Args:
            prior: (6,) a free-motion residual RMS known from elsewhere [N m; N on
                insertion] (the pipeline's calibration): the warm-up's scale is kept within
                1 and ``max_growth`` times it (floored by ``min_std``), so a warm-up that
                falls on a contact cannot start the gate several times too wide, nor a
                quiet one too narrow.
        """
        if prior is None:
            self._prior = None
        else:
            prior = np.asarray(prior, dtype=float)
            if prior.shape != (N_JOINTS,) or not np.isfinite(prior).all():
                raise DataError(f"a gate's prior scale needs {N_JOINTS} finite values, "
                                f"got {prior!r}")
            lo = np.maximum(prior, self._floor)
            self._prior = (lo ** 2, (self.config.max_growth * lo) ** 2)
        self._msq = [stats.EWMean(fading_factor=self._block_fading) for _ in range(N_JOINTS)]
        self._warm = [stats.Mean() for _ in range(N_JOINTS)]     # plain mean while warming up
        c = self.config
        self._warm_buf = (np.empty((c.warmup_samples, N_JOINTS)) if c.robust_warmup else None)
        self.reversal = (ReversalSpread(c.reversal_bins_s, c.slow_velocity, c.reversal_alpha,
                                        c.max_reversal_factor) if c.reversal_bins_s else None)
        self._acc = [0.0] * N_JOINTS           # sum of squared residuals not yet learned
        self._n_acc = 0
        self._seen = 0
        self._probation_until = -math.inf      # nothing trains before this (after a re-calibration)
        self._cap = np.full(N_JOINTS, np.inf)
        self._msq_train = [stats.EWMean(fading_factor=self._block_fading) for _ in range(N_JOINTS)]
        self._cap_train = np.full(N_JOINTS, np.inf)
        self._std = self._floor.copy()
        self._inv_var = (1.0 / self._std ** 2).tolist()
        self._in_contact = False
        self._published = False                # a contact published as such (release_free)
        self._above = 0
        self._joint_above = 0
        self._joint_held = 0                   # consecutive samples over joint_exit_sigma
        self._below_since: float | None = None
        self._contact_start = -1
        self._contact_t0 = 0.0
        self.contacts = 0
        self.setup_changes = 0
        # (SETUP_RING, 9): a contact's residual (6) and tip force (3) every SETUP_STRIDE samples
        self._ring = np.zeros((SETUP_RING, N_JOINTS + 3))
        self._ring_n = 0                       # rows written since the contact (or check) began
        self._stride = 0
        self._check_t = math.inf               # when the contact is judged for a set-up change
        self._ended_t = -math.inf              # when the last contact ended

    def seed(self, std: np.ndarray) -> None:
        """Start from a known free-motion residual scale instead of warming up: a gate that
        must judge from its first sample (the pipeline's calibration guard), where a warm-up
        could be spent in a contact and learn it as free motion.

        Args:
            std: (6,) RMS of the free residual per joint [N m; N on insertion] (floored by
                ``min_std``); the scale may grow ``max_growth`` times past it.
        """
        std = np.asarray(std, dtype=float)
        if std.shape != (N_JOINTS,) or not np.isfinite(std).all():
            raise DataError(f"a gate's seed scale needs {N_JOINTS} finite values, got {std!r}")
        self.reset()
        c = self.config
        rms = np.maximum(std, self._floor)
        for j in range(N_JOINTS):
            self._warm[j].update(float(rms[j]) ** 2)
            self._msq[j].update(float(rms[j]) ** 2)
            self._cap[j] = c.max_growth * float(rms[j])
            self._msq_train[j].update(float(rms[j]) ** 2)
            self._cap_train[j] = self._cap[j]
        self._seen = c.warmup_samples
        self._refresh()

    def rescale(self, std: np.ndarray) -> None:
        """Move a calibrated gate's scale to a known free-motion level, keeping its contact
        state (a contact in progress goes on): the calibration guard follows the robust level
        of the residual over its window this way. The scale may again grow ``max_growth``
        times past ``std`` (floored by ``min_std``) by learning.

        Raises:
            DataError: ``std`` is not six finite values, or the gate is still warming up.
        """
        std = np.asarray(std, dtype=float)
        if std.shape != (N_JOINTS,) or not np.isfinite(std).all():
            raise DataError(f"a gate's scale needs {N_JOINTS} finite values, got {std!r}")
        if not self.calibrated:
            raise DataError("only a calibrated (warmed-up or seeded) gate can be rescaled")
        rms = np.maximum(std, self._floor)
        self._acc = [0.0] * N_JOINTS
        self._n_acc = 0
        for j in range(N_JOINTS):
            self._restart_scale(j, float(rms[j]) ** 2,
                                self.config.max_growth * float(rms[j]))
        self._refresh()

    def _restart_scale(self, j: int, mean_square: float, cap: float) -> None:
        """Joint ``j``'s running scale, and the training scale beside it, start afresh at
        ``mean_square`` [(N m)^2; N^2] with the bound ``cap`` [N m; N]."""
        for msq in (self._msq, self._msq_train):
            msq[j] = stats.EWMean(fading_factor=self._block_fading)
            msq[j].update(mean_square)
        self._cap[j] = self._cap_train[j] = cap

    @property
    def in_contact(self) -> bool:
        return self._in_contact

    @property
    def contact_start(self) -> int:
        """Sample index at which the current contact began (-1: none)."""
        return self._contact_start

    def take_over_contact(self, start: int, t: float) -> None:
        """Go on with a contact that another judge found (the calibration guard, whose
        verdicts stand until this gate is calibrated): from here the contact ends by this
        gate's hysteresis, as one it had found itself.

        Args:
            start: sample index at which the contact began.
            t: time of the current sample [s] (the contact's duration counts from here).
        Raises:
            DataError: the gate is still warming up.
        """
        if not self.calibrated:
            raise DataError("only a calibrated (warmed-up or seeded) gate can take over a contact")
        if self._in_contact:
            return
        self._in_contact = self._published = True
        self._contact_start = int(start)
        self._contact_t0 = t
        self._below_since = None
        self._above = self._joint_above = self._joint_held = 0
        self.contacts += 1
        self._watch(t)

    def _watch(self, t: float, again: bool = False) -> None:
        """Buffer a contact's samples afresh from ``t`` [s], to be judged for a set-up
        change ``setup_contact_s`` later; a contact that starts within ``setup_gap_s`` of
        the last one's end goes on with its buffer and time (unless ``again``: a steady
        force judged, the next window starts)."""
        if (not again and t - self._ended_t <= self.config.setup_gap_s
                and math.isfinite(self._check_t)):
            return
        self._ring_n = self._stride = 0
        c = self.config.setup_contact_s
        self._check_t = t + c if c > 0 else math.inf

    def _buffered(self) -> np.ndarray:
        """(n, 9) the buffered residuals (6) and tip forces (3) of the contact."""
        return self._ring[:min(self._ring_n, SETUP_RING)]

    def _looks_like_setup(self) -> bool:
        """The buffered tip force is no larger than a set-up change's (RMS up to
        ``setup_max_force_n``) and changes direction with the pose (``|mean f| / RMS |f|``
        under ``steady_force_ratio``), as a set-up change seen through ``J^-T`` does and a
        contact at the tip does not; False without a tip force or with under 20 rows."""
        f = self._buffered()[:, N_JOINTS:]
        if len(f) < 20 or not np.isfinite(f).all():
            return False
        c = self.config
        rms = math.sqrt(float(np.mean(np.sum(f * f, axis=1))))
        return 0.0 < rms <= c.setup_max_force_n and float(np.linalg.norm(f.mean(axis=0))) < (
            c.steady_force_ratio * rms)

    def _relearn(self, r: list[float]) -> None:
        """Restart the scale on the contact's buffered residuals (the mean square of those
        within ``warmup_trim_sigma`` robust sigmas), on the present residual ``r`` (6,)
        when fewer than ``N_JOINTS`` rows are buffered."""
        rows = self._buffered()
        msq = (warmup_mean_square(rows[:, :N_JOINTS], self.config.warmup_trim_sigma)
               if len(rows) >= N_JOINTS else np.asarray(r) ** 2)
        self._acc = [0.0] * N_JOINTS
        self._n_acc = 0
        for j in range(N_JOINTS):
            rms = math.sqrt(float(msq[j]))
            self._restart_scale(j, float(msq[j]),
                                self.config.max_growth * max(rms, self._floor[j]))
        self._refresh()

    def settle(self, t: float) -> None:
        """This gate starts judging at time ``t`` [s] (its warm-up is over, or it takes
        over from another judge): nothing is trainable before ``t + exit_s``. A contact in
        progress that it cannot see (one too weak for its enter bounds) must show the quiet
        that ends a contact it had found before its samples may train."""
        self._probation_until = max(self._probation_until, t + self.config.exit_s)

    @property
    def calibrated(self) -> bool:
        return self._seen >= self.config.warmup_samples

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre (zeros) and scale (floored RMS) of the free residual, (6,) each."""
        return np.zeros(N_JOINTS), self._std.copy()

    def _refresh(self) -> None:
        if self._seen < self.config.warmup_samples:
            rms = np.sqrt(np.array([m.get() for m in self._warm]))
        else:
            rms = np.minimum(np.sqrt(np.array([m.get() for m in self._msq])), self._cap)
        self._std = np.maximum(rms, self._floor)
        self._inv_var = (1.0 / self._std ** 2).tolist()
        if self._seen >= self.config.warmup_samples and self._msq_train[0].get():
            rt = np.minimum(np.sqrt(np.array([m.get() for m in self._msq_train])),
                            self._cap_train)
            self._inv_var_train = (1.0 / np.maximum(rt, self._floor) ** 2).tolist()
        else:
            self._inv_var_train = self._inv_var

    def _flush(self) -> None:
        """Hand the summed squares to the river statistics and refresh the scale."""
        n, c = self._n_acc, self.config
        if n == 0:
            return
        # the block summed z^2 = r^2 / scale^2 under one scale: back to r^2
        var = (self._std ** 2).tolist()
        mean_sq = [a * v / n for a, v in zip(self._acc, var)]
        if self._seen <= c.warmup_samples:              # this block ends in the warm-up
            for j in range(N_JOINTS):
                self._warm[j].update(mean_sq[j], n)
            if self._seen == c.warmup_samples:           # seed the slow average
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
                    self._cap[j] = c.max_growth * max(math.sqrt(warm), self._floor[j])
                    self._msq_train[j] = stats.EWMean(fading_factor=self._block_fading)
                    self._msq_train[j].update(plain)
                    self._cap_train[j] = c.max_growth * max(math.sqrt(plain), self._floor[j])
        else:
            for j in range(N_JOINTS):
                self._msq[j].update(mean_sq[j])
                self._msq_train[j].update(mean_sq[j])
        self._acc = [0.0] * N_JOINTS
        self._n_acc = 0
        self._refresh()

    def _learn(self, zsq: list[float]) -> None:
        self._acc = [a + x for a, x in zip(self._acc, zsq)]
        self._n_acc += 1
        self._seen += 1
        c = self.config
        if self._seen <= c.warmup_samples:
            if self._n_acc >= c.learn_block or self._seen == c.warmup_samples:
                self._flush()
        elif self._n_acc >= c.learn_block:
            self._flush()

    def update(self, index: int, t: float, residual: np.ndarray,
               velocity: np.ndarray | None = None,
               force: np.ndarray | None = None) -> GateDecision:
        """Judge sample ``index`` at time ``t`` [s] with residual torques (6,) [N m; N],
        for ``reversal_bins_s`` joint velocities (6,) [rad/s; m/s], and for the set-up
        check (``setup_contact_s``) the tip force estimate (3,) [N]."""
        cfg = self.config
        r = residual.tolist() if isinstance(residual, np.ndarray) else [float(x) for x in residual]
        steady = [a * a * b for a, b in zip(r, self._inv_var)]   # squared scores z_j^2
        motion = self.reversal if velocity is not None else None
        if motion is None:
            zsq = steady
        else:                                   # wider where the joint just turned round
            v = velocity.tolist() if isinstance(velocity, np.ndarray) else velocity
            zsq = [z / f for z, f in zip(steady, motion.factors_sq(t, v))]
        peak = max(zsq)
        score = math.sqrt(peak)
        joint = (math.sqrt((sum(zsq) - peak) / (N_JOINTS - 1)) if cfg.joint_without_peak
                 else math.sqrt(sum(zsq) / N_JOINTS))
        if self._seen < cfg.warmup_samples:              # learn the level first, call nothing
            if self._warm_buf is not None:
                self._warm_buf[self._seen] = r
            if motion is not None:
                motion.learn(steady)
            self._learn(zsq)
            if self._seen == cfg.warmup_samples:
                self.settle(t)
            return GateDecision(False, score if self._seen > 1 else 0.0, -1)
        if not self._in_contact:
            self._above = self._above + 1 if score > cfg.enter_sigma else 0
            self._joint_above = self._joint_above + 1 if joint > cfg.joint_sigma else 0
            if self._above >= cfg.enter_samples or self._joint_above >= cfg.joint_samples:
                self._in_contact = True
                first = max(self._above if self._above >= cfg.enter_samples else 0,
                            self._joint_above if self._joint_above >= cfg.joint_samples else 0)
                self._contact_start = index - first + 1
                self._contact_t0 = t
                self._below_since = None
                self._joint_held = self._joint_above
                self._published = True
                self.contacts += 1
                self._watch(t)
            else:
                if score < cfg.learn_sigma:
                    if motion is not None:
                        motion.learn(steady)
                    self._learn(zsq)
                # training is judged on the plain scale (not widened at reversals)
                tr = (math.sqrt(max(a * a * b for a, b in zip(r, self._inv_var_train)))
                      if cfg.robust_warmup or motion is not None else score)
                return GateDecision(True, score, -1, trainable=(tr < cfg.train_sigma
                                                                and t >= self._probation_until))
        # in contact
        self._stride += 1
        if self._stride >= SETUP_STRIDE:
            self._stride = 0
            row = self._ring[self._ring_n % SETUP_RING]
            row[:N_JOINTS] = r
            row[N_JOINTS:] = force[:3] if force is not None else math.nan
            self._ring_n += 1
        self._joint_held = self._joint_held + 1 if joint > cfg.joint_exit_sigma else 0
        below = score < cfg.exit_sigma and self._joint_held < cfg.joint_samples
        if cfg.release_free:
            if self._published:
                if below:                              # released: published free from here
                    self._published, self._above, self._joint_above = False, 0, 0
            else:                                      # published again on a new entry only
                self._above = self._above + 1 if score > cfg.enter_sigma else 0
                self._joint_above = self._joint_above + 1 if joint > cfg.joint_sigma else 0
                if self._above >= cfg.enter_samples or self._joint_above >= cfg.joint_samples:
                    self._published = True
        if below:
            if self._below_since is None:
                self._below_since = t
            if t - self._below_since >= cfg.exit_s:
                self._in_contact, self._above, self._joint_above = False, 0, 0
                self._published = False
                self._ended_t = t
                start, self._contact_start = self._contact_start, -1
                # the first free sample is not trusted: it is the contact's last, and says
                # where that contact began (a -1 here would read as "onset unknown" and make
                # the pipeline drop its whole delay line at every contact's end)
                return GateDecision(cfg.release_free, score, start)
        else:
            self._below_since = None
        setup = t >= self._check_t and self._looks_like_setup()
        if setup or t - self._contact_t0 > cfg.max_contact_s:
            self._relearn(r)                           # re-scale on the contact's level
            self._in_contact, self._above, self._joint_above = False, 0, 0
            self._probation_until = t + (cfg.setup_probation_s if setup else cfg.max_contact_s)
            start, self._contact_start = self._contact_start, -1
            self._published = False
            self._check_t = math.inf
            self.setup_changes += setup
            return GateDecision(False, score, start, recalibrated=True, setup_change=setup)
        if t >= self._check_t:                         # a steady force: judged again later
            self._watch(t, again=True)
        # with release_free, a released contact is published free (never trainable)
        return GateDecision(cfg.release_free and not self._published, score,
                            self._contact_start)
