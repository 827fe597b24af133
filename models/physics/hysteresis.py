"""Rate-independent friction: the play operator, a presliding Coulomb term for cable drives.

A Coulomb term ``Fc * tanh(dq / v0)`` switches with the velocity: it assumes friction
reverses as soon as the joint does. In a cable-driven joint (the PSM's yaw, pitch and
insertion run on cables and capstans) the friction torque reverses over a small
*displacement* after a reversal instead, while the cables and the contacts they slide on
deform elastically before they slip (presliding; Dahl, "A solid friction model", Aerospace
Corp. TOR-0158, 1968). The simplest rate-independent model of that is the play (backlash)
operator of width ``r`` (Krasnosel'skii and Pokrovskii, "Systems with Hysteresis", 1989):
a follower ``z`` that the position drags along once it is ``r`` away,

    z[k] = clip(z[k - 1], q[k] - r, q[k] + r),        p[k] = (q[k] - z[k]) / r  in [-1, 1],

with ``z`` starting at the first position of a segment (``p = 0``: no presliding history
known). ``p`` is +1 after the joint has moved at least ``2 r`` forward since its last
reversal, -1 after as far backward, and linear in between. ``Fh * p`` is then a friction
torque with memory that is linear in its coefficient ``Fh``, so it joins the least-squares
columns of :mod:`wrenchd.models.physics.least_squares`; a weighted sum of several widths is a
Prandtl-Ishlinskii hysteresis model (Kuhnen, "Modeling, identification and compensation of
complex hysteretic nonlinearities", Eur. J. Control 9(4), 2003).

It is causal and its state is ``z`` (one value per joint): a segment cut anywhere and
continued from the state gives the same output as the whole segment. Units: ``q`` and ``r``
in rad (m for the insertion joint), ``p`` dimensionless.
"""

from __future__ import annotations

import numpy as np
from wrenchd.models.errors import DataError


def play(position: np.ndarray, width: np.ndarray, follower: np.ndarray | None = None
         ) -> tuple[np.ndarray, np.ndarray]:
    """The play operator over one gap-free segment.

    Args:
        position: (T, J) joint positions [rad; m].
        width: (J,) play widths ``r`` [rad; m], positive.
        follower: (J,) follower ``z`` after the sample before the segment (the state of a
            stream that continues); None starts at the segment's first position.
    Returns:
        (T, J) normalised outputs ``p`` in [-1, 1] and the (J,) follower after the last sample.
    Raises:
        DataError: mismatched shapes or a width that is not positive.
    """
    q = np.asarray(position, dtype=np.float64)
    r = np.asarray(width, dtype=np.float64)
    if q.ndim != 2 or r.shape != (q.shape[1],) or not np.all(r > 0):
        raise DataError(f"play needs (T, J) positions and J positive widths, got {q.shape} "
                        f"and {r}")
    if len(q) == 0:
        return np.zeros_like(q), (np.array(follower, dtype=np.float64) if follower is not None
                                  else np.zeros(q.shape[1]))
    z = q[0].copy() if follower is None else np.array(follower, dtype=np.float64)
    if z.shape != r.shape:
        raise DataError(f"follower must have shape {r.shape}, got {z.shape}")
    out = np.empty_like(q)
    lo, hi = q - r, q + r
    for k in range(len(q)):                  # a recursion: one cheap step per sample
        z = np.minimum(np.maximum(z, lo[k]), hi[k])
        out[k] = z
    return (q - out) / r, z


def play_step(position: np.ndarray, width: np.ndarray, follower: np.ndarray,
              started: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One sample of ``B`` streams: (B, J) positions, (J,) widths, (B, J) followers and (B,)
    whether each stream has a follower yet -> (B, J) outputs and the new (B, J) followers."""
    q = np.asarray(position, dtype=np.float64)
    z = np.where(np.asarray(started, dtype=bool)[:, None],
                 np.minimum(np.maximum(follower, q - width), q + width), q)
    return (q - z) / width, z
