"""Free-motion gate: is this sample's residual torque small enough to call it free motion?

A contact at the tip adds ``J^T w`` to the residual (measured minus predicted joint torque);
free motion's residual is noise plus what the model has not learned. :class:`FreeMotionGate`
joins two parts, each in its own module:

* :class:`~wrenchd.models.residual_scale.ResidualScale`: each joint's free-motion residual
  scale (warm-up, prior, cap, floor, the training scale, the spread after a reversal), which
  turns a residual into scores;
* :class:`~wrenchd.models.contact_hysteresis.ContactHysteresis`: the contact state machine
  on those scores (enter and exit bounds, release, the set-up check).

The gate learns the scale only from free samples scoring under ``learn_sigma``; a sample is
``trainable`` when it is free, its peak score on the training scale is under ``train_sigma``
and no probation holds: ``exit_s`` after the gate starts judging (:meth:`FreeMotionGate.settle`,
a contact too weak for the enter bounds may be in progress), ``setup_probation_s`` after a
set-up change re-learnt, ``max_contact_s`` after a contact too long. It also tells the
pipeline where the current contact began, so samples buffered before that (the onset, under
the bound) are dropped from training. Parameters and their measured effect:
``docs/replay-and-policies.md`` and ``docs/results.md``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from wrenchd.models import contact_hysteresis as ch
from wrenchd.models.contact_hysteresis import ContactHysteresis
from wrenchd.models.errors import DataError
from wrenchd.models.residual_scale import ResidualScale, ReversalSpread, warmup_mean_square
from wrenchd.models.series import N_JOINTS

if TYPE_CHECKING:
    from wrenchd.models.physics.kinematics import PSMKinematics

__all__ = ["FreeMotionGate", "GateConfig", "GateDecision", "ReversalSpread",
           "warmup_mean_square"]


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
    announced_setup_s: float = Field(
        default=3.0, ge=0.0,
        description="after an announced set-up change, a contact held then or begun within "
                    "this long is judged for a set-up change this long after the announcement "
                    "or its start, on what it buffered since the announcement, its scale "
                    "re-learnt as announced_widen says [s]; 0: as any contact")
    announced_hold_s: float = Field(
        default=1.0, ge=0.0,
        description="with the arm's kinematics and release_free, a contact begun (or "
                    "published again) within this long of an announced set-up change is "
                    "published free, never trainable, until its residual is a tip force's "
                    "(announced_release_misfit) or its announced check finds no set-up "
                    "change: a new set-up's model error reads as a contact at first [s]; "
                    "0: never")
    announced_release_misfit: float = Field(
        default=0.1, gt=0.0, lt=1.0,
        description="a withheld contact is published once a fitted tip force leaves under "
                    "this fraction of its scored residual (median over its rows since it "
                    "was withheld)")
    announced_widen: float = Field(
        default=1.5, ge=1.0,
        description="a scale re-learnt from announced_setup_s of an announced change is its "
                    "RMS times this, never narrower than the scale before the change (seconds "
                    "of a new set-up miss the larger residuals of poses still to come)")
    tip_setup_s: float = Field(
        default=2.0, ge=0.0,
        description="with the arm's kinematics, a contact held this long is judged on its "
                    "last this long, and again every quarter of it: a tip force that swings "
                    "with the pose (steady_force_ratio, setup_max_force_n) and leaves over "
                    "tip_misfit of the residual unexplained is a set-up change, its scale "
                    "re-learnt as an announced one's [s]; 0: never")
    tip_misfit: float = Field(
        default=0.4, gt=0.0, lt=1.0,
        description="median fraction of the scored residual (squared scores) a tip force "
                    "leaves unexplained over which a contact's residual is not a tip "
                    "force's (a tip contact leaves the model's noise, a random residual "
                    "about a half)")
    form_withdraw_s: float = Field(
        default=5.0, ge=0.0,
        description="a set-up change called on a contact's form (tip_setup_s) while the "
                    "contact was in force is withdrawn when, within this long, the residual on "
                    "the scale before it stays under the exit bounds for exit_s: it was a "
                    "contact, now ended, and that scale comes back (a set-up change leaves the "
                    "residual over it); a call made while the contact's end was pending stands "
                    "[s]; 0: never")
    drift_caution_s: float = Field(
        default=3.0, ge=0.0,
        description="after the drift detector fires (the free residual has grown: the model "
                    "is wrong for the set-up until adaptation catches up), for this long a "
                    "contact enters only over its enter bounds times drift_caution_factor; "
                    "scale, exits and training as before [s]; 0: never")
    drift_caution_factor: float = Field(
        default=1.25, ge=1.0,
        description="how much higher the enter bounds are for drift_caution_s after a drift")
    weak_contact_s: float = Field(
        default=0.3, ge=0.0,
        description="with the arm's kinematics, free samples whose residual a tip force of "
                    "over weak_contact_force_n explains to within weak_contact_misfit (medians "
                    "over this long) are held back from training, and the delay line's from "
                    "onset_margin_s before them dropped: a contact too weak for the gate's "
                    "bounds; what is published is unchanged [s]; 0: never")
    weak_contact_misfit: float = Field(
        default=0.1, gt=0.0, lt=1.0,
        description="median fraction of the scored residual a tip force leaves unexplained "
                    "under which free samples look like a weak contact (weak_contact_s)")
    weak_contact_force_n: float = Field(
        default=0.8, ge=0.0,
        description="median tip force over which free samples may be a weak contact "
                    "(weak_contact_s) [N]")
    weak_contact_max_s: float = Field(
        default=5.0, gt=0.0,
        description="free samples that look like a weak contact for longer than this are a "
                    "model error a tip force explains, and train again [s]")
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
    joint_cap_sigma: float | None = Field(
        default=3.0, gt=0.0,
        description="each joint adds at most this score to the joint score: a friction spike "
                    "on one joint is the peak score's to judge, a weak contact loads several "
                    "(docs/results.md); None: no cap")
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
    reversal_hold_s: float = Field(
        default=0.06, ge=0.0,
        description="a joint's peak score counts toward entering a contact only once this "
                    "long has passed since its velocity reversed [s] (a friction spike at a "
                    "reversal is one joint's, for tens of ms); the joint score still enters; "
                    "0: always")
    release_free: bool = Field(
        default=True,
        description="while a contact's exit is pending (under the exit bounds, exit_s not yet "
                    "over) publish the sample free; it stays out of training")

    @model_validator(mode="after")
    def _consistent(self) -> GateConfig:
        if len(self.min_std) != N_JOINTS or len(self.slow_velocity) != N_JOINTS:
            raise ValueError(f"min_std and slow_velocity need {N_JOINTS} values each, got "
                             f"{len(self.min_std)} and {len(self.slow_velocity)}")
        if min(self.min_std) <= 0.0 or min(self.slow_velocity) < 0.0:
            raise ValueError("min_std must be positive and slow_velocity not negative")
        if self.train_sigma > self.learn_sigma:
            raise ValueError(f"train_sigma ({self.train_sigma}) must not exceed learn_sigma "
                             f"({self.learn_sigma}): a sample that trains teaches the scale")
        if self.exit_sigma > self.enter_sigma or self.joint_exit_sigma > self.joint_sigma:
            raise ValueError("an exit bound (exit_sigma, joint_exit_sigma) must not exceed its "
                             "enter bound (enter_sigma, joint_sigma)")
        if self.announced_hold_s > self.announced_setup_s:
            raise ValueError(f"announced_hold_s ({self.announced_hold_s}) must not exceed "
                             f"announced_setup_s ({self.announced_setup_s}): a withheld "
                             "contact waits for its announced check")
        edges = self.reversal_bins_s
        if any(b <= a for a, b in zip((0.0,) + edges, edges)):
            raise ValueError(f"reversal_bins_s must be positive and increasing, got {edges}")
        return self


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
        setup_withdrawn: a set-up change called on a contact's form was withdrawn at this
            sample (``form_withdraw_s``): the scale before it is back.
    """

    free: bool
    score: float
    contact_started: int
    recalibrated: bool = False
    trainable: bool = False
    setup_change: bool = False
    setup_withdrawn: bool = False


class _FormCall:
    """A set-up change called on a contact's form while the contact was in force, on
    probation: the scale before it, and whether the residual on that scale falls under the
    exit bounds for ``exit_s`` (the contact ends) before ``form_withdraw_s`` is over
    (:meth:`FreeMotionGate.update`)."""

    __slots__ = ("snapshot", "inv_var", "until", "below_since", "joint_held")

    def __init__(self, snapshot: dict, std: np.ndarray, until: float) -> None:
        self.snapshot, self.until = snapshot, until
        self.inv_var = (1.0 / std ** 2).tolist()
        self.below_since: float | None = None
        self.joint_held = 0


class FreeMotionGate:
    """A residual scale and a contact hysteresis, per stream (see the module docstring).

    >>> import numpy as np
    >>> gate = FreeMotionGate(GateConfig(warmup_samples=200))
    >>> rng = np.random.default_rng(0)
    >>> for i in range(400):                                     # free motion: 0.1 N m noise
    ...     d = gate.update(i, i * 0.005, rng.normal(0.0, 0.1, 6))
    >>> d.free, gate.in_contact
    (True, False)
    >>> for i in range(400, 420):                                # a push on joint 2
    ...     d = gate.update(i, i * 0.005, np.r_[0.0, 3.0, 0.0, 0.0, 0.0, 0.0])
    >>> d.free, gate.in_contact, gate.contact_start
    (False, True, 400)
    """

    def __init__(self, config: GateConfig | None = None,
                 kinematics: PSMKinematics | None = None) -> None:
        """``kinematics``: the arm's, for the tip-form check (``tip_setup_s``; without it
        off)."""
        self.config = config if config is not None else GateConfig()
        self._kinematics = kinematics
        cap = self.config.joint_cap_sigma
        self._joint_cap_sq = None if cap is None else cap * cap
        self.scale = ResidualScale(self.config)
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
        self.scale.reset(prior)
        self.contact = self._hysteresis()
        self._probation_until = -math.inf      # nothing trains before this
        self._form_call: _FormCall | None = None
        self.caution_until = -math.inf         # higher enter bounds before this (a drift)
        self.withdrawn = 0                     # set-up changes called on form, withdrawn

    def seed(self, std: np.ndarray) -> None:
        """Start from a known free-motion residual scale instead of warming up: a gate that
        must judge from its first sample (the pipeline's calibration guard), where a warm-up
        could be spent in a contact and learn it as free motion.

        Args:
            std: (6,) RMS of the free residual per joint [N m; N on insertion] (floored by
                ``min_std``); the scale may grow ``max_growth`` times past it.
        """
        self.scale.seed(std)
        self.contact = self._hysteresis()
        self._probation_until = -math.inf
        self._form_call = None

    def rescale(self, std: np.ndarray) -> None:
        """Move a calibrated gate's scale to a known free-motion level, keeping its contact
        state (a contact in progress goes on): the calibration guard follows the robust level
        of the residual over its window this way.

        Raises:
            DataError: ``std`` is not six finite values, or the gate is still warming up.
        """
        self.scale.rescale(std)
        self._form_call = None                 # the level before is no longer the one to restore

    def _hysteresis(self) -> ContactHysteresis:
        if self._kinematics is None:
            return ContactHysteresis(self.config)
        kin = self._kinematics

        def misfit(rows: np.ndarray) -> np.ndarray:
            return ch.tip_force_misfit(kin.jacobian(rows[:, ch.POS], "hybrid"),
                                       rows[:, ch.RES], self.scale.std)
        return ContactHysteresis(self.config, misfit)

    @property
    def reversal(self) -> ReversalSpread | None:
        return self.scale.reversal

    @property
    def in_contact(self) -> bool:
        return self.contact.in_contact

    @property
    def contact_start(self) -> int:
        """Sample index at which the current contact began (-1: none)."""
        return self.contact.contact_start

    @property
    def contacts(self) -> int:
        return self.contact.contacts

    @property
    def setup_changes(self) -> int:
        return self.contact.setup_changes

    @property
    def withheld_contacts(self) -> int:
        """Contacts withheld after an announcement so far (``announced_hold_s``)."""
        return self.contact.withheld_count

    @property
    def calibrated(self) -> bool:
        return self.scale.calibrated

    def take_over_contact(self, start: int, t: float) -> None:
        """Go on with a contact that another judge found (the calibration guard, whose
        verdicts stand until this gate is calibrated), begun at sample ``start``, at time
        ``t`` [s]: from here it ends by this gate's hysteresis.

        Raises:
            DataError: the gate is still warming up.
        """
        if not self.calibrated:
            raise DataError("only a calibrated (warmed-up or seeded) gate can take over a contact")
        self.contact.take_over(start, t)

    def announce(self, t: float) -> None:
        """A set-up change announced at time ``t`` [s] (``announced_setup_s``): a contact
        held now, or begun soon after, is judged for a set-up change soon."""
        self.contact.announce(t)

    def drifted(self, t: float) -> None:
        """The drift detector fired at ``t`` [s]: for ``drift_caution_s`` a contact enters
        only over the enter bounds times ``drift_caution_factor`` (the free residual has
        grown past the scale, which learns it over tens of seconds)."""
        self.caution_until = t + self.config.drift_caution_s

    def settle(self, t: float) -> None:
        """This gate starts judging at time ``t`` [s] (its warm-up is over, or it takes
        over from another judge): nothing is trainable before ``t + exit_s``."""
        self._probation_until = max(self._probation_until, t + self.config.exit_s)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Centre (zeros) and scale (floored RMS) of the free residual, (6,) each."""
        return np.zeros(N_JOINTS), self.scale.std.copy()

    def update(self, index: int, t: float, residual: np.ndarray,
               velocity: np.ndarray | None = None,
               force: np.ndarray | None = None,
               position: np.ndarray | None = None) -> GateDecision:
        """Judge sample ``index`` at time ``t`` [s] with residual torques (6,) [N m; N],
        for ``reversal_bins_s`` joint velocities (6,) [rad/s; m/s], for the set-up check
        (``setup_contact_s``) the tip force estimate (3,) [N], and for the tip-form check
        (``tip_setup_s``, with kinematics) the joint positions (6,) [rad; m]."""
        cfg, scale, contact = self.config, self.scale, self.contact
        r = residual.tolist() if isinstance(residual, np.ndarray) else [float(x) for x in residual]
        zsq, steady = scale.squared_scores(r, t, velocity)
        withdrawn = self._form_call is not None and self._withdraw(t, zsq)
        if withdrawn:
            zsq, steady = scale.squared_scores(r, t, velocity)
        peak = max(zsq)
        score = math.sqrt(peak)
        joint = self._joint_score(zsq, peak)
        if not scale.calibrated:                      # learn the level first, call nothing
            scale.warm(r, steady, zsq)
            if scale.calibrated:
                self.settle(t)
            return GateDecision(False, score if scale.seen > 1 else 0.0, -1)
        enter_score = score
        # only a peak over the enter bound can count toward entry: the hold is judged there
        if (score > cfg.enter_sigma and cfg.reversal_hold_s > 0 and velocity is not None
                and scale.reversal is not None):
            held = scale.reversal.reversed_within(t, cfg.reversal_hold_s)
            enter_score = math.sqrt(max((z for z, h in zip(zsq, held) if not h), default=0.0))
        # after a drift, higher enter bounds (x / 1.0 is x exactly)
        k = cfg.drift_caution_factor if t < self.caution_until else 1.0
        if not contact.in_contact and not contact.enter(index, t, enter_score / k, joint / k):
            if score < cfg.learn_sigma:
                scale.learn(steady, zsq)
            # training is judged on the plain scale (not widened at reversals)
            tr = (scale.train_score(r) if cfg.robust_warmup or velocity is not None
                  and scale.reversal is not None else score)
            return GateDecision(True, score, -1, trainable=(tr < cfg.train_sigma
                                                            and t >= self._probation_until),
                                setup_withdrawn=withdrawn)
        withheld = contact.withheld
        outcome = contact.hold(t, score, joint, r, force, position)
        if outcome == ch.HELD:
            # with release_free, a released contact is published free (never trainable)
            return GateDecision(cfg.release_free and not contact.published, score,
                                contact.contact_start, setup_withdrawn=withdrawn)
        if outcome == ch.ENDED:
            # the first free sample is not trusted: it is the contact's last, and says
            # where that contact began (a -1 here would read as "onset unknown" and make
            # the pipeline drop its whole delay line at every contact's end)
            return GateDecision(cfg.release_free, score, contact.ended_start)
        setup = outcome == ch.SETUP                   # or too long: re-scale on its level
        # an announced change is known to be one: its level is learnt from seconds of it, a
        # scale narrower than the one before would call its slower swings contact
        # so is one judged on seconds of its form
        rows = contact.judged if setup else contact.buffered()
        if setup and (contact.announced or contact.tip_form):
            # a call made while the contact's end was pending stands: a residual that swings
            # with the pose is quiet at times, and a contact ending at the call is no proof
            self._form_call = (_FormCall(scale.snapshot(), scale.std, t + cfg.form_withdraw_s)
                               if contact.tip_form and not contact.exiting
                               and cfg.form_withdraw_s > 0 else None)
            scale.relearn(rows[:, ch.RES], r, cfg.announced_widen, at_least=scale.std.copy())
        else:
            self._form_call = None
            scale.relearn(rows[:, ch.RES], r)
        self._probation_until = t + (cfg.setup_probation_s if setup else cfg.max_contact_s)
        # a withheld contact was published free throughout, its end as well
        return GateDecision(withheld and setup, score, contact.ended_start, recalibrated=True,
                            setup_change=setup)

    def _joint_score(self, zsq: list[float], peak: float) -> float:
        """The joint score of squared scores ``zsq`` (6,) whose largest is ``peak``."""
        if self.config.joint_without_peak:
            return math.sqrt((sum(zsq) - peak) / (N_JOINTS - 1))
        cap = self._joint_cap_sq
        if cap is not None:
            return math.sqrt(sum(z if z < cap else cap for z in zsq) / N_JOINTS)
        return math.sqrt(sum(zsq) / N_JOINTS)

    def _withdraw(self, t: float, zsq: list[float]) -> bool:
        """Judge a form call on probation on this sample's squared scores ``zsq`` (6,): True
        when it is withdrawn here (the scale before it restored)."""
        call, cfg = self._form_call, self.config
        if t > call.until:
            self._form_call = None
            return False
        old = [z * v * w for z, v, w in zip(zsq, (self.scale.std ** 2).tolist(), call.inv_var)]
        peak = max(old)
        joint = self._joint_score(old, peak)
        call.joint_held = call.joint_held + 1 if joint > cfg.joint_exit_sigma else 0
        if (self.contact.in_contact or peak >= cfg.exit_sigma ** 2
                or call.joint_held >= cfg.joint_samples):
            call.below_since = None
            return False
        if call.below_since is None:
            call.below_since = t
        if t - call.below_since < cfg.exit_s:
            return False
        self.scale.restore(call.snapshot)
        self._form_call = None
        self.withdrawn += 1
        return True
