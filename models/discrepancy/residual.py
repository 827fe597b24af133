"""Find: where the model and the measurement disagree.

Per joint: RMS of the residual (measured minus model torque) against a noise floor; where in
state space (position, speed, direction of motion) and in time the residual concentrates;
whiteness (Ljung-Box, statsmodels) and correlation with the inputs.

Noise floor per joint [N m; N]: the larger of
* the white-noise level of the residual, ``1.4826 MAD(diff r) / sqrt(2)`` (a first difference
  removes anything smooth; the median ignores the sparse jumps at velocity reversals), and
* the model's own error floor, the held-out RMS its identification left
  (``inertial_delta.identified_rms``), when the model records it: a model identified on
  one recording cannot be expected to do better on the next.
"""

from __future__ import annotations

import numpy as np
from statsmodels.stats.diagnostic import acorr_ljungbox

#: A joint disagrees when its residual RMS exceeds this multiple of its noise floor.
DISAGREE_RATIO = 1.25
LJUNG_BOX_LAG = 20


def white_noise_level(residual: np.ndarray) -> np.ndarray:
    """Robust white-noise standard deviation per joint (6,) from first differences."""
    d = np.diff(residual, axis=0)
    mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(2.0)


def model_floor(model) -> np.ndarray:
    """Identification error the model file records (6,), zeros if none."""
    out = np.zeros(6)
    for effect in model.effects.values():
        if effect.name == "inertial_delta":
            out = np.maximum(out, np.asarray(effect.params.identified_rms, float))
    return out


def noise_floor(residual: np.ndarray, model) -> np.ndarray:
    """Per-joint noise floor (6,) (module docstring); at least 1e-9."""
    return np.maximum(np.maximum(white_noise_level(residual), model_floor(model)), 1e-9)


def _share(energy: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(fraction of residual energy, fraction of samples) inside ``mask``."""
    total = energy.sum()
    return (float(energy[mask].sum() / total) if total > 0 else 0.0, float(mask.mean()))


def locate(t: np.ndarray, q: np.ndarray, dq: np.ndarray, r: np.ndarray) -> dict:
    """Where one joint's residual ``r`` (N,) concentrates.

    Returns a dict with, per partition (speed quintile, position tercile, direction, time
    decile), the region with the highest energy share per sample share, the direction
    asymmetry (mean residual moving positive minus moving negative, over RMS), and a
    one-line ``summary``.
    """
    energy = r**2
    regions = []
    speed = np.abs(dq)
    cuts = np.quantile(speed, [0.2, 0.8])
    regions.append(("low speed (|dq| <= %.3g)" % cuts[0], speed <= cuts[0]))
    regions.append(("high speed (|dq| >= %.3g)" % cuts[1], speed >= cuts[1]))
    pcuts = np.quantile(q, [1 / 3, 2 / 3])
    regions.append(("low position (q <= %.3g)" % pcuts[0], q <= pcuts[0]))
    regions.append(("high position (q >= %.3g)" % pcuts[1], q >= pcuts[1]))
    regions.append(("moving positive", dq > 0))
    regions.append(("moving negative", dq < 0))
    edges = np.linspace(t[0], t[-1], 11)
    for a, b in zip(edges[:-1], edges[1:]):
        regions.append((f"t {a:.1f}-{b:.1f} s", (t >= a) & (t <= b)))
    scored = []
    for label, mask in regions:
        if mask.sum() < 10:
            continue
        e, s = _share(energy, mask)
        scored.append({"region": label, "energy_share": e, "sample_share": s,
                       "concentration": e / s if s > 0 else 0.0})
    scored.sort(key=lambda d: -d["concentration"])
    rms = float(np.sqrt(np.mean(energy))) or 1.0
    pos, neg = dq > 0, dq < 0
    asym = float((r[pos].mean() if pos.any() else 0.0) - (r[neg].mean() if neg.any() else 0.0)) / rms
    top = scored[0] if scored else {"region": "nowhere", "energy_share": 0.0, "sample_share": 0.0,
                                     "concentration": 0.0}
    parts = [f"{top['region']}: {100 * top['energy_share']:.0f}% of the residual energy in "
             f"{100 * top['sample_share']:.0f}% of the samples"]
    if abs(asym) > 0.5:
        parts.append(f"direction-dependent (mean moving + minus moving - = {asym:+.2f} RMS: "
                     "friction-like)")
    return {"summary": "; ".join(parts), "regions": scored[:4], "direction_asymmetry": asym}


def whiteness(r: np.ndarray) -> dict:
    """Lag-1 autocorrelation and the Ljung-Box p-value at lag 20 of one residual (N,)."""
    r = r - r.mean()
    denom = float(r @ r)
    lag1 = float(r[1:] @ r[:-1] / denom) if denom > 0 else 0.0
    lb = acorr_ljungbox(r, lags=[LJUNG_BOX_LAG], return_df=True)
    return {"lag1_autocorrelation": lag1, "ljung_box_p": float(lb["lb_pvalue"].iloc[0])}


def input_correlation(t, q, dq, ddq, r) -> dict:
    """Pearson correlation of one joint's residual with its own inputs and time."""
    out = {}
    for name, x in (("position", q), ("velocity", dq), ("direction", np.sign(dq)),
                    ("acceleration", ddq), ("time", t)):
        sx, sr = np.std(x), np.std(r)
        out[name] = float(np.mean((x - x.mean()) * (r - r.mean())) / (sx * sr)) if sx > 0 and sr > 0 else 0.0
    return out


def find(t, q, dq, ddq, residual, floor) -> list[dict]:
    """Per-joint findings (list of 6 dicts, joints numbered from 1)."""
    rmse = np.sqrt(np.mean(residual**2, axis=0))
    out = []
    for j in range(6):
        where = locate(t, q[:, j], dq[:, j], residual[:, j])
        out.append({
            "joint": j + 1, "rmse": float(rmse[j]), "noise_floor": float(floor[j]),
            "ratio": float(rmse[j] / floor[j]), "disagrees": bool(rmse[j] > DISAGREE_RATIO * floor[j]),
            "where": where["summary"], "where_detail": where,
            "whiteness": whiteness(residual[:, j]),
            "correlation": input_correlation(t, q[:, j], dq[:, j], ddq[:, j], residual[:, j]),
        })
    return out
