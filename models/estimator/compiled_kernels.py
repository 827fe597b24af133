"""numba kernels of :mod:`wrenchd.models.estimator.compiled` (imported only where numba is
installed and wanted; see there for the numerics)."""

from __future__ import annotations

import numba
import numpy as np

f32 = np.float32
# error_model="numpy": a float division by zero gives inf or NaN as in NumPy instead of
# raising; numba's default ("python") tests every divisor, and that branch keeps LLVM from
# vectorising the loops around tanh32 (the gates' activations ran 8x slower). The one
# divisor here, tanh32's q, is at least 4.9e-3.
jit = numba.njit(cache=True, fastmath=True, nogil=True, error_model="numpy")
inline = numba.njit(inline="always", fastmath=True, nogil=True, error_model="numpy")


# tanh on float32 as a rational function of x^2 on [-c, c], +-1 beyond: the coefficients
# of Eigen's generic_fast_tanh_float (Eigen/src/Core/MathFunctionsImpl.h, MPL-2.0).
@inline
def tanh32(x):
    x = min(max(x, f32(-7.90531110763549805)), f32(7.90531110763549805))
    x2 = x * x
    p = f32(-2.76076847742355e-16)
    p = p * x2 + f32(2.00018790482477e-13)
    p = p * x2 + f32(-8.60467152213735e-11)
    p = p * x2 + f32(5.12229709037114e-08)
    p = p * x2 + f32(1.48572235717979e-05)
    p = p * x2 + f32(6.37261928875436e-04)
    p = p * x2 + f32(4.89352455891786e-03)
    q = f32(1.19825839466702e-06)
    q = q * x2 + f32(1.18534705686654e-04)
    q = q * x2 + f32(2.26843463243900e-03)
    q = q * x2 + f32(4.89352518554385e-03)
    return x * p / q


@inline
def lstm_layer(x, w, b, h, c):
    """One LSTM layer of G groups for B streams: x (Gx, B, n_in) with Gx 1 (an input shared
    by the groups) or G; w (G, n_in + H, 4H) with columns i, f, o, g and the sigmoid gates
    pre-scaled by 1/2; b (G, 4H); h, c (G, B, H). Returns the new ``(h, c)``."""
    groups, rows, cols = w.shape
    streams = h.shape[1]
    hidden = cols // 4
    n_in = rows - hidden
    h_out = np.empty((groups, streams, hidden), np.float32)
    c_out = np.empty((groups, streams, hidden), np.float32)
    z = np.empty((streams, cols), np.float32)
    for g in range(groups):
        xg = 0 if x.shape[0] == 1 else g
        for s in range(streams):
            for j in range(cols):
                z[s, j] = b[g, j]
        for i in range(n_in):                  # each weight row read once for all streams
            for s in range(streams):
                v = x[xg, s, i]
                for j in range(cols):
                    z[s, j] += v * w[g, i, j]
        for i in range(hidden):
            for s in range(streams):
                v = h[g, s, i]
                for j in range(cols):
                    z[s, j] += v * w[g, n_in + i, j]
        for s in range(streams):
            for j in range(cols):
                z[s, j] = tanh32(z[s, j])
            for j in range(hidden):
                cn = ((f32(0.5) + f32(0.5) * z[s, hidden + j]) * c[g, s, j]
                      + (f32(0.5) + f32(0.5) * z[s, j]) * z[s, 3 * hidden + j])
                c_out[g, s, j] = cn
                h_out[g, s, j] = (f32(0.5) + f32(0.5) * z[s, 2 * hidden + j]) * tanh32(cn)
    return h_out, c_out


@inline
def heads(top, trunk_w, trunk_b, trunk_n, offsets, final_w, final_b):
    """The output heads on the last layer's hidden states ``top`` (G, B, H): each group's
    optional ReLU trunk layer (``trunk_n[g]`` outputs, weights (G, width, H); 0: none, the
    hidden state passes), then one block-diagonal final layer (n_out, features) over the
    groups' features (group g's at ``offsets[g]``). Returns (B, n_out)."""
    groups, streams, hidden = top.shape
    n_out, n_feats = final_w.shape
    feats = np.empty(n_feats, np.float32)
    y = np.empty((streams, n_out), np.float32)
    for s in range(streams):
        for g in range(groups):
            o, n = offsets[g], trunk_n[g]
            if n == 0:
                for j in range(hidden):
                    feats[o + j] = top[g, s, j]
                continue
            for j in range(n):
                acc = trunk_b[g, j]
                for i in range(hidden):
                    acc += trunk_w[g, j, i] * top[g, s, i]
                feats[o + j] = max(acc, f32(0.0))
        for j in range(n_out):
            acc = final_b[j]
            for i in range(n_feats):
                acc += final_w[j, i] * feats[i]
            y[s, j] = acc
    return y


@jit
def layer_step(x, w, b, h, c):
    """One LSTM layer (:func:`lstm_layer`): ``(h, c)`` new."""
    return lstm_layer(x, w, b, h, c)


@jit
def heads_step(top, trunk_w, trunk_b, trunk_n, offsets, final_w, final_b):
    """:func:`heads` on its own (after several layers)."""
    return heads(top, trunk_w, trunk_b, trunk_n, offsets, final_w, final_b)


@jit
def one_layer_step(x, w, b, h, c, trunk_w, trunk_b, trunk_n, offsets, final_w, final_b):
    """A one-layer kernel's whole step: ``(y (B, n_out), h, c)``."""
    h_out, c_out = lstm_layer(x, w, b, h, c)
    y = heads(h_out, trunk_w, trunk_b, trunk_n, offsets, final_w, final_b)
    return y, h_out, c_out


@jit
def mlp2_residual(window, step1, w1, b1, w2, b2):
    """``step1 + W2 relu(W1 [window, step1] + b1) + b2`` for one row, in float32: the
    correction net with its normalisation folded in. window (W, F) float64, step1 (6,)
    float32; w1 (hidden, W F + 6), w2 (6, hidden): each output's weights contiguous."""
    rows, feats = window.shape
    n_win = rows * feats
    hidden = w1.shape[0]
    v = np.empty(n_win + step1.shape[0], np.float32)
    for r in range(rows):
        for f in range(feats):
            v[r * feats + f] = f32(window[r, f])
    for k in range(step1.shape[0]):
        v[n_win + k] = step1[k]
    a = np.empty(hidden, np.float32)
    for j in range(hidden):
        acc = b1[j]
        for i in range(v.shape[0]):
            acc += w1[j, i] * v[i]
        a[j] = max(acc, f32(0.0))
    out = np.empty(w2.shape[0], np.float32)
    for j in range(w2.shape[0]):
        acc = b2[j]
        for i in range(hidden):
            acc += w2[j, i] * a[i]
        out[j] = step1[j] + acc
    return out


# The correction net's fine-tuning (:mod:`wrenchd.models.estimator.corr_finetune`): the
# element-wise parts of a step, each NumPy float32 operation of the NumPy form in its order,
# one element at a time. No fastmath (it would fuse a multiply and an add into one rounding):
# the same bits as NumPy, so a fine-tuning gives the same nets with or without numba.
exact = numba.njit(cache=True, nogil=True, error_model="numpy")


@exact
def hidden_forward(z, b1, h):
    """``z += b1; h = max(z, 0)`` for the hidden layer's (B, H) pre-activations ``z``."""
    rows, cols = z.shape
    zero = f32(0.0)
    for r in range(rows):
        for j in range(cols):
            v = z[r, j] + b1[j]
            z[r, j] = v
            h[r, j] = v if v >= zero else zero


@exact
def output_error(err, b2, target, scale, g_b2):
    """``err = (err + b2 - target) * scale`` (the loss's gradient at the output, in place) and
    ``g_b2`` its column sums, summed row after row."""
    rows, cols = err.shape
    for j in range(cols):
        g_b2[j] = f32(0.0)
    for r in range(rows):
        for j in range(cols):
            v = ((err[r, j] + b2[j]) - target[r, j]) * scale
            err[r, j] = v
            g_b2[j] += v


@exact
def hidden_backward(d_h, z, g_b1):
    """``d_h *= z > 0`` (the ReLU's gradient, in place) and ``g_b1`` its column sums."""
    rows, cols = d_h.shape
    zero = f32(0.0)
    for j in range(cols):
        g_b1[j] = zero
    for r in range(rows):
        for j in range(cols):
            v = d_h[r, j] * (f32(1.0) if z[r, j] > zero else zero)
            d_h[r, j] = v
            g_b1[j] += v


@exact
def adam_update(flat, g, m, v, weight_decay, b1, b2, gain1, gain2, step_size, root_bc2, eps):
    """Adam's update of the flat parameters (every argument float32): ``g += wd flat``;
    ``m = b1 m + (1 - b1) g``; ``v = b2 v + (1 - b2) g^2``;
    ``flat -= step_size m / (sqrt(v) / root_bc2 + eps)``."""
    for i in range(flat.shape[0]):
        gi = g[i]
        if weight_decay != f32(0.0):
            gi = gi + flat[i] * weight_decay
            g[i] = gi
        mi = m[i] * b1 + gi * gain1
        vi = v[i] * b2 + (gi * gi) * gain2
        m[i] = mi
        v[i] = vi
        flat[i] = flat[i] - (mi / (np.sqrt(vi) / root_bc2 + eps)) * step_size


# The hybrid step 1's streaming step (models/estimator/hybrid.py), in float64 without
# fastmath: the NumPy path's operations element by element, in its order where it sums
# (the acceleration filter's taps may round otherwise: ~1e-16 relative).
@exact
def hybrid_motion(q, v, history, started, acc_weights, follower, width):
    """One sample of B streams: the causal acceleration filter and the play operator.

    q, v (B, 6) positions and velocities; history (B, taps, 6) the velocities, newest first;
    started (B,) whether a stream has a history and a follower (else it starts at this
    sample); acc_weights (6, taps); follower (B, 6); width (6,) the play widths (empty: no
    play). Returns the accelerations (B, 6), the new history, the play outputs (B, 6)
    (zeros without play) and the new followers: ``z = clip(follower, q - w, q + w)`` (``q``
    where not started), outputs ``(q - z) / w``."""
    streams, taps, joints = history.shape
    new = np.empty_like(history)
    acc = np.empty((streams, joints))
    out = np.zeros((streams, joints))
    new_follower = follower.copy()
    play = width.shape[0] > 0
    for s in range(streams):
        for j in range(joints):
            new[s, 0, j] = v[s, j]
            for i in range(1, taps):
                new[s, i, j] = history[s, i - 1, j] if started[s] else v[s, j]
            a = 0.0
            for i in range(taps):
                a += new[s, i, j] * acc_weights[j, i]
            acc[s, j] = a
            if play:
                z = q[s, j]
                if started[s]:
                    z = min(max(follower[s, j], q[s, j] - width[j]), q[s, j] + width[j])
                new_follower[s, j] = z
                out[s, j] = (q[s, j] - z) / width[j]
    return acc, new, out, new_follower


@jit
def nearest_distance(row, mean, scale, points, norms):
    """Distance of ``(row - mean) / scale`` to the nearest of ``points`` (M, D), whose
    squared norms are ``norms`` (M,): ``|p|^2 - 2 p.z + |z|^2`` at its least (the
    coverage's streamed form; fastmath: sums in any order, as a BLAS product's)."""
    width = row.shape[0]
    z = np.empty(width)
    zz = 0.0
    for k in range(width):
        z[k] = (row[k] - mean[k]) / scale[k]
        zz += z[k] * z[k]
    best = np.inf
    for p in range(points.shape[0]):
        dot = 0.0
        for k in range(width):
            dot += points[p, k] * z[k]
        best = min(best, norms[p] - 2.0 * dot)
    return np.sqrt(max(best + zz, 0.0))


@exact
def hybrid_combine(rigid, q, dq, acc, presliding, friction, coulomb_v0, spring, play,
                   residual, rows, mean, scale, points, norms, inner, outer, low, high,
                   margin):
    """Physics plus trusted residual (B, 6): ``rigid`` the rigid body's torques (B, 6);
    ``friction`` (K, 6) the diagonal columns' coefficients in their order (armature,
    Coulomb: tanh(dq / coulomb_v0), or sign(dq) where coulomb_v0 <= 0, viscous, offset
    [, spring] [, play]); ``residual`` (B, 6) the net's torques, trusted by the distance of
    ``rows`` (B, D) to the coverage (:func:`nearest_distance`) between its ``inner`` and
    ``outer`` bounds; ``low``, ``high`` (6,) the residual's range, its trust falling over
    ``margin`` times its width (margin <= 0: no bound)."""
    streams, joints = q.shape
    y = np.empty((streams, joints))
    for s in range(streams):
        distance = nearest_distance(rows[s], mean, scale, points, norms)
        x = min(max((outer - distance) / (outer - inner), 0.0), 1.0)
        w = x * x * (3.0 - 2.0 * x)
        if margin > 0.0:
            worst = 0.0
            for j in range(joints):
                r = residual[s, j]
                o = max(max(low[j] - r, r - high[j]), 0.0) / max(high[j] - low[j], 1e-12)
                worst = max(worst, o)
            x = min(max(worst / margin, 0.0), 1.0)
            bound = 1.0 - x * x * (3.0 - 2.0 * x)
            w = w * (1.0 - (1.0 - w) * (1.0 - bound))
        for j in range(joints):
            t = rigid[s, j] + acc[s, j] * friction[0, j]
            if coulomb_v0 > 0.0:
                t += np.tanh(dq[s, j] / coulomb_v0) * friction[1, j]
            else:
                t += np.sign(dq[s, j]) * friction[1, j]
            t += dq[s, j] * friction[2, j]
            t += friction[3, j]
            k = 4
            if spring:
                t += q[s, j] * friction[k, j]
                k += 1
            if play:
                t += presliding[s, j] * friction[k, j]
            y[s, j] = t + w * residual[s, j]
    return y


@exact
def plain_wrench(jac, tau, bound2, out):
    """The undamped tip wrench ``out = J^-T tau`` (6,) of a (6, 6) Jacobian where it is
    provably exact, as :meth:`~wrenchd.models.estimator.wrench.WrenchMap.wrench`'s fast path:
    ``J^-1`` by Gauss-Jordan elimination with partial pivoting, and True when ``J`` is
    invertible and ``||J^-1||_F^2 <= bound2`` (then ``s_min >= threshold``); False (``out``
    untouched) where the damped map must decide."""
    n = jac.shape[0]
    a = np.empty((n, 2 * n))
    for i in range(n):
        for j in range(n):
            a[i, j] = jac[i, j]
            a[i, n + j] = 1.0 if i == j else 0.0
    for col in range(n):
        pivot, best = col, abs(a[col, col])
        for i in range(col + 1, n):
            if abs(a[i, col]) > best:
                pivot, best = i, abs(a[i, col])
        if best == 0.0 or not np.isfinite(best):
            return False
        if pivot != col:
            for j in range(2 * n):
                a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
        inv_p = 1.0 / a[col, col]
        for j in range(2 * n):
            a[col, j] *= inv_p
        for i in range(n):
            if i != col:
                f = a[i, col]
                if f != 0.0:
                    for j in range(2 * n):
                        a[i, j] -= f * a[col, j]
    frob2 = 0.0
    for i in range(n):
        for j in range(n):
            frob2 += a[i, n + j] * a[i, n + j]
    if not frob2 <= bound2:
        return False
    for j in range(n):                       # (J^-1)^T tau: column j of J^-1 against tau
        acc = 0.0
        for i in range(n):
            acc += a[i, n + j] * tau[i]
        out[j] = acc
    return True
