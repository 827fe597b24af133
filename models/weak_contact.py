"""Weak contacts the gate passes as free motion, kept out of training by their form.

A contact under the gate's bounds (about 1 N against a free-motion error of about 1 N) is
published free and would train the correction net on a contact's torques. Its residual
still has a contact's form: a force at the tool tip makes ``J_v^T f``, six torques from
three numbers, and a fit of a tip force to it leaves almost nothing; free-motion model
error leaves about a third to a half of its scored residual (the wrist joints, which a tip
force barely loads, carry their own error). So over a short run of free samples whose
residual a tip force of over ``weak_contact_force_n`` explains to within
``weak_contact_misfit`` (median over ``weak_contact_s``), the pipeline trains on nothing and
drops what waited in its delay line from ``onset_margin_s`` before. What the gate publishes is
unchanged: this only chooses what trains.

A model gone wrong in a way a tip force explains would be held back for ever; a run longer
than ``weak_contact_max_s`` is taken for that and trains again until the form clears. The
pipeline asks only after the calibration (an untrained model's error is the trocar's, a
force on the shaft, which a tip force explains too on the first three joints) and outside
eager adaptation (after a drift or a set-up change the model is known to be wrong).

The hot path gains a comparison per sample: a row (positions, residual) is kept every
``STRIDE_S`` and the rows are judged together every ``JUDGE_S``, one Jacobian batch.
"""

from __future__ import annotations

import math
from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from wrenchd.models.contact_hysteresis import tip_force_fit

if TYPE_CHECKING:
    from wrenchd.models.gate import GateConfig
    from wrenchd.models.physics.kinematics import PSMKinematics

#: a row is kept every this long [s], and the kept rows are judged every ``JUDGE_S`` [s]
#: (or when ``ROWS`` wait)
STRIDE_S, JUDGE_S, ROWS = 0.01, 0.1, 32


class WeakContactWatch:
    """Whether free samples may train, judged on their residual's form (module docstring).

    Feed it every free sample (:meth:`update`) and tell it when the gate's contact or a gap
    breaks the run of free samples (:meth:`clear`).

    >>> import numpy as np
    >>> from wrenchd.models.gate import GateConfig
    >>> from wrenchd.models.physics.kinematics import PSMKinematics
    >>> kin, std = PSMKinematics(), np.array([0.1, 0.1, 0.5, 0.01, 0.01, 0.01])
    >>> watch = WeakContactWatch(GateConfig(), kin)
    >>> q = np.array([0.2, -0.1, 0.12, 0.3, 0.1, -0.2])
    >>> push = kin.jacobian(q[None], "hybrid")[0, :3, :].T @ np.array([0.0, 0.0, 1.5])
    >>> held = [watch.update(i * 0.001, q, push, std) for i in range(1000)]
    >>> round(held.index(True) * 0.001, 1), held[-1], watch.runs          # from half a window
    (0.2, True, 1)
    """

    def __init__(self, config: GateConfig, kinematics: PSMKinematics) -> None:
        self.config = config
        self._kinematics = kinematics
        self.runs = 0                       # runs held back so far (the pipeline counts samples)
        # rows waiting to be judged (copied: the caller's arrays are not kept)
        self._q, self._r, self._t = np.empty((ROWS, 6)), np.empty((ROWS, 6)), np.empty(ROWS)
        self._n = 0
        self._clear = False                 # nothing kept since the last clear()
        self.clear()

    def clear(self) -> None:
        """Forget the run of free samples (a contact, a gap, a new set-up); called on every
        sample in contact, so a clear watch returns at once."""
        if self._clear:
            return
        self._clear = True
        self._n = 0
        self._judged: deque[tuple[float, float, float]] = deque()   # (t, misfit, |f|)
        self._next_row = -math.inf
        self._next_judge = -math.inf
        self._since: float | None = None     # the form has held since then [s]
        self.holding = False
        self.onset: float | None = None      # set at the sample a run starts being held

    def update(self, t: float, position: np.ndarray, residual: np.ndarray,
               std: np.ndarray) -> bool:
        """Note a free sample at ``t`` [s]; whether it is held back from training. Where a
        run starts being held, :attr:`onset` is its first judged time [s] (else None)."""
        self.onset = None
        self._clear = False
        if t >= self._next_row:
            self._next_row = t + STRIDE_S
            n = self._n
            self._q[n] = position
            self._r[n] = residual
            self._t[n] = t
            self._n = n + 1
            if t >= self._next_judge or self._n == ROWS:
                self._next_judge = t + JUDGE_S
                self._judge(t, std)
        return self.holding

    def _judge(self, t: float, std: np.ndarray) -> None:
        cfg = self.config
        n, self._n = self._n, 0
        misfit, f = tip_force_fit(self._kinematics.jacobian(self._q[:n], "hybrid"),
                                  self._r[:n], np.asarray(std, float))
        force = np.sqrt(np.sum(f * f, axis=1))
        judged = self._judged
        judged.extend(zip(self._t[:n].tolist(), misfit.tolist(), force.tolist()))
        while judged and judged[0][0] < t - cfg.weak_contact_s:
            judged.popleft()
        if len(judged) < max(3, 0.5 * cfg.weak_contact_s / STRIDE_S):   # half a window
            return
        _, m, fn = zip(*judged)
        tip_like = (float(np.median(m)) < cfg.weak_contact_misfit
                    and float(np.median(fn)) > cfg.weak_contact_force_n)
        if not tip_like:
            self._since = None
            self.holding = False
            return
        if self._since is None:
            self._since = judged[0][0]
            self.holding = True
            self.onset = self._since
            self.runs += 1
        elif t - self._since > cfg.weak_contact_max_s:
            self.holding = False                 # lasting: a model error, not a contact
