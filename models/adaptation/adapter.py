"""Lifelong adaptation of the correction net (step 2) on gated free-motion samples.

Step 2 of the two-step estimator (Wu, Yilmaz, Kazanzides and Tumerdem, "Estimation of Trocar
and Tool Interaction Forces on the da Vinci Research Kit with Two-Step Deep Learning") learns
what the cannula seal and the body wall add to the joint torques [N m; N on insertion]. Those
change during surgery (insufflation pressure, instrument swaps), so the net keeps learning on
the free motion the gate lets through. :class:`Adapter` is the deterministic core of that
learning, used alike by the daemon (in :mod:`wrenchd.service.runtime.worker`'s process) and
by replay (inline, in simulated time), so a replay proves something about the daemon.

Every round fine-tunes a *copy* of the serving ``Corr`` (Adam with L2 weight decay, the
paper's Corr recipe) on a replay buffer that mixes recent samples with a reservoir of older
ones, then scores candidate and serving net on held-out recent free motion: a swap never
increases validation error. Set-up changes, announced or taken from a detected drift, make the
rounds eager; a pressure change carries the buffer over to the new body wall stiffness
(:class:`~wrenchd.models.body_wall_tracker.BodyWallTracker`), an instrument change restarts
it. Units: sample times and the rounds' clock in seconds; validation errors in units of the
step-1 model's torque standard deviation. The mechanisms, with their settings, are in
docs/architecture.md ("Lifelong adaptation"); their measured effect in docs/results.md.
"""

from __future__ import annotations

import copy

import numpy as np
import torch

from wrenchd.models.body_wall_tracker import (WALL_JOINTS, BodyWallTracker, wall_regressors)
from wrenchd.models.estimator.corr_finetune import CorrFineTuner
from wrenchd.models.estimator.correction import Corr, CorrKernel, zero_corr
from wrenchd.models.estimator.trocar_physics import fit_trocar, trocar_torque
from wrenchd.models.adaptation.buffer import RowRing
from wrenchd.models.adaptation.config import AdaptationConfig, RoundResult, corr_config_of
from wrenchd.models.series import N_JOINTS


#: what an announced set-up change can be (:meth:`Adapter.on_setup_change`)
SETUP_KINDS = ("pressure", "instrument")


def normalisation_of(free_space) -> dict[str, np.ndarray] | None:
    """The step-1 model's normalisation as a ``Corr`` normalisation (plain arrays); None for
    a model without one (a hybrid step 1): the adapter then fits it on its first samples."""
    if not isinstance(free_space, torch.nn.Module):
        return None
    return {"in_mean": free_space.in_mean.double().numpy().copy(),
            "in_std": free_space.in_std.double().numpy().copy(),
            "tau_mean": free_space.out_mean.double().numpy().copy(),
            "tau_std": free_space.out_std.double().numpy().copy()}


def _rmse_mean(pred: np.ndarray, target: np.ndarray) -> float:
    """Mean over joints of the RMSE of (B, 6) predictions (torque-std units)."""
    return float(np.mean(np.sqrt(np.mean((pred - target) ** 2, axis=0))))


class Adapter:
    """Replay buffer, fine-tuning rounds, validation and versions of the correction net.

    :meth:`add` offers free-motion samples, :meth:`round` runs a round when one is due,
    :meth:`on_drift` and :meth:`on_setup_change` are told of changes. The first net is a fresh
    ``Corr`` with a zero output layer (it changes nothing until a round is accepted),
    normalised as ``normalisation`` (the step-1 model's, :func:`normalisation_of`: fitted on
    the whole workspace) or else on the first ``min_train_samples`` samples.

    A step-1 model that misses 0.5 N m on the first joint, learnt in one round:

    >>> rng = np.random.default_rng(0)
    >>> step1 = rng.normal(size=(1000, 6))
    >>> adapter = Adapter()
    >>> adapter.add(rng.normal(size=(1000, 10, 12)), step1, step1 + [0.5, 0, 0, 0, 0, 0],
    ...             t=np.arange(1000) / 200)
    >>> adapter.recent.n, len(adapter.holdout)          # every 5th sample is held out
    (800, 200)
    >>> result = adapter.round(5.0)
    >>> result.accepted, result.version, result.val_after < result.val_before / 4
    (True, 1, True)
    >>> adapter.round(5.1) is None                     # the next one is due interval_s later
    True
    """

    def __init__(self, config: AdaptationConfig | None = None,
                 corr: Corr | None = None, version: int = 0,
                 normalisation: dict[str, np.ndarray] | None = None) -> None:
        self.config = c = config if config is not None else AdaptationConfig()
        self.normalisation = normalisation
        self.corr_config = corr_config_of(c)
        self.width = c.window * 12 + 2 * N_JOINTS
        self.recent = RowRing(c.recent_size, self.width)
        self.reservoir = RowRing(max(c.reservoir_size, 1), self.width)
        self._holdout = RowRing(c.holdout_size, self.width)
        self.corr = corr
        if corr is not None:
            self.corr_config = corr.config
        self.version = version
        self.seen = 0            # samples offered (for the holdout split and the reservoir)
        self._evicted = 0        # samples that left the recent ring (reservoir stream length)
        self._rng = np.random.default_rng(c.seed)
        self._scaling_cache: tuple | None = None
        self._batch_buf: tuple[np.ndarray, np.ndarray] | None = None
        self._eager_until = -np.inf
        # the end of the eager period of the latest set-up change, announced or taken from a
        # drift (extended by its first carry-over), on the rounds' clock: a drift before it
        # is that change's, not a new one
        self._change_until = -np.inf
        self._next_round: float | None = None
        self._trocar_until: float | None = None   # the wall's physics is fitted until then
        self.rounds = 0
        self.accepted = 0
        self.skipped = 0          # rounds due but skipped: nothing offered since the last
        self._seen_at_round = -1  # ``seen`` when the last round ran
        self._refused = 0         # rounds in a row whose candidate was refused
        self.body_wall = BodyWallTracker(c.body_wall)
        self._carried_segment = 0           # the latest segment the buffer was carried into

    # -- data ---------------------------------------------------------------------------
    def add(self, windows: np.ndarray, step1: np.ndarray, measured: np.ndarray,
            t: np.ndarray | None = None) -> None:
        """Offer free-motion samples: (n, W, 12) windows, (n, 6) step-1 and measured torques,
        and their sample times (n,) [s] (None: unknown; such samples are never carried over).
        Every ``holdout_every``-th sample goes to the held-out set of recent free motion, the
        others to a ring of ``recent_size`` recent samples; what leaves the ring enters a
        reservoir sample of ``reservoir_size`` older ones."""
        windows = np.asarray(windows, dtype=np.float32).reshape(len(step1), -1)
        self.add_rows(np.concatenate([windows, np.asarray(step1, np.float32),
                                      np.asarray(measured, np.float32)], axis=1), t)

    def add_rows(self, rows: np.ndarray, t: np.ndarray | None = None) -> None:
        """:meth:`add` of (n, W * 12 + 12) float32 rows: flat window, step-1, measured."""
        stamps = (np.full(len(rows), np.nan) if t is None
                  else np.asarray(t, dtype=np.float64).reshape(-1))
        if len(stamps) != len(rows):
            raise ValueError(f"{len(rows)} rows but {len(stamps)} times")
        if self.config.body_wall.enabled and len(rows):
            self._track(rows, stamps)
        for row, stamp in zip(rows, stamps):
            self.seen += 1
            if self.seen % self.config.holdout_every == 0:
                self._holdout.push(row, stamp)
                continue
            recent = self.recent
            if recent.n == recent.capacity and self.config.reservoir_size > 0:
                k = recent.head
                self._to_reservoir(recent.rows[k].copy(), recent.stamp[k], recent.shift[k])
            recent.push(row, stamp)

    def _to_reservoir(self, row: np.ndarray, stamp: float = np.nan, shift: float = 0.0) -> None:
        self._evicted += 1
        if self.reservoir.n < self.reservoir.capacity:
            self.reservoir.push(row, stamp, shift)
            return
        k = int(self._rng.integers(0, self._evicted))        # reservoir sampling
        if k < self.reservoir.capacity:
            self.reservoir.put(k, row, stamp, shift)

    def _positions(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities (n, 6) of rows: the newest sample of their window."""
        last = (self.config.window - 1) * 12
        return rows[:, last:last + N_JOINTS], rows[:, last + N_JOINTS:last + 2 * N_JOINTS]

    def _track(self, rows: np.ndarray, stamps: np.ndarray) -> None:
        """The body wall tracker's share of offered rows: their step-1 residual on the wall's
        joints. Times that go back by more than two bins are a new timeline (the robot's clock
        restarted: the pipeline's ``clock_reset``): see :meth:`_new_timeline`."""
        earliest = np.fmin.reduce(stamps)                     # NaN only if every time is
        if earliest < self.body_wall.latest - 2 * self.body_wall.config.bin_s:
            self._new_timeline()
        k = self.config.window * 12
        a, b = WALL_JOINTS[0], WALL_JOINTS[-1] + 1          # adjacent joints: slices
        residual = rows[:, k + N_JOINTS + a:k + N_JOINTS + b] - rows[:, k + a:k + b]
        self.body_wall.add(stamps, *self._positions(rows), residual)

    def _new_timeline(self) -> None:
        """Sample times restarted: the buffered rows stay as they were carried (the set-up did
        not change with the clock), but their times mean nothing on the new timeline, so they
        are never carried again; the tracker starts afresh."""
        for ring in (self.recent, self.reservoir, self._holdout):
            ring.stamp[:] = np.nan
            ring.shift[:] = 0.0
        self.body_wall = BodyWallTracker(self.config.body_wall)
        self._carried_segment = 0

    def on_setup_change(self, t: float, now: float | None = None,
                        kind: str = "pressure") -> None:
        """The set-up changed at sample time ``t`` [s] (announced): adapt eagerly from ``now``
        (the rounds' clock; default ``t``), for ``eager_s``.

        A ``"pressure"`` change (the insufflator's) carries the buffer over, the held-out set
        too: the tracker fits the body wall's stiffness ``k`` [N/m] per bin of sample time, and
        before every round each row from an earlier segment gets ``(k_now - k_then) g(q)``
        added to its measured yaw and pitch torques (``g``: the wall's torque per N/m), which
        follows the estimates as bins close. An ``"instrument"`` change (a new payload on the
        arm) cannot be carried over: no tracked quantity maps the old instrument's samples onto
        the new one, so the buffer, the held-out set and the tracker restart; the serving
        ``Corr`` is kept as the eager rounds' start and serves until one is accepted.

        Raises:
            ValueError: ``kind`` is not one of :data:`SETUP_KINDS`.
        """
        if kind not in SETUP_KINDS:
            raise ValueError(f"unknown set-up change kind {kind!r}; one of "
                             f"{', '.join(SETUP_KINDS)}")
        if kind == "instrument":
            self._forget_instrument()
        else:
            self.body_wall.announce(t)
        now = t if now is None else now
        self._eager_until = now + self.config.eager_s
        self._change_until = self._eager_until if kind == "pressure" else -np.inf
        self._next_round = now
        self._refused = 0

    def _forget_instrument(self) -> None:
        """Drop the training data of the instrument that left: the rings, the reservoir's
        sampling count and the body wall tracker; the serving ``Corr`` stays."""
        for ring in (self.recent, self.reservoir, self._holdout):
            ring.clear()
        self._evicted = 0
        self.body_wall = BodyWallTracker(self.config.body_wall)
        self._carried_segment = 0

    def _carry_over(self, t: float) -> int:
        """Bring every buffered row's measured yaw and pitch torques to the latest segment's
        body wall stiffness (what the tracker knows now); the number of rows changed. The
        first carry-over into a segment (its first bin closed, ~``bin_s`` after the change)
        makes the rounds eager again from ``t`` (the rounds' clock): the eager rounds before it
        trained on a buffer that still mixed the two set-ups."""
        if not self.config.body_wall.enabled or not self.body_wall.starts:
            return 0
        k = self.config.window * 12 + N_JOINTS
        changed = 0
        for ring in (self.recent, self.reservoir, self._holdout):
            if not ring.n:
                continue
            want = self.body_wall.carry_over(ring.stamp[:ring.n])
            idx = np.flatnonzero(np.abs(want - ring.shift[:ring.n]) > 1e-9)
            if not len(idx):
                continue
            q, dq = self._positions(ring.rows[idx])
            g, _ = wall_regressors(q, dq, self.config.body_wall.incision_m)
            delta = (want[idx] - ring.shift[idx])[:, None] * g
            for j, col in enumerate(WALL_JOINTS):
                ring.rows[idx, k + col] += delta[:, j].astype(np.float32)
            ring.shift[idx] = want[idx]
            ring.dirty[idx] = True
            changed += len(idx)
        latest = len(self.body_wall.starts)
        if changed and self._carried_segment < latest:
            self._carried_segment = latest
            self._eager_until = max(self._eager_until, t + self.config.eager_s)
            self._change_until = max(self._change_until, t + self.config.eager_s)
        return changed

    def on_drift(self, t: float, now: float | None = None) -> None:
        """A drift detected at sample time ``t`` [s]: adapt eagerly from ``now`` (the rounds'
        clock; default ``t``), forget the held-out samples (the old regime is no longer what
        "recent" means) and keep the reservoir. With ``drift_carry_over`` it is taken for an
        unannounced pressure change at ``t - drift_lead_s`` unless the rounds are still eager
        for the latest change (then it is that change's: a segment started there would be
        fitted on a bin or two of free motion and carry the whole buffer by its error)."""
        now = t if now is None else now
        within = now < self._change_until    # still adapting to the latest change
        self._eager_until = now + self.config.eager_s
        self._next_round = now
        self._refused = 0
        self._holdout.clear()
        if self.config.drift_carry_over and self.config.body_wall.enabled and not within:
            if self._carry_over_drift(t - self.config.drift_lead_s):
                self._change_until = self._eager_until

    def _carry_over_drift(self, onset: float) -> bool:
        """Take a drift for an unannounced change at ``onset`` [s], unless there is nothing
        to carry (no sample yet: the pipeline's eager start) or a change was taken less than
        ``eager_s`` before it (the drift is that change, announced or detected); whether it
        was taken."""
        if self.body_wall.latest == -np.inf:
            return False
        starts = self.body_wall.starts
        if starts and onset - starts[-1] < self.config.eager_s:
            return False
        self.body_wall.announce(onset)
        return True

    @property
    def holdout(self) -> np.ndarray:
        """The held-out rows, oldest first."""
        return self._holdout.rows[self._holdout.order()]

    def eager(self, t: float) -> bool:
        return t < self._eager_until

    # -- training -----------------------------------------------------------------------
    def _split(self, rows: np.ndarray) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        w = self.config.window
        x = torch.from_numpy(rows[:, :w * 12].reshape(-1, w, 12))
        s = torch.from_numpy(rows[:, w * 12:w * 12 + N_JOINTS])
        y = torch.from_numpy(rows[:, w * 12 + N_JOINTS:])
        return x, s, y

    def _scaling(self, corr: Corr) -> tuple:
        """``shift``, ``scale`` of a row's network input (window, step-1 torque) and the torque
        scale, as float32 arrays: the normalisation of ``corr`` applied to buffer rows; then
        ``corr``'s trocar physics parameters (float64; None without them), whose torque the
        net's target leaves out."""
        w = self.config.window
        shift = np.concatenate([np.tile(corr.in_mean.numpy(), w), corr.tau_mean.numpy()])
        scale = np.concatenate([np.tile(corr.in_std.numpy(), w), corr.tau_std.numpy()])
        theta = (corr.trocar_theta.double().numpy().copy() if corr.config.trocar_physics
                 else None)
        return (shift.astype(np.float32), scale.astype(np.float32),
                corr.tau_std.numpy().astype(np.float32), theta)

    def _residual(self, rows: np.ndarray, dtype=np.float32) -> np.ndarray:
        """(n, 6) measured minus step-1 torques of rows, computed in ``dtype``."""
        k = self.config.window * 12 + N_JOINTS
        return rows[:, k:].astype(dtype, copy=False) - rows[:, k - N_JOINTS:k]

    def _net_io(self, rows: np.ndarray, scaling, tensors: bool = True):
        """Rows -> (normalised network input, target correction in torque-std units): the same
        numbers as ``Corr.normalised_input`` and ``(measured - step1 - trocar) / tau_std``
        (``trocar``: the physics of the scaling's parameters, when it has them), on NumPy;
        torch tensors unless ``tensors`` is False."""
        shift, scale, tau_std, theta = scaling
        k = self.config.window * 12 + N_JOINTS
        inp = (rows[:, :k] - shift) / scale
        residual = self._residual(rows)
        if theta is not None:
            residual = residual - trocar_torque(*self._positions(rows), theta)
        target = (residual / tau_std).astype(np.float32)
        if not tensors:
            return inp, target
        return torch.from_numpy(inp), torch.from_numpy(target)

    def _net_rows(self, rows: np.ndarray, scaling) -> tuple[np.ndarray, np.ndarray]:
        return self._net_io(rows, scaling, tensors=False)

    def score(self, corr: Corr, rows: np.ndarray) -> float:
        """Held-out error: mean over joints of RMSE / tau_std of the corrected torque."""
        inp, target = self._net_io(rows, self._scaling(corr))
        with torch.no_grad():
            rmse = torch.sqrt(torch.mean((corr.net(inp) - target) ** 2, dim=0))
        return float(rmse.mean())

    def _refit_trocar(self, tuner: CorrFineTuner, scaling: tuple) -> tuple:
        """The trocar physics re-fitted on the training rows (recent ring and reservoir, each
        row alike: the physics is one model of the whole workspace, and weighting the recent
        ring as the mini-batches do made it follow local motion and extrapolate worse) to
        what the tuner's net leaves of their step-1 residual, shrunk towards the current
        parameters (``trocar_shrink``); returns the scaling with the new parameters, the
        rings' targets renormalised to it."""
        shift, scale, tau_std, theta = scaling
        parts = [(ring.rows[:ring.n], ring.inp[:ring.n]) for ring in (self.recent, self.reservoir)
                 if ring.n]
        rows = np.concatenate([p[0] for p in parts])
        net = np.concatenate([tuner.forward(p[1]) for p in parts]).astype(np.float64)
        residual = self._residual(rows, np.float64) - net * tau_std.astype(np.float64)
        theta = fit_trocar(*self._positions(rows), residual, theta, self.config.trocar_shrink)
        theta = theta.astype(np.float32).astype(np.float64)     # as the net's buffer holds it
        fitted = (shift, scale, tau_std, theta)
        for ring in (self.recent, self.reservoir, self._holdout):
            ring.normalise(fitted, self._net_rows)
        return fitted

    def due(self, t: float) -> bool:
        """Whether a round is due at time ``t`` [s] (and enough data is there)."""
        if not self.config.enabled or self.recent.n + self.reservoir.n < self._needed():
            return False
        if self._next_round is None:
            self._next_round = t
        return t >= self._next_round

    def may_be_due(self, t: float) -> bool:
        """False when no round can be due at ``t`` [s], whatever samples come before it: a
        cheap test that lets a caller skip :meth:`round` calls (:meth:`due` decides)."""
        return self.config.enabled and (self._next_round is None or t >= self._next_round)

    def _needed(self) -> int:
        return self.config.min_train_samples if self.corr is None else 32

    def _batch_split(self, n: int) -> tuple[int, int]:
        """Rows of an ``n``-row mini-batch from the recent ring and from the reservoir."""
        n_recent = n if self.reservoir.n == 0 else int(round(n * self.config.recent_fraction))
        n_recent = min(n_recent, n) if self.recent.n else 0
        return n_recent, (n - n_recent if self.reservoir.n else 0)

    def _batch(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """A mini-batch of ``n`` rows' (network input, target), drawn ``recent_fraction``
        from the recent ring, the rest from the reservoir, from the rings' normalised rows
        (:meth:`RowRing.normalise` first); the arrays are reused by the next call."""
        n_recent, n_old = self._batch_split(n)
        size = n_recent + n_old
        width = (self.recent.inp.shape[1], self.recent.target.shape[1])
        if self._batch_buf is None or self._batch_buf[0].shape != (size, width[0]):
            self._batch_buf = (np.empty((size, width[0]), np.float32),
                               np.empty((size, width[1]), np.float32))
        inp, target = self._batch_buf
        if n_recent:
            idx = self._rng.integers(0, self.recent.n, n_recent)
            self.recent.inp.take(idx, 0, inp[:n_recent])
            self.recent.target.take(idx, 0, target[:n_recent])
        if n_old:
            idx = self._rng.integers(0, self.reservoir.n, n_old)
            self.reservoir.inp.take(idx, 0, inp[n_recent:])
            self.reservoir.target.take(idx, 0, target[n_recent:])
        return inp, target

    def _round_scaling(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`_scaling` of the serving net, the same object while its values are (the
        rings then keep their normalised rows)."""
        scaling = self._scaling(self.corr)
        cached = self._scaling_cache
        if cached is not None and all(a is b or (a is not None and b is not None
                                                 and np.array_equal(a, b))
                                      for a, b in zip(scaling, cached)):
            return cached
        self._scaling_cache = scaling
        return scaling

    def _refit_output(self, tuner: CorrFineTuner) -> None:
        """Re-solve ``tuner``'s output layer (hidden -> 6 and its bias) on the recent ring's
        rows, in place, in float64: ``W = argmin |H W - T|^2 + lam |W - W_cur|^2`` with ``H``
        the features ``[relu(x W1 + b1), 1]``, ``T`` the targets and
        ``lam = refit_shrink * trace(H^T H) / (hidden + 1)``. A round's few Adam steps move the
        net only part of the way to a new regime; the hidden features, learnt over the whole
        history, stay and their read-out follows the recent one, shrunk towards the current
        layer so that a ring covering little of the workspace is not over-fitted."""
        ring = self.recent
        if ring.n == 0:
            return
        w1, b1, w2, b2 = tuner.params
        hidden = np.maximum(ring.inp[:ring.n] @ w1 + b1, 0.0).astype(np.float64)
        feats = np.concatenate([hidden, np.ones((ring.n, 1))], axis=1)      # (n, H + 1)
        current = np.concatenate([w2, b2[None]], axis=0).astype(np.float64)  # (H + 1, 6)
        gram = feats.T @ feats
        lam = self.config.refit_shrink * np.trace(gram) / len(gram)
        rhs = feats.T @ ring.target[:ring.n].astype(np.float64) + lam * current
        solved = np.linalg.solve(gram + lam * np.eye(len(gram)), rhs)
        w2[...] = solved[:-1]
        b2[...] = solved[-1]

    def _interval(self, eager: bool) -> float:
        """Time to the next round [s]: ``eager_interval_s`` while eager; else ``interval_s``,
        doubled per refused round past ``backoff_after`` in a row, up to ``backoff_max``
        times."""
        c = self.config
        if eager:
            return c.eager_interval_s
        over = self._refused - c.backoff_after + 1 if c.backoff_after else 0
        return c.interval_s * (min(2.0 ** over, c.backoff_max) if over > 0 else 1.0)

    def round(self, t: float) -> RoundResult | None:
        """One round at ``t`` [s] if due, else None: with ``trocar_physics`` and within
        ``trocar_fit_s`` of the first round, :meth:`_refit_trocar` first; ``round_steps`` Adam
        steps on batches drawn ``recent_fraction`` from the recent ring, the rest from the
        reservoir, then :meth:`_refit_output`; the candidate serves, as the next version, only
        if its held-out error is lower by ``min_improvement``. Outside an eager period a due
        round is skipped (None, counted in ``skipped``) when no sample was offered since the
        last one (``skip_idle``), and the interval backs off after refused rounds
        (:meth:`_interval`)."""
        if not self.due(t):
            return None
        c = self.config
        eager = self.eager(t)
        self._next_round = t + self._interval(eager)
        if (c.skip_idle and not eager and self.corr is not None
                and self.seen == self._seen_at_round):
            self.skipped += 1
            return None
        self._seen_at_round = self.seen
        if self.corr is None:
            rows = np.concatenate([self.recent.data(), self.reservoir.data()])
            x, s, _ = self._split(rows)
            self.corr = zero_corr(self.corr_config, x.numpy(), s.numpy(), self.config.seed,
                                  self.normalisation)
        self._carry_over(t)
        scaling = self._round_scaling()
        for ring in (self.recent, self.reservoir, self._holdout):
            ring.normalise(scaling, self._net_rows)
        n_holdout = self._holdout.n if self._holdout.n >= 16 else 0
        # Adam as torch.optim.Adam, on NumPy (models/estimator/corr_finetune.py: ~10x faster
        # per step at this size, where torch's dispatch costs more than the arithmetic). The
        # tuner starts from a copy of the serving net's weights.
        tuner = CorrFineTuner(self.corr.net, lr=c.lr, weight_decay=c.weight_decay)
        if n_holdout:
            order = self._holdout.order()
            h_inp, h_target = self._holdout.inp[order], self._holdout.target[order]
            before = _rmse_mean(tuner.forward(h_inp), h_target)
        fitted = scaling
        if self._trocar_until is None:
            self._trocar_until = t + c.trocar_fit_s
        if scaling[3] is not None and t < self._trocar_until:
            # the physics first, against the serving net; the net then learns what is left
            fitted = self._refit_trocar(tuner, scaling)
            if n_holdout:
                h_target = self._holdout.target[order]
        for _ in range(c.round_steps):
            tuner.step(*self._batch(c.batch_size), with_loss=False)
        if c.refit_shrink > 0:
            self._refit_output(tuner)
        self.rounds += 1
        n_train = self.recent.n + self.reservoir.n
        wall = self.body_wall.stiffnesses()
        if not n_holdout:
            return RoundResult(t, False, self.version, float("nan"), float("nan"), n_train, 0,
                               eager, body_wall=wall)
        after = _rmse_mean(tuner.forward(h_inp), h_target)
        accepted = after < before * (1.0 - c.min_improvement)
        self._refused = 0 if accepted else self._refused + 1
        self._next_round = t + self._interval(eager)       # backed off from this refusal on
        candidate = None
        if accepted:
            candidate = copy.deepcopy(self.corr)
            tuner.write_to(candidate.net)
            if fitted[3] is not None:
                candidate.trocar_theta.copy_(torch.from_numpy(fitted[3]))
                self._scaling_cache = fitted       # the rings hold this scaling's targets
            self.corr = candidate.eval()
            self.version += 1
            self.accepted += 1
        state = candidate.state_arrays() if accepted else None
        kernel = CorrKernel.from_state(state, self.corr.window) if accepted else None
        return RoundResult(t, accepted, self.version, before, after, n_train, n_holdout, eager,
                           state, kernel, wall)
