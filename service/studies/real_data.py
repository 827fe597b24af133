"""Step 1 on real dVRK recordings: the paper's LSTM, least squares and the hybrid side by side.

Models (``--models`` of ``wrenchd real-data``), all trained on the same free-motion samples:

* ``lstm``: the paper's per-group LSTMs (:func:`~wrenchd.models.estimator.free_space_training.
  fit_free_space`, a shortened recipe, the last 20 % of each training series picks the epoch);
* ``ls``: rigid body + friction by least squares with the centred (offline) acceleration, in
  two column sets: the first baseline (``sign`` Coulomb) and the improved one (``tanh``
  Coulomb, a spring per joint), :mod:`wrenchd.models.physics.least_squares`;
* ``hybrid``: :mod:`wrenchd.models.estimator.hybrid`, causal; its physics part alone is
  reported too (``ls_causal``), and its residual without the trust gate;
* ``lstm-residual``: the hybrid's physics plus the paper's LSTMs trained on its residual,
  behind the same trust gate (the network choice, compared).

With ``lookahead_ms``, the hybrid is fitted again for each look-ahead, its acceleration
filter reading that far past the estimated sample (``hybrid_lookahead_<ms>ms``): what an
estimate published that much later would gain over the causal one. Such a model does not
stream; it measures a latency the service does not have.

Newtons at the tip and known loads: :mod:`wrenchd.service.studies.newtons`.

Besides the RMSE per joint: the share of test samples inside the hybrid's training coverage
and the errors there, the test recording's run-to-run repeatability (its trajectories repeat:
the torque difference at the same phase one period apart, over sqrt 2, is the noise of one
sample), and the external torque each model implies on recordings with added loads.
"""

from __future__ import annotations

import re
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.series import JointStates

if TYPE_CHECKING:
    from wrenchd.service.studies.newtons import KnownLoad

MODELS = ("lstm", "ls", "hybrid", "lstm-residual")
#: Shortened step-1 recipe for 30 s recordings (the paper trains 1000 epochs on far more).
REAL_RECIPE = {"epochs": 150, "lr": 3e-3, "lr_halving_epochs": 50, "window": 50,
               "lane_windows": 4, "batch_size": 8, "patience": 60}
#: Chain link whose gravity columns describe a load on the parallelogram (pitch link), and
#: its first-moment columns (m c_x, m c_y, m c_z) in the regressor.
LOAD_COLUMNS = slice(11, 14)
LOAD_JOINTS = (0, 1)


@dataclass(frozen=True)
class Source:
    """A recording, or a time window ``[start_s, stop_s)`` of it (seconds from its start)."""

    path: str
    start_s: float | None = None
    stop_s: float | None = None

    @classmethod
    def parse(cls, spec: str) -> Source:
        """``path`` or ``path:start_s:stop_s`` (either bound may be empty)."""
        m = re.fullmatch(r"(.+?)(?::([0-9.]*):([0-9.]*))?", spec)
        path, a, b = m.group(1), m.group(2), m.group(3)
        try:
            start, stop = (float(a) if a else None), (float(b) if b else None)
        except ValueError:
            raise ConfigError(f"{spec!r}: expected path or path:start_s:stop_s") from None
        if start is not None and stop is not None and not stop > start:
            raise ConfigError(f"{spec!r}: the window must end after it starts")
        return cls(path, start, stop)

    @property
    def label(self) -> str:
        if self.start_s is None and self.stop_s is None:
            return self.path
        return f"{self.path}:{self.start_s or 0:g}:{'' if self.stop_s is None else f'{self.stop_s:g}'}"

    def load(self) -> JointStates:
        from wrenchd.adapters.csv_psm import read_wpi_csv

        js, _ = read_wpi_csv(self.path)
        t = js.t - js.t[0]
        keep = np.ones(len(t), dtype=bool)
        if self.start_s is not None:
            keep &= t >= self.start_s - 1e-9
        if self.stop_s is not None:
            keep &= t < self.stop_s - 1e-9
        if keep.sum() < 50:
            raise DataError(f"{self.label}: fewer than 50 samples in the window")
        return JointStates(js.t[keep], js.position[keep], js.velocity[keep], js.effort[keep])


def lookahead_key(ms: float) -> str:
    """Result key of the hybrid whose acceleration reads ``ms`` milliseconds ahead."""
    return f"hybrid_lookahead_{ms:g}ms"


def rmse(pred: np.ndarray, target: np.ndarray) -> list[float]:
    """Per-joint RMS error [N m; N]."""
    return np.sqrt(np.mean((pred - target) ** 2, axis=0)).tolist()


def features(js: JointStates) -> np.ndarray:
    return np.concatenate([js.position, js.velocity], axis=1)


def offline_acceleration(js: JointStates) -> np.ndarray:
    """Centred Savitzky-Golay acceleration (N, 6) of a gap-free series."""
    from wrenchd.models.physics.least_squares import smoothed_acceleration

    return smoothed_acceleration(js.velocity, float(np.median(np.diff(js.t))))


def repeatability(js: JointStates, min_period_s: float = 2.0,
                  max_position_rms: float = 0.01) -> dict[str, Any] | None:
    """Run-to-run noise floor of a periodic recording, or None if it does not repeat.

    The period is the shift (at least ``min_period_s``, leaving as much overlap) that best
    matches the positions of joints 1-3; the floor is the RMS torque difference one period
    apart over sqrt 2 (the noise of one sample), and ``previous_periods_rmse`` the error of
    predicting each sample by the mean of the samples whole periods before it (the best a
    model of the trajectory's own past can do).
    """
    dt = float(np.median(np.diff(js.t)))
    lo, hi = int(round(min_period_s / dt)), len(js) - int(round(min_period_s / dt))
    if hi <= lo:
        return None
    q = js.position[:, :3]
    errs = np.array([np.sqrt(np.mean((q[p:] - q[:-p]) ** 2)) for p in range(lo, hi)])
    # The shortest shift nearly as good as the best (multiples of the period match too).
    k = int(np.flatnonzero(errs <= 2.0 * errs.min() + 1e-4)[0])
    while k + 1 < len(errs) and errs[k + 1] < errs[k]:
        k += 1
    p = lo + k
    if errs[k] > max_position_rms:
        return None
    tau = js.effort
    floor = np.sqrt(np.mean((tau[p:] - tau[:-p]) ** 2, axis=0)) / np.sqrt(2.0)
    prev = np.zeros_like(tau[p:])
    count = np.zeros((len(tau) - p, 1))
    for n in range(1, len(tau) // p + 1):
        idx = np.arange(p, len(tau)) - n * p
        ok = idx >= 0
        prev[ok] += tau[idx[ok]]
        count[ok] += 1
    return {"period_s": p * dt, "position_rms": float(errs[k]),
            "floor_rmse": floor.tolist(),
            "previous_periods_rmse": rmse(prev / count, tau[p:])}


def load_moment(external: np.ndarray, q: np.ndarray, offsets: bool) -> np.ndarray:
    """Least-squares first moment (3,) [kg m] of a point load on the pitch link (chain link 2)
    that explains the (N, 6) external torques of joints 1 and 2 through gravity; with
    ``offsets`` a constant torque per joint is fitted beside it (and dropped)."""
    from wrenchd.models.physics.dynamics import RigidBodyModel

    zeros = np.zeros_like(q)
    cols = RigidBodyModel().regressor(q, zeros, zeros)[:, LOAD_JOINTS, LOAD_COLUMNS]
    if offsets:
        eye = np.broadcast_to(np.eye(len(LOAD_JOINTS)), (len(q), len(LOAD_JOINTS),
                                                         len(LOAD_JOINTS)))
        cols = np.concatenate([cols, eye], axis=2)
    a = cols.reshape(-1, cols.shape[2])
    theta = np.linalg.lstsq(a, external[:, LOAD_JOINTS].reshape(-1), rcond=None)[0]
    return theta[:3]


def load_summary(external: np.ndarray, q: np.ndarray) -> dict[str, Any]:
    """Load estimates of one recording from the external torque (N, 6)."""
    moment = load_moment(external, q, offsets=False)
    return {"external_mean": external.mean(0)[:3].tolist(),
            "external_rms": np.sqrt(np.mean(external ** 2, 0))[:3].tolist(),
            "moment_vector_kgm": moment.tolist(), "moment_kgm": float(np.linalg.norm(moment)),
            "moment_with_offsets_kgm": float(np.linalg.norm(load_moment(external, q, True)))}


def at_rate(js: JointStates, dt: float) -> JointStates:
    """``js`` on a grid of period ``dt`` [s] (linear interpolation), or ``js`` itself where its
    period is already ``dt``: a causal filter's taps hold for the rate it was fitted at."""
    own = float(np.median(np.diff(js.t)))
    if abs(own / dt - 1.0) < 0.01:
        return js
    t = np.arange(js.t[0], js.t[-1] + 1e-12, dt)
    cols = [np.stack([np.interp(t, js.t, a[:, j]) for j in range(a.shape[1])], axis=1)
            for a in (js.position, js.velocity, js.effort)]
    return JointStates(t, *cols)


def grams(path: str) -> float | None:
    m = re.search(r"(\d+)g", Path(path).name)
    return float(m.group(1)) if m else None


class Trained:
    """The models of one experiment, trained on ``train`` (a list of series)."""

    def __init__(self, train: Sequence[JointStates], models: Sequence[str], seed: int,
                 lstm_epochs: int | None, hybrid_epochs: int | None, train_label: str,
                 lookahead_ms: Sequence[float] = ()) -> None:
        from wrenchd.models.estimator.hybrid import (
            HybridConfig,
            ResidualNetConfig,
            fit_hybrid,
        )
        from wrenchd.models.physics.causal_acceleration import CausalAccelerationConfig

        self.models, self.meta = tuple(models), {}
        self.lookahead: dict[str, Any] = {}
        if {"hybrid", "lstm-residual"} & set(models):
            residual = ResidualNetConfig(seed=seed, **({"epochs": hybrid_epochs}
                                                       if hybrid_epochs else {}))
            self.hybrid = fit_hybrid(train, HybridConfig(residual=residual))
            self.meta["hybrid_info"] = self.hybrid.info
            self.meta["hybrid_config"] = self.hybrid.config.model_dump()
        if "hybrid" in models:
            for ms in lookahead_ms:
                accel = CausalAccelerationConfig(lookahead_s=ms / 1000.0)
                self.lookahead[lookahead_key(ms)] = fit_hybrid(
                    train, HybridConfig(residual=residual, acceleration=accel))
            if lookahead_ms:
                self.meta["lookahead_ms"] = [float(ms) for ms in lookahead_ms]
        if "ls" in models:
            from wrenchd.models.physics.least_squares import (
                PLAIN_LEAST_SQUARES,
                LeastSquaresConfig,
                RigidBodyFrictionModel,
            )

            q, dq, tau = (np.concatenate([getattr(s, n) for s in train])
                          for n in ("position", "velocity", "effort"))
            acc = np.concatenate([offline_acceleration(s) for s in train])
            start = time.perf_counter()
            self.ls = RigidBodyFrictionModel.fit(q, dq, acc, tau, config=LeastSquaresConfig())
            self.meta["ls_fit_seconds"] = round(time.perf_counter() - start, 2)
            self.ls_plain = RigidBodyFrictionModel.fit(q, dq, acc, tau, config=PLAIN_LEAST_SQUARES)
            self.meta["ls_rank"], self.meta["ls_plain_rank"] = self.ls.rank, self.ls_plain.rank
        overrides = {**REAL_RECIPE, "seed": seed, **({"epochs": lstm_epochs} if lstm_epochs
                                                     else {})}
        if "lstm" in models:
            self.lstm = self._fit_lstm(train, overrides, train_label, "lstm")
        if "lstm-residual" in models:
            residual_series = [JointStates(s.t, s.position, s.velocity,
                                           s.effort - self.hybrid.parts(features(s)).physics)
                               for s in train]
            self.lstm_residual = self._fit_lstm(residual_series, overrides, train_label,
                                                "lstm_residual")
        self.meta["recipe"] = overrides

    def _fit_lstm(self, series, overrides, label, key):
        from wrenchd.models.estimator.free_space_training import fit_free_space
        from wrenchd.models.estimator.training import recipe

        start = time.perf_counter()
        result = fit_free_space(list(series), config=recipe("free-space", **overrides),
                                data={"source": "csv", "path": label})
        self.meta[f"{key}_train_seconds"] = round(time.perf_counter() - start, 1)
        self.meta[f"{key}_epochs_run"] = result.validation["epochs_run"]
        return result.model

    def predict(self, js: JointStates) -> dict[str, np.ndarray]:
        """Torques (N, 6) of each model on one gap-free series, by result key."""
        x, out = features(js), {}
        if "lstm" in self.models:
            out["lstm"] = self.lstm.predict_sequence(x)
        if "ls" in self.models:
            acc = offline_acceleration(js)
            out["ls"] = self.ls.predict(js.position, js.velocity, acc)
            out["ls_plain"] = self.ls_plain.predict(js.position, js.velocity, acc)
        if hasattr(self, "hybrid"):
            parts = self.hybrid.parts(x)
            out["ls_causal"] = parts.physics
            if "hybrid" in self.models:
                out["hybrid"] = parts.torque
                out["hybrid_ungated"] = parts.physics + parts.residual
            if "lstm-residual" in self.models:
                out["lstm_residual"] = (parts.physics + parts.weight[:, None]
                                        * self.lstm_residual.predict_sequence(x))
            out["_weight"] = parts.weight
        for key, model in self.lookahead.items():
            out[key] = model.parts(x).torque
        return out


def scores(trained: Trained, series: Sequence[JointStates]) -> dict[str, Any]:
    """RMSE per joint of every model over ``series`` (concatenated), with the coverage."""
    preds = [trained.predict(s) for s in series]
    tau = np.concatenate([s.effort for s in series])
    out: dict[str, Any] = {"torque_std": tau.std(0).tolist()}
    for key in preds[0]:
        if not key.startswith("_"):
            out[f"{key}_rmse"] = rmse(np.concatenate([p[key] for p in preds]), tau)
    if "_weight" in preds[0]:
        w = np.concatenate([p["_weight"] for p in preds])
        d = np.concatenate([trained.hybrid.coverage_distance(features(s)) for s in series])
        inside = w >= 1.0
        cov: dict[str, Any] = {"share_full": float(inside.mean()), "share_any": float((w > 0).mean()),
                               "distance_quantiles": dict(zip(
                                   ("10", "50", "90"), np.quantile(d, [0.1, 0.5, 0.9]).tolist())),
                               "n_inside": int(inside.sum()),
                               "inner_distance": trained.hybrid.config.coverage.inner_distance,
                               "outer_distance": trained.hybrid.config.coverage.outer_distance}
        if inside.any():
            for key in ("ls", "ls_causal", "hybrid"):
                if key in preds[0]:
                    cov[f"{key}_rmse_inside"] = rmse(np.concatenate([p[key] for p in preds])[inside],
                                                     tau[inside])
        out["coverage"] = cov
    return out


def evaluate(train: Sequence[Source], test: Source, models: Sequence[str] = MODELS,
             seed: int = 0, lstm_epochs: int | None = None, hybrid_epochs: int | None = None,
             loads: Sequence[Source] = (), lookahead_ms: Sequence[float] = (),
             known_loads: Sequence[KnownLoad] = ()) -> dict[str, Any]:
    """Train the chosen models on ``train``, score them on ``train`` and ``test`` (joint
    torques and the free-motion tip force), estimate the external torque on each of
    ``loads`` and score it against each of ``known_loads``; ``lookahead_ms``: the hybrid again
    with an acceleration reading that far ahead (offline). Returns a JSON-ready dict."""
    from wrenchd.service.studies.newtons import (
        known_load_study,
        load_runs,
        run_to_run,
        tip_force_floor,
        tip_force_table,
    )

    unknown = set(models) - set(MODELS)
    if unknown or not models:
        raise ConfigError(f"unknown models {sorted(unknown)}; choose from {', '.join(MODELS)}")
    train_series = [s.load() for s in train]
    test_series = test.load()
    if lookahead_ms and "hybrid" not in models:
        raise ConfigError("a look-ahead is measured on the hybrid: add it to the models")
    trained = Trained(train_series, models, seed, lstm_epochs, hybrid_epochs,
                      ",".join(s.label for s in train), lookahead_ms)
    r: dict[str, Any] = {"train": [s.label for s in train], "test": test.label,
                         "models": list(models), "seed": seed, **trained.meta}
    r["train_file"] = scores(trained, train_series)
    r["test_file"] = scores(trained, [test_series])
    rep = repeatability(test_series)
    r["test_file"]["repeatability"] = rep
    r["test_file"]["tip_force_N"] = tip_force_table(trained, test_series)
    r["test_file"]["tip_force_floor_N"] = (tip_force_floor(test_series, rep["period_s"])
                                           if rep else None)
    if len(train_series) == 1:
        rep = repeatability(train_series[0])
        r["train_file"]["tip_force_N"] = tip_force_table(trained, train_series[0])
        r["train_file"]["tip_force_floor_N"] = (tip_force_floor(train_series[0], rep["period_s"])
                                                if rep else None)
    if known_loads:
        runs = load_runs(trained, known_loads)
        r["known_loads"] = known_load_study(runs)
        r["known_load_pairs"] = run_to_run(runs)
    if loads:
        r["loads"] = load_study(trained, train, train_series, loads)
    return r


def load_study(trained: Trained, train: Sequence[Source], train_series: Sequence[JointStates],
               loads: Sequence[Source]) -> dict[str, Any]:
    """External torque on recordings with added loads, and the load ratios it implies."""
    out: dict[str, Any] = {"recordings": {}}
    reference = train_series[0]
    for src in loads:
        js = src.load()
        rec: dict[str, Any] = {"grams": grams(src.path)}
        for key, pred in trained.predict(js).items():
            if not key.startswith("_") and key not in ("hybrid_ungated", "ls_plain"):
                rec[key] = load_summary(js.effort - pred, js.position)
        if len(reference) == len(js) and np.sqrt(np.mean(
                (reference.position[:, :3] - js.position[:, :3]) ** 2)) < 0.01:
            rec["measured_difference"] = load_summary(js.effort - reference.effort, js.position)
        out["recordings"][src.label] = rec
    if len(loads) >= 2:
        a, b = (out["recordings"][s.label] for s in loads[:2])
        truth = (b["grams"] / a["grams"]) if a["grams"] and b["grams"] else None
        ratios: dict[str, Any] = {"of": [loads[1].label, loads[0].label], "truth": truth}
        for key in a:
            if key != "grams" and key in b:
                ratios[key] = {"moment": b[key]["moment_kgm"] / a[key]["moment_kgm"],
                               "moment_with_offsets": (b[key]["moment_with_offsets_kgm"]
                                                       / a[key]["moment_with_offsets_kgm"]),
                               "pitch_rms": b[key]["external_rms"][1] / a[key]["external_rms"][1]}
        out["ratios"] = ratios
    return out
