"""Contact or free motion, from a sample's scores: the gate's state machine with hysteresis.

Two scores (in :class:`~wrenchd.models.residual_scale.ResidualScale` units), two ways in:

* the **peak** score ``max_j |z_j|`` over ``enter_sigma`` on ``enter_samples`` samples in a
  row: a contact that loads one joint hard (a push along the shaft);
* the **joint** score ``sqrt(mean_j z_j^2)`` over ``joint_sigma`` on ``joint_samples``
  samples in a row: a weak contact loads several joints at once, each under the peak bound,
  where free-motion model error is mostly in one joint at a time.

A contact ends when, for ``exit_s``, the peak score stays under ``exit_sigma`` and the joint
score has not been over ``joint_exit_sigma`` for ``joint_samples`` samples in a row: a force
passing through zero does not chop a contact into pieces. With ``release_free`` a contact's
samples are published free from its first sample under both exit bounds (the force is gone)
but stay the contact's, never trainable, until it ends; published again only on a new entry.

A set-up change (a load on a link, a heavier instrument) adds a torque that depends on the
pose; a contact adds ``J^T f`` with a force that follows the tissue. A contact that has
lasted ``setup_contact_s`` is judged on its buffered tip force: under ``steady_force_ratio``
(``|mean f| / RMS |f|``: a set-up change seen through ``J^-T`` swings with the pose) and no
larger than ``setup_max_force_n``, it is a set-up change. Contacts within ``setup_gap_s`` of
each other count as one here. A contact longer than ``max_contact_s`` is a set-up change too.
After an announced set-up change (:meth:`ContactHysteresis.announce`) a contact held then or
begun within ``announced_setup_s`` is judged that soon, on what it buffered since.

A contact at the tool tip is a force there: its residual is ``J_v^T f`` (six torques from
three numbers), and a fit of a tip force to it leaves only the model's noise. A model that
has gone wrong (a new set-up, poses it never saw) leaves torques no tip force makes. With a
``tip_misfit`` function (the gate's, on the arm's kinematics) a contact held ``tip_setup_s``
is judged on its last ``tip_setup_s`` too (its rows over the exit bounds: a tail, the force
gone, is free motion's error), and again every ``TIP_EVERY`` of that: the tip force swings
with the pose (as above) **and** a tip force leaves more than ``tip_misfit`` of the scored
residual unexplained (median over the rows): a set-up change, its scale re-learnt as an
announced one's. Either test alone calls real contacts set-up changes (docs/results.md).

A new set-up's model error reads as a contact at first. With the tip-form function, a contact
begun (or published again) within ``announced_hold_s`` of an announcement is **withheld**:
published free, never trainable, until its rows since then are a tip force's (a fitted tip
force leaves under ``announced_release_misfit`` of their scored residual, from ``HOLD_ROWS``
rows and ``HOLD_S`` on) or its announced check finds no set-up change. A contact's force at
the tip is published a few rows late; the change's error is never published as a contact.

The residuals, tip forces, positions and times are buffered every ``SETUP_STRIDE`` samples in
a ring of ``SETUP_RING`` rows, so the hot path gains a counter and now and then a row.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from wrenchd.models.gate import GateConfig

#: a contact's rows are buffered every this many samples (the set-up checks
#: and the re-learnt scale read them), in a ring of ``SETUP_RING`` rows
SETUP_STRIDE, SETUP_RING = 10, 1024

#: columns of a buffered row: residual (6), tip force (3), joint positions (6), time, and
#: 1 where the sample was under both exit bounds (the force gone or passing through zero)
RES, FORCE, POS, TIME, BELOW = slice(0, 6), slice(6, 9), slice(9, 15), 15, 16
ROW = 17

#: after its first, the tip-form check runs every this fraction of ``tip_setup_s`` (on the
#: last ``tip_setup_s``)
TIP_EVERY = 0.25

#: a withheld contact is judged on its form from this many buffered rows, spanning this
#: long [s], on (rows are every SETUP_STRIDE samples: at 1 kHz three come within 30 ms)
HOLD_ROWS, HOLD_S = 3, 0.1

#: :meth:`ContactHysteresis.hold` outcomes
HELD, ENDED, SETUP, TOO_LONG = 0, 1, 2, 3


def tip_force_fit(jacobian: np.ndarray, residual: np.ndarray, std: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The tip force that best explains each residual in the scale's units, and what it
    leaves: ``(misfit (n,), force (n, 3) [N])``. The misfit is the fraction of each
    residual's squared score the force leaves unexplained, ``min_f |(r - J_v^T f) / std|^2 /
    |r / std|^2`` (0: a tip force's exactly; a random six-vector leaves about a half).

    Args:
        jacobian: (n, 6, 6) hybrid Jacobians of the tip, rows ``[v; w]``.
        residual: (n, 6) residual torques [N m; N on insertion].
        std: (6,) the gate's scale, the weights [N m; N].
    """
    a = np.transpose(jacobian[:, :3, :], (0, 2, 1)) / std[None, :, None]     # (n, 6, 3)
    z = residual / std
    ata = np.einsum("nji,njk->nik", a, a)
    atz = np.einsum("nji,nj->ni", a, z)
    f = np.linalg.solve(ata, atz[..., None])[..., 0]
    left = z - np.einsum("nij,nj->ni", a, f)
    misfit = np.sum(left * left, axis=1) / np.maximum(np.sum(z * z, axis=1), 1e-300)
    return misfit, f


def tip_force_misfit(jacobian: np.ndarray, residual: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(n,) the misfit of :func:`tip_force_fit`."""
    return tip_force_fit(jacobian, residual, std)[0]


class ContactHysteresis:
    """Enter and exit bounds, release, and the set-up check of one stream (module docstring).

    >>> from wrenchd.models.gate import GateConfig
    >>> h = ContactHysteresis(GateConfig(enter_samples=2, exit_s=0.0))
    >>> [h.enter(i, i * 0.01, 9.0, 0.0) for i in range(2)]   # two samples over 5 sigma
    [False, True]
    >>> h.contact_start, h.hold(0.02, 1.0, 0.0, [0.0] * 6, None)
    (0, 1)
    """

    def __init__(self, config: GateConfig,
                 tip_misfit: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
        """``tip_misfit``: buffered rows (n, ``ROW``) -> (n,) the fraction of each row's
        scored residual a tip force leaves unexplained (None: no tip-form check)."""
        self.config = config
        self._tip_misfit = tip_misfit if config.tip_setup_s > 0 else None
        self.contacts = 0
        self.setup_changes = 0
        self.in_contact = False
        self.published = False                 # a contact published as such (release_free)
        self._above = self._joint_above = 0
        self._joint_held = 0                   # consecutive samples over joint_exit_sigma
        self._below_since: float | None = None
        self.contact_start = -1
        self._t0 = 0.0
        # (SETUP_RING, ROW): a contact's rows (RES, FORCE, POS, TIME, BELOW) every SETUP_STRIDE
        self._ring = np.zeros((SETUP_RING, ROW))
        self._ring_n = 0                       # rows written since the contact (or check) began
        self._stride = 0
        self._check_t = math.inf               # when the contact is judged for a set-up change
        self._ended_t = -math.inf              # when the last contact ended
        self.announced_t = -math.inf           # when a set-up change was last announced
        self.announced = False                 # the check due is an announced change's
        self._tip_t = math.inf                 # when the contact's form is judged next
        self.judged: np.ndarray | None = None  # the rows the last set-up verdict read
        self.tip_form = False                  # that verdict was the tip-form check's
        self.withheld = False                  # begun just after an announcement: not
                                               # published until its form or check clears it
        self._withheld_t = 0.0                 # when it was withheld
        self.withheld_count = 0                # contacts withheld so far

    def enter(self, index: int, t: float, score: float, joint: float) -> bool:
        """Count a free sample's scores toward the enter bounds; True when sample ``index``
        at ``t`` [s] starts a contact (begun at the first sample of the run over them)."""
        c = self.config
        self._above = self._above + 1 if score > c.enter_sigma else 0
        self._joint_above = self._joint_above + 1 if joint > c.joint_sigma else 0
        if self._above < c.enter_samples and self._joint_above < c.joint_samples:
            return False
        first = max(self._above if self._above >= c.enter_samples else 0,
                    self._joint_above if self._joint_above >= c.joint_samples else 0)
        self._begin(index - first + 1, t)
        self._joint_held = self._joint_above
        return True

    def take_over(self, start: int, t: float) -> None:
        """Go on with a contact begun at sample ``start`` that another judge found."""
        if self.in_contact:
            return
        self._begin(int(start), t)
        self._above = self._joint_above = self._joint_held = 0

    def _begin(self, start: int, t: float) -> None:
        self.in_contact = self.published = True
        self.contact_start = start
        self._t0 = t
        self._below_since = None
        self.contacts += 1
        self._watch(t)
        self._tip_t = t + self.config.tip_setup_s if self._tip_misfit is not None else math.inf
        if self._holds(t):
            self._withhold(t)

    def _watch(self, t: float, again: bool = False) -> None:
        """Buffer afresh from ``t`` [s], to be judged ``setup_contact_s`` later; a contact
        within ``setup_gap_s`` of the last one's end keeps its buffer (unless ``again``)."""
        if (not again and t - self._ended_t <= self.config.setup_gap_s
                and math.isfinite(self._check_t)):
            return
        self._ring_n = self._stride = 0
        c = self.config.setup_contact_s
        self._check_t = t + c if c > 0 else math.inf
        a = self.config.announced_setup_s
        self.announced = a > 0 and t - self.announced_t <= a and not again
        if self.announced:
            self._check_t = min(self._check_t, max(t, self.announced_t) + a)

    def announce(self, t: float) -> None:
        """A set-up change announced at ``t`` [s]: a contact held now is judged
        ``announced_setup_s`` from now on what it buffers from now, one begun within that
        long that soon after its start (nothing without ``announced_setup_s``)."""
        self.announced_t = t
        a = self.config.announced_setup_s
        if self.in_contact and a > 0:
            self._ring_n = self._stride = 0
            self._check_t, self.announced = t + a, True

    def buffered(self) -> np.ndarray:
        """(n, ``ROW``) the contact's buffered rows since its check began (the last
        ``SETUP_RING``, not in order once the ring has wrapped)."""
        return self._ring[:min(self._ring_n, SETUP_RING)]

    def _holds(self, t: float) -> bool:
        """A contact (re-)entered at ``t`` [s] is withheld: ``announced_hold_s`` after an
        announcement, its check due (``announced_setup_s``), with the tip-form check to
        release it early and ``release_free`` to publish it free meanwhile."""
        c = self.config
        return (self.announced and t - self.announced_t <= c.announced_hold_s
                and c.release_free and self._tip_misfit is not None)

    def _withhold(self, t: float) -> None:
        self.published, self.withheld, self._withheld_t = False, True, t
        self.withheld_count += 1

    def _clear(self, below: bool) -> None:
        """A withheld contact is a contact after all: published unless its force is gone."""
        self.withheld, self.published = False, not below

    def _tip_form_since(self, t0: float) -> bool:
        """The rows buffered since ``t0`` [s] over the exit bounds, at least
        ``HOLD_ROWS`` of them, are a tip force's: a fitted tip force leaves under
        ``announced_release_misfit`` of their scored residual (median)."""
        rows = self.buffered()
        misfit = self._median_misfit(rows[(rows[:, TIME] >= t0) & (rows[:, BELOW] == 0)],
                                     HOLD_ROWS)
        return misfit is not None and misfit < self.config.announced_release_misfit

    def _median_misfit(self, rows: np.ndarray, least: int) -> float | None:
        """The median fraction of the rows' scored residual a fitted tip force leaves; None
        with under ``least`` rows or a position that is not finite."""
        if len(rows) < least or not np.isfinite(rows[:, POS]).all():
            return None
        return float(np.median(self._tip_misfit(rows)))

    def _looks_like_setup(self, rows: np.ndarray) -> bool:
        """The rows' tip force is no larger than ``setup_max_force_n`` (RMS) and swings
        with the pose (``|mean f| / RMS |f|`` under ``steady_force_ratio``); False without a
        tip force or with under 20 rows."""
        f = rows[:, FORCE]
        if len(f) < 20 or not np.isfinite(f).all():
            return False
        c = self.config
        rms = math.sqrt(float(np.mean(np.sum(f * f, axis=1))))
        return 0.0 < rms <= c.setup_max_force_n and float(np.linalg.norm(f.mean(axis=0))) < (
            c.steady_force_ratio * rms)

    def _not_a_tip_force(self, t: float) -> np.ndarray | None:
        """The rows of the last ``tip_setup_s`` over the exit bounds when they look like a
        set-up change (the tip force swings and a tip force leaves over ``tip_misfit`` of the
        residual unexplained, median over the rows), else None. Rows under the exit bounds
        are left out: a contact's tail, its force gone, is free motion's error."""
        rows = self.buffered()
        rows = rows[(rows[:, TIME] > t - self.config.tip_setup_s) & (rows[:, BELOW] == 0)]
        if not self._looks_like_setup(rows):            # the cheap test first
            return None
        misfit = self._median_misfit(rows, 20)
        return rows if misfit is not None and misfit > self.config.tip_misfit else None

    def hold(self, t: float, score: float, joint: float, r: list[float],
             force: np.ndarray | None, position: np.ndarray | None = None) -> int:
        """One sample in contact, residual ``r`` (6,), tip force (3,) [N] and joint positions
        (6,) buffered: the outcome, :data:`HELD` (see :attr:`published`), :data:`ENDED`,
        :data:`SETUP` or :data:`TOO_LONG` (the contact is over then; :attr:`ended_start` says
        where it began, :attr:`judged` which rows a set-up verdict read)."""
        c = self.config
        self._joint_held = self._joint_held + 1 if joint > c.joint_exit_sigma else 0
        below = score < c.exit_sigma and self._joint_held < c.joint_samples
        self._stride += 1
        if self._stride >= SETUP_STRIDE:
            self._stride = 0
            row = self._ring[self._ring_n % SETUP_RING]
            row[RES] = r
            row[FORCE] = force[:3] if force is not None else math.nan
            row[POS] = position if position is not None else math.nan
            row[TIME] = t
            row[BELOW] = below
            self._ring_n += 1
            if (self.withheld and t - self._withheld_t >= HOLD_S
                    and self._tip_form_since(self._withheld_t)):
                self._clear(below)
        if c.release_free:
            if self.published:
                if below:                              # released: published free from here
                    self.published, self._above, self._joint_above = False, 0, 0
            elif not self.withheld:                    # published again on a new entry only
                self._above = self._above + 1 if score > c.enter_sigma else 0
                self._joint_above = self._joint_above + 1 if joint > c.joint_sigma else 0
                if self._above >= c.enter_samples or self._joint_above >= c.joint_samples:
                    if self._holds(t):
                        self._withhold(t)
                    else:
                        self.published = True
        if below:
            if self._below_since is None:
                self._below_since = t
            if t - self._below_since >= c.exit_s:
                self._end()
                self._ended_t = t
                return ENDED
        else:
            self._below_since = None
        judged = None
        if t >= self._tip_t and not self.announced:
            self._tip_t = t + c.tip_setup_s * TIP_EVERY
            judged = self._not_a_tip_force(t)
        tip_form = judged is not None
        if judged is None and t >= self._check_t:
            rows = self.buffered()
            judged = rows if self._looks_like_setup(rows) else None
        setup = judged is not None
        if setup or t - self._t0 > c.max_contact_s:
            self._end()
            self._check_t = self._tip_t = math.inf
            self.setup_changes += setup
            self.judged, self.tip_form = judged, tip_form
            return SETUP if setup else TOO_LONG
        if t >= self._check_t:                         # a steady force: judged again later
            self._watch(t, again=True)
            if self.withheld:                          # no set-up change: a contact
                self._clear(below)
        return HELD

    @property
    def exiting(self) -> bool:
        """The last sample held was under the exit bounds: the contact's end was pending
        (``exit_s`` not yet over)."""
        return self._below_since is not None

    def _end(self) -> None:
        self.in_contact, self._above, self._joint_above = False, 0, 0
        self.published = self.withheld = False
        self.ended_start, self.contact_start = self.contact_start, -1
