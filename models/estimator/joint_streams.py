"""Several streams stepped as one batch: the arms of one daemon sharing a step-1 kernel.

At each step the streams' recurrences form one batch, so the step-1 weights (about 1 MB) are
read once for all arms; each stream's restarts (its first sample, gaps, jumps), Corr window
and wrench stay its own. Equal to each stream's own
:meth:`~wrenchd.models.estimator.estimator.TwoStepEstimator.step_many` up to float32 rounding.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.series import N_JOINTS, all_finite

if TYPE_CHECKING:
    from wrenchd.models.estimator.estimator import EstimatorOutput, TwoStepEstimator


def step_many_joint(estimators: list[TwoStepEstimator],
                    batches: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
                    ) -> list[list[EstimatorOutput]]:
    """:meth:`TwoStepEstimator.step_many` for several streams whose estimators share one step-1 kernel
    (:meth:`TwoStepEstimator.share_step1`: arms of one daemon), their recurrences stepped together: at
    each step the streams are one batch, so the ~1 MB of step-1 weights are read once for
    all of them. Equal to each stream's own :meth:`step_many` up to float32 rounding.

    Args:
        estimators: B estimators sharing one step-1 kernel, each its own stream.
        batches: per estimator ``(t, q, dq, tau_measured)`` as in :meth:`step_many`
            (lengths may differ, zero included).
    Raises:
        ConfigError: estimators that do not share their step-1 kernel.
        DataError: wrong shapes or non-finite values (nothing is estimated then).
    """
    kernel = estimators[0]._recurrent
    if any(e._recurrent is not kernel for e in estimators):
        raise ConfigError("step_many_joint needs estimators sharing one step-1 kernel")
    if len(kernel.layers) != 1:            # stacked layers (Xfer): one stream at a time
        return [e.step_many(*b) for e, b in zip(estimators, batches)]
    if all(len(b[0]) == 1 for b in batches):
        return _step_one_each(estimators, batches)
    checked = [e._check_many(*b) for e, b in zip(estimators, batches)]
    layer = kernel.layers[0]
    lengths = [len(c[0]) for c in checked]
    steps, width = max(lengths, default=0), len(estimators)
    g, hid = layer.n_groups, layer.hidden_size
    proj = np.zeros((steps, width, g, 4 * hid), dtype=kernel.dtype)
    for i, (c, n) in enumerate(zip(checked, lengths)):
        if n:
            xp = c[2].astype(kernel.dtype) @ layer.weight_x
            xp += layer.bias_flat
            proj[:n, i] = xp.reshape(n, g, -1)
    h = np.zeros((g, width, hid), dtype=kernel.dtype)
    cell = np.zeros_like(h)
    for i, e in enumerate(estimators):
        if e._state is not None:
            h[:, i], cell[:, i] = e._state[0][:, 0], e._state[1][:, 0]
    restart = np.zeros((steps, width), dtype=bool)
    active = np.zeros((steps, width), dtype=bool)
    for i, (c, n) in enumerate(zip(checked, lengths)):
        restart[:n, i], active[:n, i] = c[4], True
    out = np.empty((steps, g, width, hid), dtype=kernel.dtype)
    for k in range(steps):
        if restart[k].any():
            h[:, restart[k]] = 0.0
            cell[:, restart[k]] = 0.0
        h_new, c_new = layer.step_projected(proj[k].transpose(1, 0, 2), h, cell)
        if not active[k].all():                  # a stream with fewer samples waits
            idle = ~active[k]
            h_new[:, idle], c_new[:, idle] = h[:, idle], cell[:, idle]
        h, cell = h_new, c_new
        out[k] = h
    results = []
    for i, (e, c, n) in enumerate(zip(estimators, checked, lengths)):
        if n == 0:
            results.append([])
            continue
        e._state = (np.ascontiguousarray(h[:, i:i + 1]), np.ascontiguousarray(cell[:, i:i + 1]))
        step1 = kernel.head(out[:n, :, i, :].transpose(1, 0, 2)).astype(np.float64)
        results.append(e._finish_many(c[0], c[1], c[2], c[3], c[4], step1))
    return results

def _step_one_each(estimators: list[TwoStepEstimator],
                   batches: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
                   ) -> list[list[EstimatorOutput]]:
    """:func:`step_many_joint` when every stream has one sample (arms at the same rate,
    each sample handled as it comes): the streams' inputs checked, projected, stepped and
    read out as one (B, ...) batch, without the per-stream bookkeeping of runs."""
    kernel = estimators[0]._recurrent
    layer = kernel.layers[0]
    try:
        t = np.array([float(b[0][0]) for b in batches])
        q = np.array([b[1] for b in batches], dtype=np.float64).reshape(-1, N_JOINTS)
        dq = np.array([b[2] for b in batches], dtype=np.float64).reshape(-1, N_JOINTS)
        tau = np.array([b[3] for b in batches], dtype=np.float64).reshape(-1, N_JOINTS)
    except (TypeError, ValueError) as exc:
        raise DataError(f"t must be (1,) and q, dq, tau_measured (1, 6) per stream: {exc}")
    width = len(estimators)
    if q.shape != (width, N_JOINTS) or dq.shape != q.shape or tau.shape != q.shape:
        raise DataError(f"t must be (1,) and q, dq, tau_measured (1, 6) per stream; got "
                        f"{q.shape}, {dq.shape}, {tau.shape} for {width} streams")
    x = np.concatenate([q, dq], axis=1)                                   # (B, 12)
    if not all_finite(t, x, tau):
        raise DataError("joint state contains NaN or Inf")
    g, hid = layer.n_groups, layer.hidden_size
    h = np.zeros((g, width, hid), dtype=kernel.dtype)
    cell = np.zeros_like(h)
    restart = []
    for i, e in enumerate(estimators):
        last = e._t_last
        fresh = (last is None or not 0.0 < t[i] - last <= e.config.max_gap_s
                 or e._jumped(float(t[i]), q[i], dq[i]))
        restart.append(fresh)
        if not fresh and e._state is not None:
            h[:, i], cell[:, i] = e._state[0][:, 0], e._state[1][:, 0]
    y, (h, cell) = kernel.step(x, (h, cell))
    step1 = y.astype(np.float64)                                        # (B, 6)
    results = []
    for i, e in enumerate(estimators):
        e._state = (np.ascontiguousarray(h[:, i:i + 1]),
                    np.ascontiguousarray(cell[:, i:i + 1]))
        results.append(e._finish_many(t[i:i + 1], q[i:i + 1], x[i:i + 1], tau[i:i + 1],
                                      np.array(restart[i:i + 1]), step1[i:i + 1]))
    return results
