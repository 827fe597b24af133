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
The residuals and tip forces are buffered every ``SETUP_STRIDE`` samples in a ring of
``SETUP_RING`` rows, so the hot path gains a counter and now and then a row.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from wrenchd.models.series import N_JOINTS

if TYPE_CHECKING:
    from wrenchd.models.gate import GateConfig

#: a contact's residual and tip force are buffered every this many samples (the set-up check
#: and the re-learnt scale read them), in a ring of ``SETUP_RING`` rows
SETUP_STRIDE, SETUP_RING = 10, 1024

#: :meth:`ContactHysteresis.hold` outcomes
HELD, ENDED, SETUP, TOO_LONG = 0, 1, 2, 3


class ContactHysteresis:
    """Enter and exit bounds, release, and the set-up check of one stream (module docstring).

    >>> from wrenchd.models.gate import GateConfig
    >>> h = ContactHysteresis(GateConfig(enter_samples=2, exit_s=0.0))
    >>> [h.enter(i, i * 0.01, 9.0, 0.0) for i in range(2)]   # two samples over 5 sigma
    [False, True]
    >>> h.contact_start, h.hold(0.02, 1.0, 0.0, [0.0] * 6, None)
    (0, 1)
    """

    def __init__(self, config: GateConfig) -> None:
        self.config = config
        self.contacts = 0
        self.setup_changes = 0
        self.in_contact = False
        self.published = False                 # a contact published as such (release_free)
        self._above = self._joint_above = 0
        self._joint_held = 0                   # consecutive samples over joint_exit_sigma
        self._below_since: float | None = None
        self.contact_start = -1
        self._t0 = 0.0
        # (SETUP_RING, 9): a contact's residual (6) and tip force (3) every SETUP_STRIDE samples
        self._ring = np.zeros((SETUP_RING, N_JOINTS + 3))
        self._ring_n = 0                       # rows written since the contact (or check) began
        self._stride = 0
        self._check_t = math.inf               # when the contact is judged for a set-up change
        self._ended_t = -math.inf              # when the last contact ended
        self.announced_t = -math.inf           # when a set-up change was last announced
        self.announced = False                 # the check due is an announced change's

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
        """(n, 9) the buffered residuals (6) and tip forces (3) of the contact."""
        return self._ring[:min(self._ring_n, SETUP_RING)]

    def _looks_like_setup(self) -> bool:
        """The buffered tip force is no larger than ``setup_max_force_n`` (RMS) and swings
        with the pose (``|mean f| / RMS |f|`` under ``steady_force_ratio``); False without a
        tip force or with under 20 rows."""
        f = self.buffered()[:, N_JOINTS:]
        if len(f) < 20 or not np.isfinite(f).all():
            return False
        c = self.config
        rms = math.sqrt(float(np.mean(np.sum(f * f, axis=1))))
        return 0.0 < rms <= c.setup_max_force_n and float(np.linalg.norm(f.mean(axis=0))) < (
            c.steady_force_ratio * rms)

    def hold(self, t: float, score: float, joint: float, r: list[float],
             force: np.ndarray | None) -> int:
        """One sample in contact, residual ``r`` (6,) and tip force (3,) [N] buffered: the
        outcome, :data:`HELD` (see :attr:`published`), :data:`ENDED`, :data:`SETUP` or
        :data:`TOO_LONG` (the contact is over then; :attr:`ended_start` says where it began)."""
        c = self.config
        self._stride += 1
        if self._stride >= SETUP_STRIDE:
            self._stride = 0
            row = self._ring[self._ring_n % SETUP_RING]
            row[:N_JOINTS] = r
            row[N_JOINTS:] = force[:3] if force is not None else math.nan
            self._ring_n += 1
        self._joint_held = self._joint_held + 1 if joint > c.joint_exit_sigma else 0
        below = score < c.exit_sigma and self._joint_held < c.joint_samples
        if c.release_free:
            if self.published:
                if below:                              # released: published free from here
                    self.published, self._above, self._joint_above = False, 0, 0
            else:                                      # published again on a new entry only
                self._above = self._above + 1 if score > c.enter_sigma else 0
                self._joint_above = self._joint_above + 1 if joint > c.joint_sigma else 0
                if self._above >= c.enter_samples or self._joint_above >= c.joint_samples:
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
        setup = t >= self._check_t and self._looks_like_setup()
        if setup or t - self._t0 > c.max_contact_s:
            self._end()
            self._check_t = math.inf
            self.setup_changes += setup
            return SETUP if setup else TOO_LONG
        if t >= self._check_t:                         # a steady force: judged again later
            self._watch(t, again=True)
        return HELD

    def _end(self) -> None:
        self.in_contact, self._above, self._joint_above = False, 0, 0
        self.published = False
        self.ended_start, self.contact_start = self.contact_start, -1
