"""Candidate effects as groups of physically meaningful regressor columns.

The discrepancy workflow names the effect a model lacks by regressing its residual on what
each missing effect would add. Each candidate is an effect of the library written as columns
``X`` (N, 6, k): the joint torque [N m; N on insertion] per unit of each of its parameters, so
the residual ``r ~ X beta`` is linear and ``beta`` maps back to the effect's parameters
(``Candidate.to_params``); shapes that are not linear in a parameter (Stribeck velocities,
the seal's presliding travel and static ratio) are profiled over a grid. Columns are built on
the *measured* motion (encoder positions, zero-phase velocity, smoothed acceleration). The
effects and their columns are listed at :func:`build_candidates`.

Not candidates (:data:`NOT_CANDIDATES`): ``external_contact`` (a tip wrench during contact
episodes; free-motion data has none, and its anchor and timing are not functions of the
motion) and ``inertial_delta`` (re-identifying the rigid body would absorb a payload or a
spring into the base parameters: the workflow keeps the given model fixed and explains what
it leaves).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from wrenchd.models.physics.effects.base import Motion
from wrenchd.models.physics.effects.body_wall import BodyWall
from wrenchd.models.physics.effects.coupling import CableCoupling
from wrenchd.models.physics.effects.friction import SIGN_SMOOTHING, StribeckParams, smooth_sign
from wrenchd.models.physics.effects.payload import PayloadParams, point_mass_parameters
from wrenchd.models.physics.effects.seal import SEALED_JOINTS, SealParams
from wrenchd.models.physics.model import PhysicsModel

#: Parameter a drift of each effect scales (the effect's level).
DRIFT_PARAM = {
    "coulomb_friction": "fc", "viscous_friction": "fv", "stribeck_friction": "fs",
    "joint_offset": "offset", "spring": "stiffness", "seal_friction": "fc",
    "cable_coupling": "motor_fc", "payload_mass": "mass_kg", "body_wall": "pressure_mmhg",
}
#: Payload hypotheses: carrying link -> point-mass position in its DH frame [m]: the point a
#: one-column site holds, the nominal lever arm of a first-moment site
#: (:data:`FIRST_MOMENT_SITES`); a free-position site fits its own (see :func:`_payload`).
#: The yaw link (link 1) is no site: its first moments act on yaw alone, one of the two is
#: also the parallelogram's, and the other one, offered as a candidate, took the yaw part of
#: the real WPI parallelogram loads (a link that translates, which no serial-chain site
#: represents exactly) and split each into two payloads. A yaw-link load is named on link 2.
PAYLOAD_SITES = {2: tuple(PayloadParams().position_m), 3: (0.0, 0.0, 0.0), 6: (0.0, 0.0, 0.0)}
#: Sites whose origin does not move (links turning about the RCM): a mass there acts only
#: through its first moment ``m c``, and the mass is read at the nominal lever arm.
FIRST_MOMENT_SITES = (2,)
#: Sites whose point mass is fitted with its position free: mass and first moments, four
#: columns (the insertion stage: its origin moves with the insertion, so the mass itself acts
#: on every joint it moves, and on the insertion joint through gravity along the tool axis).
FREE_POSITION_SITES = (3,)
#: Joints a spring candidate may act on (0-based): the insertion (a cable or hose pulled
#: along the tool axis) and the instrument's cable-driven roll and wrist (cable preload; WPI's
#: identified K). Yaw and pitch carry no spring, and over their +-0.8 rad a spring ``k q + c``
#: and the gravity of a mass (``~ sin q``) are collinear (R^2 > 0.99 on the WPI trajectory), so
#: one could not be told from the other there; on the insertion gravity goes with the pitch
#: and yaw angles, not with the insertion, and a spring can be told from a load.
SPRING_JOINTS = (2, 3, 4, 5)
#: Effects whose columns are one parameter per joint, counted only where supported.
PER_COLUMN = ("coulomb_friction", "viscous_friction", "stribeck_friction", "joint_offset")
#: Stribeck velocities tried, as multiples of the library default per joint.
STRIBECK_GRID = tuple(float(v) for v in np.geomspace(0.25, 4.0, 13))
#: Seal presliding travels tried, as multiples of the library default.
PRESLIDING_GRID = tuple(float(v) for v in np.geomspace(0.25, 8.0, 9))
#: Seal static-excess ratios ``fs_excess / (fc + fs_excess)`` tried (library default 0.375).
SEAL_RATIO_GRID = tuple(float(v) for v in np.linspace(0.0, 0.6, 9))
#: Effects never offered as candidates, and why (reported).
NOT_CANDIDATES = {
    "external_contact": "a tip wrench during contact episodes, not free motion; its anchor "
                        "and timing are not functions of the joint motion",
    "inertial_delta": "the identified rigid body itself; refitting it would absorb payloads "
                      "and springs, so the given model's rigid body stays fixed",
}


@dataclass
class Candidate:
    """One candidate effect: its columns and how coefficients become model-file params.

    Attributes:
        name: effect vocabulary word.
        label: unique label (``payload_mass@link2``, ``drift:coulomb_friction.fc``).
        columns: (N, 6, k) torque per unit parameter [N m or N per unit].
        names: the k coefficient names.
        to_params: coefficients (k,) -> the effect's parameters to add.
        main: indices of the coefficients that carry the effect's size (for stability).
    """

    name: str
    label: str
    columns: np.ndarray
    names: list[str]
    to_params: Callable[[np.ndarray], dict[str, Any]]
    main: list[int] = field(default_factory=list)
    fixed: dict[str, Any] = field(default_factory=dict)
    #: (coefficient index, the model's current value): physically the sum must be >= 0
    nonneg: list[tuple[int, float]] = field(default_factory=list)
    #: for candidates whose shape is profiled on the residual (Stribeck velocity, seal
    #: travel and static ratio): rebuild on another residual (N, 6)
    rebuild: Callable[[np.ndarray], "Candidate"] | None = None

    def inadmissible(self, beta: np.ndarray, bse: np.ndarray, size: np.ndarray,
                     sigmas: float = 3.0, material: float = 0.2) -> str | None:
        """Why ``beta`` is unphysical, or None if it is not.

        A constrained coefficient fails when its sum with the model's value is negative by
        more than ``sigmas`` standard errors *and* the negative part is material: its torque
        RMS (``size[i]`` per unit coefficient, in noise floors) reaches ``material``.
        """
        bad = [self.names[i] for i, base in self.nonneg
               if base + beta[i] + sigmas * bse[i] < 0 and -(base + beta[i]) * size[i] >= material]
        return f"unphysical sign of {', '.join(bad)}" if bad else None

    @property
    def per_column(self) -> bool:
        """One column per joint, each a separate parameter (:data:`PER_COLUMN`): the
        selection counts only the columns with support."""
        return self.name in PER_COLUMN

    def torque(self, beta: np.ndarray) -> np.ndarray:
        """Effect torque (N, 6) for coefficients ``beta`` (k,)."""
        return self.columns @ beta

    def joints(self) -> np.ndarray:
        """Joints (0-based) any column touches."""
        return np.flatnonzero(np.any(self.columns != 0, axis=(0, 2)))


def _diag(values: np.ndarray, joints) -> np.ndarray:
    """(N, 6, len(joints)) with ``values[:, j]`` on joint j in column i."""
    n = values.shape[0]
    out = np.zeros((n, 6, len(joints)))
    for i, j in enumerate(joints):
        out[:, j, i] = values[:, j]
    return out


def _per_joint(key: str) -> Callable[[np.ndarray], dict[str, Any]]:
    return lambda b: {key: [float(v) for v in b]}


def _stribeck(motion: Motion, residual: np.ndarray, weights: np.ndarray) -> Candidate:
    default_vs = np.asarray(StribeckParams().vs)
    vs = np.empty(6)
    for j in range(6):   # profile vs_j: best single-column fit of joint j's residual
        best = np.inf
        for f in STRIBECK_GRID:
            col = np.exp(-np.square(motion.dq[:, j] / (f * default_vs[j]))) * smooth_sign(motion.dq[:, j])
            denom = col @ col
            ssr = residual[:, j] @ residual[:, j] - (col @ residual[:, j]) ** 2 / denom if denom > 0 else np.inf
            if ssr < best:
                best, vs[j] = ssr, f * default_vs[j]
    cols = _diag(np.exp(-np.square(motion.dq / vs)) * smooth_sign(motion.dq), range(6))
    vs_list = [float(v) for v in vs]
    return Candidate("stribeck_friction", "stribeck_friction", cols,
                     [f"fs{j}" for j in range(1, 7)],
                     lambda b: {"fs": [float(v) for v in b], "vs": vs_list},
                     list(range(6)), {"vs": vs_list})


def _spring(motion: Motion) -> Candidate:
    n = len(motion)
    cols = np.concatenate([_diag(motion.q, SPRING_JOINTS), _diag(np.ones((n, 6)), SPRING_JOINTS)],
                          axis=2)
    m = len(SPRING_JOINTS)

    def to_params(b):
        k, rest = np.zeros(6), np.zeros(6)
        for i, j in enumerate(SPRING_JOINTS):
            k[j] = b[i]
            rest[j] = -b[m + i] / b[i] if abs(b[i]) > 1e-12 else 0.0
        return {"stiffness": [float(v) for v in k], "rest": [float(v) for v in rest]}
    return Candidate("spring", "spring", cols, [f"k{j + 1}" for j in SPRING_JOINTS]
                     + [f"c{j + 1}" for j in SPRING_JOINTS], to_params, list(range(m)))


def bristle_state(x: np.ndarray, v: np.ndarray, z0: float, ratio: float, vs: float) -> np.ndarray:
    """Normalised LuGre bristle force ``F / (fc + fs_excess)`` (N,) of a seal-like contact.

    With ``G = fc + fs_excess``, ``ratio = fs_excess / G`` and ``z0 = G / sigma0`` the
    presliding travel, the LuGre state normalised by ``z0`` relaxes per step towards
    ``sign(dx) g(v) / G``, ``g(v) / G = 1 - ratio + ratio exp(-(v/vs)^2)``, with exponent
    ``|dx| / (z0 g(v) / G)`` (the integration of :mod:`~wrenchd.models.physics.effects.seal`), so the
    bristle force is ``G`` times this column, exactly, for given ``z0``, ``ratio`` and ``vs``.
    """
    dx = np.diff(x, prepend=x[:1])
    level = 1.0 - ratio + ratio * np.exp(-np.square(v / vs))
    decay = np.exp(-np.abs(dx) / (z0 * level)).tolist()
    target = (np.sign(dx) * level).tolist()
    u, out = 0.0, []
    for e, s in zip(decay, target):
        u = s + (u - s) * e
        out.append(u)
    return np.asarray(out)


def _seal(motion: Motion, residual: np.ndarray) -> Candidate:
    """Seal columns: the bristle force per unit level on insertion and roll, and ``dq`` on
    insertion (the roll's viscous term, 3.5e-5 N m s/rad by default, cannot be told from its
    broad Stribeck curve, vs 1.2 rad/s, and stays out).

    The presliding travel ``z0`` (multiples of the library default, :data:`PRESLIDING_GRID`)
    and then the static excess ratio (:data:`SEAL_RATIO_GRID`) are profiled per joint on the
    residual (best fit; coarse to fine: travel at the middle ratio, then the ratio); the coefficients are ``G = fc + fs_excess`` and ``sigma2``.
    """
    d = SealParams()
    cols = np.zeros((len(motion), 6, 3))
    names: list[str] = []
    shape = []
    for i, j in enumerate(SEALED_JOINTS):
        v = motion.dq[:, j]
        default_z0 = (d.fc[i] + d.fs_excess[i]) / d.sigma0[i]          # [m; rad]
        best = (np.inf, None, None)

        def score(f, ratio):
            u = bristle_state(motion.q[:, j], v, f * default_z0, ratio, d.vs[i])
            x = np.column_stack([u, v]) if i == 0 else u[:, None]
            _, ssr, *_ = np.linalg.lstsq(x, residual[:, j], rcond=None)
            return (float(ssr[0]) if ssr.size else np.inf), u
        # coarse to fine: travel at the default ratio, then the ratio at that travel
        for f in PRESLIDING_GRID:
            ssr, u = score(f, SEAL_RATIO_GRID[len(SEAL_RATIO_GRID) // 2])
            if ssr < best[0]:
                best = (ssr, (f * default_z0, SEAL_RATIO_GRID[len(SEAL_RATIO_GRID) // 2]), u)
        f_best = best[1][0] / default_z0
        for ratio in SEAL_RATIO_GRID:
            ssr, u = score(f_best, ratio)
            if ssr < best[0]:
                best = (ssr, (f_best * default_z0, ratio), u)
        shape.append(best[1])
        if i == 0:
            cols[:, j, 0], cols[:, j, 1] = best[2], v
            names += [f"level{j + 1}", f"sigma2_{j + 1}"]
        else:
            cols[:, j, 2] = best[2]
            names.append(f"level{j + 1}")

    def to_params(b):
        out = {"fc": [], "fs_excess": [], "sigma0": [], "sigma2": [float(b[1]), 0.0]}
        for level, (z0, ratio) in zip((b[0], b[2]), shape):
            out["fc"].append(float(level * (1 - ratio)))
            out["fs_excess"].append(float(level * ratio))
            out["sigma0"].append(float(max(level, 1e-9) / z0))
        return out
    return Candidate("seal_friction", "seal_friction", cols, names, to_params, [0, 2],
                     {"presliding_travel": [s[0] for s in shape],
                      "static_ratio": [s[1] for s in shape]})


def _body_wall(motion: Motion) -> Candidate:
    stiff = BodyWall({"k0_n_per_m": 1.0, "k_per_mmhg": 0.0, "damping_ns_per_m": 0.0}).torque(motion)
    damp = BodyWall({"k0_n_per_m": 0.0, "k_per_mmhg": 0.0, "damping_ns_per_m": 1.0}).torque(motion)
    cols = np.stack([stiff, damp], axis=2)
    return Candidate("body_wall", "body_wall", cols, ["k_n_per_m", "damping_ns_per_m"],
                     lambda b: {"k0_n_per_m": float(b[0]), "k_per_mmhg": 0.0,
                                "damping_ns_per_m": float(b[1])}, [0])


def _payload(motion: Motion, regressor: np.ndarray, link: int) -> Candidate:
    """A point mass on ``link``.

    Link 2 (the parallelogram) turns about the RCM, its frame's origin, so a mass there acts
    only through its first moment ``m c``: three columns (the regressor's ``mx, my, mz``)
    whose fit gives the load's direction, and ``mass = |m c| / |c_nominal|`` with the
    nominal lever arm (the library default position, the WPI load's). The insertion stage
    (link 3, :data:`FREE_POSITION_SITES`) moves its origin, so the mass shows apart from its
    first moment: four columns ``m, m c``, giving the mass and ``c = m c / m``. Other sites
    are one column, the point mass per kg at the fixed position. Rotational inertia of the
    point mass (``m |c|^2``, ~6e-3 kg m^2 for 0.2 kg at 0.18 m) is left out of the
    multi-column candidates.
    """
    position = np.asarray(PAYLOAD_SITES[link], float)
    block = regressor[:, :, 10 * (link - 1):10 * link]
    if link in FREE_POSITION_SITES:
        def free_to_params(b):
            mass = float(b[0])
            pos = np.asarray(b[1:4], float) / mass if mass > 1e-6 else position
            return {"mass_kg": mass, "link": link, "position_m": [float(p) for p in pos]}
        return Candidate("payload_mass", f"payload_mass@link{link}", block[:, :, 0:4].copy(),
                         ["mass_kg", "m_cx", "m_cy", "m_cz"], free_to_params, [0],
                         {"link": link}, [(0, 0.0)])
    if link in FIRST_MOMENT_SITES:
        lever = float(np.linalg.norm(position))

        def to_params(b):
            mc = np.asarray(b[:3], float)
            mass = float(np.linalg.norm(mc)) / lever
            pos = (mc / np.linalg.norm(mc) * lever) if mass > 0 else position
            return {"mass_kg": mass, "link": link, "position_m": [float(p) for p in pos]}
        return Candidate("payload_mass", f"payload_mass@link{link}", block[:, :, 1:4].copy(),
                         ["m_cx", "m_cy", "m_cz"], to_params, [0, 1, 2], {"link": link})
    per_kg = block @ point_mass_parameters(1.0, position)              # (N, 6) [N m / kg]
    pos = [float(p) for p in position]
    return Candidate("payload_mass", f"payload_mass@link{link}", per_kg[:, :, None], ["mass_kg"],
                     lambda b: {"mass_kg": float(b[0]), "link": link, "position_m": pos}, [0],
                     {"link": link, "position_m": pos}, [(0, 0.0)])


def _cable(motion: Motion) -> Candidate:
    c = np.asarray(CableCoupling().params.coupling)                  # (2, 2)
    m_vel = motion.dq[:, 4:6] @ c.T                                   # (N, 2) motor velocities
    cols = np.zeros((len(motion), 6, 4))
    for i in range(2):
        cols[:, 4:6, i] = smooth_sign(m_vel[:, i], SIGN_SMOOTHING)[:, None] * c[i][None, :]
        cols[:, 4:6, 2 + i] = m_vel[:, i][:, None] * c[i][None, :]
    coupling = [[float(v) for v in row] for row in c]
    return Candidate("cable_coupling", "cable_coupling", cols,
                     ["motor_fc1", "motor_fc2", "motor_fv1", "motor_fv2"],
                     lambda b: {"coupling": coupling, "motor_fc": [float(b[0]), float(b[1])],
                                "motor_fv": [float(b[2]), float(b[3])]}, [0, 1])


def _drifts(motion: Motion, model: PhysicsModel, floor: np.ndarray) -> list[Candidate]:
    out = []
    hours = (motion.t - motion.t[0]) / 3600.0
    for key, effect in model.effects.items():
        param = DRIFT_PARAM.get(effect.name)
        if param is None:
            continue
        nominal = effect.param(param)
        if not np.any(nominal != 0):
            continue
        eps = 0.1
        dtau = (effect.torque(motion, {param: nominal * (1 + eps)}) - effect.torque(motion)) / eps
        if np.max(np.sqrt(np.mean(dtau**2, axis=0)) / floor) < 0.05:
            continue   # a drift of this effect could not show within this recording
        t0 = float(motion.t[0])
        out.append(Candidate(
            "drift", f"drift:{key}.{param}", (hours[:, None] * dtau)[:, :, None], ["rate_per_hour"],
            lambda b, key=key, param=param, t0=t0: {
                "target": key, "param": param, "kind": "linear",
                "rate_per_hour": float(b[0]), "t_start_s": t0}, [0],
            {"target": key, "param": param}))
    return out


def build_candidates(motion: Motion, model: PhysicsModel, residual: np.ndarray,
                     floor: np.ndarray, regressor: np.ndarray | None = None) -> list[Candidate]:
    """Every candidate effect for this motion and model:

    =====================  ======================================================  ============
    effect                 columns                                                 parameters
    =====================  ======================================================  ============
    coulomb_friction       ``tanh(dq_j / 1e-3)`` on joint j, j = 1..6              fc (6)
    viscous_friction       ``dq_j`` on joint j                                     fv (6)
    stribeck_friction      ``exp(-(dq_j/vs_j)^2) sign(dq_j)``, vs_j profiled       fs (6), vs
    joint_offset           1 on joint j                                            offset (6)
    spring                 ``q_j`` and 1 on insertion, roll, wrist (rest = -c/k)   stiffness, rest
    seal_friction          insertion and roll: LuGre bristle force per unit level   fc + fs_excess,
                           (presliding travel and static ratio profiled), and       sigma2 (insertion);
                           ``dq`` on insertion                                      sigma0 from travel
    body_wall              port stiffness and damping torques, default incision    k, damping
    payload_mass           link 2 (parallelogram): first moments ``m c`` (3        mass_kg,
                           columns); link 3 (insertion stage): ``m`` and ``m c``    position_m
                           (4 columns); link 6 (tip): point mass per kg at its
                           origin
    cable_coupling         ``C^T e_i tanh(m_i / 1e-3)``, ``C^T e_i m_i``, m = C dq   motor_fc, motor_fv
    drift                  ``(t - t0) / 3600 * d tau_E / d log p`` for each effect  rate_per_hour
                           E of the model and its level parameter p
    =====================  ======================================================  ============

    Args:
        motion: measured motion (``ddq`` smoothed).
        model: the model whose residual is being explained (for drift targets).
        residual: (N, 6) measured minus model torque (profiles Stribeck velocities).
        floor: (6,) noise floor per joint (skips drifts too small to see).
        regressor: (N, 6, 60) of the motion, if already computed.
    """
    y = regressor if regressor is not None else motion.robot.regressor(motion.q, motion.dq, motion.ddq)
    weights = 1.0 / floor**2
    n = len(motion)
    cands = [
        Candidate("coulomb_friction", "coulomb_friction",
                  _diag(smooth_sign(motion.dq, SIGN_SMOOTHING), range(6)),
                  [f"fc{j}" for j in range(1, 7)], _per_joint("fc"), list(range(6))),
        Candidate("viscous_friction", "viscous_friction", _diag(motion.dq, range(6)),
                  [f"fv{j}" for j in range(1, 7)], _per_joint("fv"), list(range(6))),
        _stribeck(motion, residual, weights),
        Candidate("joint_offset", "joint_offset", _diag(np.ones((n, 6)), range(6)),
                  [f"offset{j}" for j in range(1, 7)], _per_joint("offset"), list(range(6))),
        _spring(motion),
        _seal(motion, residual),
        _body_wall(motion),
        *(_payload(motion, y, link) for link in PAYLOAD_SITES),
        _cable(motion),
        *_drifts(motion, model, floor),
    ]
    for cand in cands:
        if not cand.nonneg:
            cand.nonneg = _sign_constraints(cand, model)
    for cand in cands:
        if cand.name in ("stribeck_friction", "seal_friction"):
            cand.rebuild = _rebuilder(cand.name, motion, model, weights)
    return cands


def _rebuilder(name: str, motion: Motion, model: PhysicsModel, weights: np.ndarray):
    def rebuild(residual: np.ndarray) -> Candidate:
        cand = _stribeck(motion, residual, weights) if name == "stribeck_friction" \
            else _seal(motion, residual)
        cand.nonneg = _sign_constraints(cand, model)
        cand.rebuild = rebuild
        return cand
    return rebuild


def _current(model: PhysicsModel, name: str, key: str, size: int) -> np.ndarray:
    """Sum over the model's enabled ``name`` effects of parameter ``key`` (zeros if none)."""
    out = np.zeros(size)
    for effect in model.effects.values():
        if effect.name == name:
            out = out + np.broadcast_to(np.asarray(effect.param(key), float), (size,))
    return out


def _sign_constraints(cand: Candidate, model: PhysicsModel) -> list[tuple[int, float]]:
    """Coefficients whose sum with the model's value must stay >= 0 (dissipation, mass)."""
    name = cand.name
    if name in ("coulomb_friction", "viscous_friction", "stribeck_friction"):
        key = {"coulomb_friction": "fc", "viscous_friction": "fv", "stribeck_friction": "fs"}[name]
        cur = _current(model, name, key, 6)
        return [(j, float(cur[j])) for j in range(6)]
    if name == "seal_friction":
        level = _current(model, name, "fc", 2) + _current(model, name, "fs_excess", 2)
        s2 = _current(model, name, "sigma2", 2)
        return [(0, float(level[0])), (1, float(s2[0])), (2, float(level[1]))]
    if name == "body_wall":
        k = sum(float(e.params.k0_n_per_m + e.params.k_per_mmhg * e.params.pressure_mmhg)
                for e in model.effects.values() if e.name == name)
        d = float(_current(model, name, "damping_ns_per_m", 1)[0])
        return [(0, k), (1, d)]
    if name == "cable_coupling":
        fc, fv = _current(model, name, "motor_fc", 2), _current(model, name, "motor_fv", 2)
        return [(0, float(fc[0])), (1, float(fc[1])), (2, float(fv[0])), (3, float(fv[1]))]
    if name == "spring":
        k = _current(model, name, "stiffness", 6)
        return [(i, float(k[j])) for i, j in enumerate(SPRING_JOINTS)]
    return []
