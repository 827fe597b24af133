"""Cannula seal friction: a LuGre bristle model plus a stick-slip rubber lip.

The trocar's seal grips the instrument shaft, so it resists insertion (joint 3, force [N])
and tool roll (joint 4, torque [N m]); it does nothing to yaw, pitch or the wrist. The
estimator's step 2 learns this force, and the simulator needs it to show what a seal does.

Published magnitudes (van den Dobbelsteen, Schooleman and Dankelman, "Friction dynamics of
trocars", Surg Endosc 21:1338, 2007: six trocars, a 5 mm grasper): sliding friction 0.25 to
3.0 N depending on trocar, velocity and direction; fluctuations of 0.2 to 2.5 N when motion
starts or reverses, which they attribute to deformation of the rubber and silicone seal parts.
Alazmani et al. (Proc IMechE H 229:271, 2015) see stick-slip in dry seals (gone with
lubrication) and higher friction on retraction than on insertion.

Model, per sealed joint: LuGre bristles (Canudas de Wit, Olsson, Astrom and Lischinsky, IEEE
TAC 40:419, 1995), whose presliding gives the hysteresis of force against position and a
breakaway spike at every start or reversal, plus a rubber lip that sticks to the shaft at low
speed and slips back (a sawtooth that vanishes above a critical velocity). The equations and
assumptions are at :class:`SealFriction`, the defaults and their sources at
:class:`SealParams` (:func:`seal_force` computes the force).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field, field_validator

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.physics.effects.base import Effect, EffectParams, Motion, register, zeros

#: Columns the seal acts on: insertion [m, N] and tool roll [rad, N m].
SEALED_JOINTS = (2, 3)
#: Parameters that must be > 0 (the others must be >= 0).
POSITIVE = frozenset({"vs", "sigma0", "lip_stiffness", "lip_velocity"})
#: Steps per chunk: bounds the memory of the Python float lists and numpy temporaries.
_CHUNK = 1 << 16


def _pair(description: str, insertion: float, roll: float):
    return Field(default=(insertion, roll), description=description + " (insertion, roll)")


class SealParams(EffectParams):
    """Seal parameters, each a pair ``(insertion [N, m units], roll [N m, rad units])``.

    Defaults (insertion): fc 1.0 N and fs_excess 0.6 N, mid-range of the published values; vs 5
    mm/s; sigma0 5e4 N/m, so the bristle deflects ~30 um at breakaway and a slow reversal (<
    ~0.05 m/s^2) develops most of the spike, a sharp one less of it; sigma1 5 N s/m, below 4
    sigma2 fc / fs_excess = 13 N s/m, the bound under which the map v -> F stays passive as we
    recall it from Barabanov and Ortega (IEEE TAC 45:830, 2000; not re-derived); sigma2 2 N s/m;
    lip sawtooth 0.15 N at 3e3 N/m (teeth of 50 um at rest, ~7 Hz at 0.3 mm/s), gone above 2
    mm/s. Roll defaults are the insertion values moved to a shaft of radius ``r = 4.2 mm``:
    forces times ``r``, stiffnesses and damping times ``r^2``, velocities divided by ``r``.
    """

    fc: tuple[float, float] = _pair("Coulomb (sliding) level [N; N m]", 1.0, 0.004)
    fs_excess: tuple[float, float] = _pair(
        "static excess over Coulomb, Fs - Fc: the breakaway spike [N; N m]", 0.6, 0.0025)
    vs: tuple[float, float] = _pair("Stribeck velocity [m/s; rad/s]", 0.005, 1.2)
    sigma0: tuple[float, float] = _pair("bristle (presliding) stiffness [N/m; N m/rad]",
                                        5.0e4, 0.88)
    sigma1: tuple[float, float] = _pair("bristle damping [N s/m; N m s/rad]", 5.0, 9.0e-5)
    sigma2: tuple[float, float] = _pair("viscous coefficient [N s/m; N m s/rad]", 2.0, 3.5e-5)
    lip_amplitude: tuple[float, float] = _pair(
        "stick-slip sawtooth height at rest, 0 to disable [N; N m]", 0.15, 6.0e-4)
    lip_stiffness: tuple[float, float] = _pair("lip stiffness while stuck [N/m; N m/rad]",
                                               3.0e3, 0.053)
    lip_velocity: tuple[float, float] = _pair(
        "speed above which the lip slides continuously [m/s; rad/s]", 0.002, 0.5)

    @field_validator("*")
    @classmethod
    def _in_range(cls, value, info):
        low = "> 0" if info.field_name in POSITIVE else ">= 0"
        for v in value:
            if not math.isfinite(v) or v < 0 or (v == 0 and info.field_name in POSITIVE):
                raise ValueError(f"{info.field_name} must be finite and {low}, got {value}")
        return value


def _levels(name: str, value, n: int) -> np.ndarray:
    """A parameter as an (n,) array; raises ConfigError if out of range or mis-shaped."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim > 1 or (arr.ndim == 1 and arr.shape[0] != n):
        raise ConfigError(f"seal parameter {name!r}: expected a scalar or shape ({n},), "
                          f"got {arr.shape}")
    bad = ~np.isfinite(arr) | (arr <= 0 if name in POSITIVE else arr < 0)
    if np.any(bad):
        low = "> 0" if name in POSITIVE else ">= 0"
        raise ConfigError(f"seal parameter {name!r} must be finite and {low}, "
                          f"got {np.asarray(arr)[bad].ravel()[:3]}")
    return np.broadcast_to(arr, (n,))


def _bristle_states(decay: list[float], drive: list[float], z: float) -> list[float]:
    """``z[k] = decay[k] z[k-1] + drive[k]`` from ``z[-1] = z``."""
    zs: list[float] = []
    append = zs.append
    for e, b in zip(decay, drive):
        z = e * z + b
        append(z)
    return zs


def _lip_states(dx: list[float], limit: list[float], y: float) -> list[float]:
    """Lip deflection from ``y``: follows ``dx`` while stuck, snaps to 0 past ``+-limit``."""
    ys: list[float] = []
    append = ys.append
    for d, lim in zip(dx, limit):
        y += d
        if y > lim:
            y -= lim  # slipped at +lim, stuck again for the rest of the step
            if y > lim:
                y = 0.0
        elif y < -lim:
            y += lim
            if y < -lim:
                y = 0.0
        append(y)
    return ys


def seal_force(t, x, v, *, fc, fs_excess, vs, sigma0, sigma1, sigma2,
               lip_amplitude, lip_stiffness, lip_velocity) -> np.ndarray:
    """The force the drive supplies against one sealed joint's seal, from rest.

    Args:
        t: (N,) times [s], non-decreasing (a repeated time is a zero step).
        x: (N,) joint position [m or rad].
        v: (N,) joint velocity [m/s or rad/s].
        fc, fs_excess, vs, sigma0, sigma1, sigma2, lip_amplitude, lip_stiffness,
            lip_velocity: scalars or (N,) arrays (a value per step), units of
            :class:`SealParams`.

    Returns:
        (N,) force [N] or torque [N m].

    Raises:
        DataError: shapes of ``t``, ``x``, ``v`` differ or ``t`` decreases.
        ConfigError: a parameter is mis-shaped, negative, or zero where it must be > 0.
    """
    t, x, v = (np.asarray(a, dtype=np.float64) for a in (t, x, v))
    if t.ndim != 1 or x.shape != t.shape or v.shape != t.shape:
        raise DataError(f"t, x, v must share one (N,) shape, got {t.shape}, {x.shape}, {v.shape}")
    n = t.shape[0]
    given = dict(fc=fc, fs_excess=fs_excess, vs=vs, sigma0=sigma0, sigma1=sigma1,
                 sigma2=sigma2, lip_amplitude=lip_amplitude, lip_stiffness=lip_stiffness,
                 lip_velocity=lip_velocity)
    p = {key: _levels(key, value, n) for key, value in given.items()}
    if n > 1 and np.any(np.diff(t) < 0):
        raise DataError("t must be non-decreasing")
    bristles = bool(np.any(p["fc"] + p["fs_excess"] > 0))
    lip = bool(np.any(p["lip_amplitude"] > 0))
    force = np.empty(n)
    z = y = 0.0                                    # state at rest
    for start in range(0, n, _CHUNK):
        # Each chunk also sees the previous sample, for its first step's increments.
        s = slice(start, min(start + _CHUNK, n))
        prev = max(start - 1, 0)
        dt = t[s] - np.concatenate((t[prev:prev + 1], t[s][:-1]))
        dx = x[s] - np.concatenate((x[prev:prev + 1], x[s][:-1]))   # (M,) over the step to k
        v_step = np.divide(dx, dt, out=np.zeros_like(dx), where=dt > 0)
        c = {key: arr[s] for key, arr in p.items()}
        force[s] = c["sigma2"] * v[s]
        if bristles:
            zs, z = _bristle_chunk(dx, v_step, v[s], c, z)
            force[s] += zs
        if lip:
            limit = c["lip_amplitude"] / c["lip_stiffness"] * np.clip(
                1.0 - np.abs(v_step) / c["lip_velocity"], 0.0, None)
            ys = _lip_states(dx.tolist(), limit.tolist(), y)
            y = ys[-1]
            force[s] += c["lip_stiffness"] * np.asarray(ys)
    return force


def _bristle_chunk(dx, v_step, v, c, z0: float) -> tuple[np.ndarray, float]:
    """LuGre force ``sigma0 z + sigma1 dz/dt`` (M,) over one chunk, and the final ``z``."""
    fc, fs_excess, vs, sigma0 = c["fc"], c["fs_excess"], c["vs"], c["sigma0"]
    g_step = fc + fs_excess * np.exp(-np.square(v_step / vs))
    with np.errstate(divide="ignore", invalid="ignore"):
        # g = 0 (no friction in this step): the bristle releases at once.
        rate = np.where(g_step > 0, sigma0 * np.abs(dx) / g_step, np.inf)
    decay = np.exp(-rate)
    drive = (1.0 - decay) * np.sign(dx) * g_step / sigma0
    z = np.asarray(_bristle_states(decay.tolist(), drive.tolist(), z0))
    g = fc + fs_excess * np.exp(-np.square(v / vs))
    dzdt = v - np.divide(sigma0 * np.abs(v) * z, g, out=np.zeros_like(z), where=g > 0)
    dzdt[g <= 0] = 0.0
    return sigma0 * z + c["sigma1"] * dzdt, float(z[-1])


@register
class SealFriction(Effect):
    """Cannula seal friction on insertion and roll.

    Per sealed joint, with ``x`` the joint position [m; rad] and ``v`` its velocity:

    * **LuGre bristles** (Canudas de Wit, Olsson, Astrom and Lischinsky, IEEE TAC 40:419, 1995):
      ``dz/dt = v - sigma0 |v| z / g(v)``, ``g(v) = fc + fs_excess exp(-(v/vs)^2)``,
      ``F_b = sigma0 z + sigma1 dz/dt + sigma2 v``. Presliding (the bristle deflects like a spring
      before the seal slides) gives the hysteresis loop of force against position; ``g`` near
      zero velocity is the static level ``fc + fs_excess``, so every reversal or start passes
      through a breakaway spike before friction settles to ``fc``.
    * **Stick-slip lip**: at low speed the rubber lip sticks to the shaft and deflects with it,
      ``F_l = lip_stiffness * y`` with ``dy/dt = v``, until ``|F_l|`` reaches the break level
      ``lip_amplitude * (1 - |v| / lip_velocity)``; it then slips back to rest (``y = 0``) and
      sticks again: a sawtooth of height up to ``lip_amplitude`` whose teeth shrink with speed and
      vanish at ``lip_velocity`` (the classic critical velocity of stick-slip), above which the lip
      slides continuously and carries no force of its own.

    The drive supplies ``F = F_b + F_l`` (sign of the velocity while sliding).

    Assumptions:

    * The motion is prescribed (stiff position servo), so the seal cannot feed back on it.
      Stick-slip normally emerges from falling friction plus a compliance; with the motion
      imposed it cannot emerge from LuGre alone, hence the lip state, added in parallel (a
      phenomenological sawtooth, not a series compliance).
    * Insertion and roll have independent bristles and lips; a real seal shares one contact, so a
      combined helical slide would break away earlier than this model says.
    * Symmetric in direction (no insertion/retraction asymmetry), independent of insertion depth,
      of insufflation pressure and of lateral load from the body wall.
    * Each step ``t[k-1] -> t[k]`` is integrated exactly for a velocity held at
      ``(x[k] - x[k-1]) / (t[k] - t[k-1])``: ``z`` relaxes exponentially towards
      ``sign(v) g(v) / sigma0`` with exponent ``sigma0 |dx| / g`` (stable for any stiffness, no
      fixed step assumed). The state starts at rest: ``z = 0``, ``y = 0``.

    Overrides (e.g. from ``drift``) of a parameter may have shape ``(2,)`` (constant),
    ``(N, 2)`` (a pair per step) or ``(N,)`` (one value per step for both joints; when
    ``N == 2`` a 1-D override is read as a pair).
    """

    name = "seal_friction"
    Params = SealParams
    stateful = True

    def _pairs(self, key: str, overrides, n: int) -> np.ndarray:
        """Parameter ``key`` as an (n, 2) or (2,) array."""
        arr = self.param(key, overrides)
        if arr.ndim == 0 or arr.shape == (2,) or arr.shape == (n, 2):
            return arr * np.ones(2) if arr.ndim == 0 else arr
        if arr.shape == (n,):
            return arr[:, None] * np.ones(2)
        raise ConfigError(f"effect {self.name!r}: override of {key!r} must have shape (2,), "
                          f"({n}, 2) or ({n},), got {arr.shape}")

    def torque(self, motion: Motion, overrides=None) -> np.ndarray:
        n = len(motion)
        pairs = {key: self._pairs(key, overrides, n) for key in SealParams.model_fields}
        tau = zeros(motion)
        for col, joint in enumerate(SEALED_JOINTS):
            p = {key: arr[..., col] for key, arr in pairs.items()}
            if not any(np.any(p[k] > 0) for k in ("fc", "fs_excess", "sigma2", "lip_amplitude")):
                continue
            tau[:, joint] = seal_force(motion.t, motion.q[:, joint], motion.dq[:, joint], **p)
        return tau
