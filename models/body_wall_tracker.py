"""The body wall's stiffness, tracked from free motion, and carried over at a set-up change.

After a set-up change (the insufflator's pressure set higher, say) the adaptation's replay
buffer still holds the old set-up's torques, and every mini-batch pulls the correction net back
towards them (docs/replay-and-policies.md, "What limits recovery"). The body wall at the port is
the effect insufflation changes (:mod:`wrenchd.models.physics.effects.body_wall`): a lateral
spring on the shaft whose stiffness ``k`` [N/m] rises with the pressure. Its torque on yaw and
pitch is ``k g(q)`` [N m], with ``g`` the torque per N/m at the incision point, plus a damping
term ``c h(q, dq)``. Once the stiffness before and after the change is known, every older
buffered sample is *carried over*: its measured yaw and pitch torques get
``(k_after - k_before) g(q)`` added, and the whole buffer speaks for the new set-up.

:class:`BodyWallTracker` measures ``k`` per bin of sample time on the step-1 residual of the
free motion offered for training, and the change needs to be *announced*
(:meth:`BodyWallTracker.announce`: the daemon's ``setup`` key, or a detected drift that the
adapter takes for one). Pure: arrays in, arrays out. The incision point is a setting
(:class:`BodyWallTrackerConfig`), by default the body wall effect's
(``BodyWallParams.incision_m``), which on the simulator is the truth; on a real set-up it
comes from the port placement or from the discrepancy workflow.
"""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.models.errors import DataError
from wrenchd.models.physics.effects.base import Motion
from wrenchd.models.physics.effects.body_wall import BodyWall, BodyWallParams

#: joints the body wall acts on (0-based): outer yaw and pitch
WALL_JOINTS = (0, 1)             # adjacent: the adapter takes them as a slice
_N_COLS = 4                      # stiffness, damping, offset yaw, offset pitch
#: samples kept before they are binned (:class:`BodyWallTracker`)
FLUSH_ROWS = 2048


class BodyWallTrackerConfig(BaseModel):
    """How the body wall's stiffness is tracked and the buffer carried over."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(default=True, description="carry the buffer over at an announced "
                                                    "set-up change")
    bin_s: float = Field(default=10.0, gt=0.0, description="stiffness bin length [s]")
    min_bin_samples: int = Field(default=300, ge=8,
                                 description="free-motion samples a bin needs to count")
    incision_m: tuple[float, float, float] = Field(
        default=BodyWallParams().incision_m,
        description="incision point relative to the RCM, base axes [m]")


def wall_regressors(q: np.ndarray, dq: np.ndarray, incision_m) -> tuple[np.ndarray, np.ndarray]:
    """Yaw and pitch torque per unit of the body wall's stiffness [N m per N/m] and of its
    damping [N m per N s/m]: ``(g, h)``, each (N, 2), for positions and velocities (N, 6)."""
    q = np.asarray(q, dtype=np.float64)
    dq = np.asarray(dq, dtype=np.float64)
    motion = Motion(np.zeros(len(q)), q, dq, np.zeros_like(q), None)
    base = {"incision_m": tuple(incision_m), "k_per_mmhg": 0.0}
    g = BodyWall({**base, "k0_n_per_m": 1.0, "damping_ns_per_m": 0.0}).torque(motion)
    h = BodyWall({**base, "k0_n_per_m": 0.0, "damping_ns_per_m": 1.0}).torque(motion)
    cols = list(WALL_JOINTS)
    return g[:, cols], h[:, cols]


class BodyWallTracker:
    """Per-bin stiffness of the body wall, and its change across announced set-up changes.

    Samples are added with their sample times; a bin is closed once a sample at least one bin
    later arrives (samples come in time order, give or take the pipeline's delay line). The
    segment of a time is the number of announced changes at or before it.

    ``k`` is fitted on the *step-1* residual (measured torque minus the free-space network's
    prediction), which still holds the whole body wall; the correction net's residual does not
    (it has absorbed most of it, and its own misfit dominates what is left). Per ``bin_s`` bin,
    the yaw and pitch residuals are regressed on ``[g, h, 1_yaw, 1_pitch]`` (stiffness,
    damping, one offset per joint: the free-space net's local bias); the bin's ``k`` is the
    first coefficient. A segment (the time between announced changes) is one fit over its
    bins, stiffness and damping shared and offsets per bin, so a bin that saw little free
    motion weighs little. The bins' level is biased by the free-space net's misfit, their step
    much less, and the carry-over uses only the step.

    Samples are kept as they come and binned in batches (:data:`FLUSH_ROWS`, and before
    anything reads or changes the bins): the pipeline offers a few rows at a time, and the
    regressors cost about as much for three rows as for a thousand. A notice should come
    before the samples after its time (the pipeline's delay line gives it a few seconds); one
    that comes later, or stamped in the past, drops the old segment's bins that reach past its
    time, and one older than an earlier notice moves the later segments up by one.
    """

    def __init__(self, config: BodyWallTrackerConfig | None = None) -> None:
        self.config = config if config is not None else BodyWallTrackerConfig()
        self.starts: list[float] = []                       # announced changes [s], sorted
        self._open: dict[tuple[int, int], list] = {}        # (segment, bin) -> [A, b, n]
        self._bins: list[tuple[float, int, float, int]] = []  # (bin start [s], segment, k, n)
        # per segment, the bins' information on (k, c) with their offsets eliminated, and
        # per closed bin what it added (a late notice takes it back out)
        self._pooled: dict[int, list[np.ndarray]] = {}       # segment -> [S (2, 2), r (2,)]
        self._reduced: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._latest = -math.inf
        self._pending: list[tuple[np.ndarray, ...]] = []    # added, not binned yet
        self._pending_n = 0

    @property
    def bins(self) -> list[tuple[float, int, float, int]]:
        """Closed bins: ``(bin start [s], segment, stiffness [N/m], samples)`` each."""
        self._flush()
        return self._bins

    @property
    def latest(self) -> float:
        """The latest sample time added [s] (-inf before any)."""
        return self._latest

    # -- input ---------------------------------------------------------------------------
    def segment_of(self, t: np.ndarray) -> np.ndarray:
        """Segment index of each sample time (N,); NaN times are in segment -1."""
        t = np.asarray(t, dtype=np.float64)
        seg = np.searchsorted(np.asarray(self.starts), t, side="right")
        return np.where(np.isfinite(t), seg, -1)

    def add(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray,
            residual: np.ndarray) -> None:
        """Free-motion samples: times (N,) [s], positions and velocities (N, 6), step-1
        residual torques of yaw and pitch (N, 2) [N m] (copied). Samples without a finite
        time, position, velocity or residual are ignored (when they are binned; :attr:`latest`
        counts every finite time).

        Raises:
            DataError: shapes that do not match.
        """
        t = np.array(t, dtype=np.float64).reshape(-1)
        q, dq = np.array(q, np.float64), np.array(dq, np.float64)
        residual = np.array(residual, np.float64)
        n = len(t)
        if q.shape != (n, 6) or dq.shape != (n, 6) or residual.shape != (n, 2):
            raise DataError(f"body wall tracker: expected (N,), (N, 6), (N, 6), (N, 2), got "
                            f"{t.shape}, {q.shape}, {dq.shape}, {residual.shape}")
        if n == 0:
            return
        latest = float(np.fmax.reduce(t))                     # NaN only if every time is
        if latest > self._latest:
            self._latest = latest
        self._pending.append((t, q, dq, residual))
        self._pending_n += n
        if self._pending_n >= FLUSH_ROWS:
            self._flush()

    def _flush(self) -> None:
        """Bin the samples kept since the last flush and close the bins they complete."""
        if not self._pending:
            return
        t, q, dq, residual = (np.concatenate(parts) for parts in zip(*self._pending))
        self._pending, self._pending_n = [], 0
        ok = np.isfinite(t) & np.isfinite(residual).all(axis=1) & np.isfinite(q).all(axis=1) \
            & np.isfinite(dq).all(axis=1)
        if not ok.all():
            t, q, dq, residual = t[ok], q[ok], dq[ok], residual[ok]
        if len(t) == 0:
            return
        g, h = wall_regressors(q, dq, self.config.incision_m)
        seg = self.segment_of(t)
        b = np.floor((t - self._origin(seg)) / self.config.bin_s).astype(np.int64)
        for key in sorted(set(zip(seg.tolist(), b.tolist()))):
            m = (seg == key[0]) & (b == key[1])
            k = int(m.sum())
            x = np.zeros((2 * k, _N_COLS))
            x[:, 0] = g[m].reshape(-1)
            x[:, 1] = h[m].reshape(-1)
            x[0::2, 2] = 1.0
            x[1::2, 3] = 1.0
            acc = self._open.setdefault(key, [np.zeros((_N_COLS, _N_COLS)), np.zeros(_N_COLS), 0])
            acc[0] += x.T @ x
            acc[1] += x.T @ residual[m].reshape(-1)
            acc[2] += k
        self._close(self._latest)

    def _origin(self, seg: np.ndarray) -> np.ndarray:
        """Where each segment's bins start [s]: 0 for the first, else its announced change
        (bins never straddle a change)."""
        starts = np.concatenate([[0.0], self.starts])
        return starts[np.maximum(seg, 0)]

    def announce(self, t: float) -> None:
        """A set-up change at sample time ``t`` [s]: later samples start a new segment.

        Raises:
            DataError: ``t`` is not finite.
        """
        if not math.isfinite(t):
            raise DataError(f"a set-up change needs a finite time, got {t!r}")
        t = float(t)
        self._flush()                   # the samples so far were added before the notice
        old = int(self.segment_of(np.array([t]))[0])     # the segment it splits
        # Samples are binned by the segments known when they arrive. A notice that comes after
        # samples past its time were added (later than the pipeline's delay line, or stamped
        # in the past) finds them in the old segment: the bins of that segment that reach
        # past ``t`` mix the two set-ups and are dropped, closed or open (their samples are
        # lost to the tracker, not re-binned: only their sums were kept).
        edge = t - float(self._origin(np.array([old]))[0])
        for key in [key for key in self._open if key[0] == old
                    and (key[1] + 1) * self.config.bin_s > edge]:
            del self._open[key]
        mixed = [key for key in self._reduced if key[0] == old
                 and (key[1] + 1) * self.config.bin_s > edge]
        for key in mixed:
            info, rhs = self._reduced.pop(key)
            self._pooled[old][0] -= info
            self._pooled[old][1] -= rhs
        if mixed:
            self._bins = [b for b in self._bins if not (b[1] == old and b[0] + self.config.bin_s
                                                      > t)]
            if not any(key[0] == old for key in self._reduced):
                del self._pooled[old]
        # a notice older than another one: the later segments move up by one
        def up(seg: int) -> int:
            return seg + 1 if seg > old else seg
        self._open = {(up(s), b): v for (s, b), v in self._open.items()}
        self._reduced = {(up(s), b): v for (s, b), v in self._reduced.items()}
        self._pooled = {up(s): v for s, v in self._pooled.items()}
        self._bins = [(b, up(s), k, n) for b, s, k, n in self._bins]
        self.starts.insert(bisect_right(self.starts, t), t)

    # -- output --------------------------------------------------------------------------
    def _close(self, latest: float) -> None:
        """Close the bins that end at or before ``latest`` [s] (samples come in time order)
        and those of earlier segments."""
        c = self.config
        current = int(self.segment_of(np.array([latest]))[0])
        done = [key for key in self._open
                if key[0] < current
                or float(self._origin(np.array([key[0]]))[0]) + (key[1] + 1) * c.bin_s <= latest]
        for key in sorted(done):
            a, v, n = self._open.pop(key)
            if n < c.min_bin_samples:
                continue
            try:
                coef = np.linalg.solve(a, v)
                # the bin's own offsets eliminated (Schur complement): what it says of (k, c)
                gain = a[:2, 2:] @ np.linalg.inv(a[2:, 2:])
            except np.linalg.LinAlgError:
                continue                                  # no excitation: nothing to say
            if not np.isfinite(coef).all():
                continue
            start = float(self._origin(np.array([key[0]]))[0]) + key[1] * c.bin_s
            self._bins.append((start, key[0], float(coef[0]), n))
            info, rhs = a[:2, :2] - gain @ a[2:, :2], v[:2] - gain @ v[2:]
            self._reduced[key] = (info, rhs)
            pooled = self._pooled.setdefault(key[0], [np.zeros((2, 2)), np.zeros(2)])
            pooled[0] += info
            pooled[1] += rhs

    def stiffness(self, segment: int) -> float | None:
        """Stiffness [N/m] of a segment: one least-squares fit over its closed bins, stiffness
        and damping shared, yaw and pitch offsets per bin (a bin that saw little motion, or
        little of it free, weighs little); None before its first bin."""
        self._flush()
        pooled = self._pooled.get(segment)
        if pooled is None:
            return None
        try:
            k = float(np.linalg.solve(pooled[0], pooled[1])[0])
        except np.linalg.LinAlgError:
            return None
        return k if math.isfinite(k) else None

    def carry_over(self, t: np.ndarray) -> np.ndarray:
        """The stiffness change [N/m] that brings a sample of time ``t`` (N,) to the latest
        segment: ``k(latest) - k(its segment)``; 0 where either is not known yet (or the
        time is not finite)."""
        seg = self.segment_of(t)
        out = np.zeros(len(seg))
        now = len(self.starts)
        k_now = self.stiffness(now)
        if k_now is None:
            return out
        for s in set(seg.tolist()) - {now, -1}:
            k = self.stiffness(s)
            if k is not None:
                out[seg == s] = k_now - k
        return out

    def stiffnesses(self) -> list[float | None]:
        """:meth:`stiffness` of every segment, oldest first (one more than the changes)."""
        return [self.stiffness(i) for i in range(len(self.starts) + 1)]
