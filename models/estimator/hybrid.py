"""A physics-informed step 1: rigid body + friction, plus a learned residual where it has data.

    tau(q, dq) = physics(q, dq, ddq_hat) + w(q, dq) * residual([q, dq, ddq_hat])

* ``physics``: the rigid-body + friction model identified by least squares
  (:mod:`wrenchd.models.physics.least_squares`) on the causal acceleration estimate
  ``ddq_hat`` (:mod:`wrenchd.models.physics.causal_acceleration`); it extrapolates to joint
  states the training never visited. :data:`HYBRID_PHYSICS` adds a presliding friction per
  joint (the play operator of :mod:`wrenchd.models.physics.hysteresis`) and drops parameter
  directions excited below 1e-4 of the strongest.
* ``residual``: a small tanh feed-forward network learns what physics misses, from the joint
  state and the same acceleration (so it also corrects that estimate's lag where it has seen
  the trajectory): a smooth function that a 2 x 128 network fits in a minute on a CPU and
  runs in microseconds, with no recurrent state to warm up.
* ``w``: the trust of :class:`wrenchd.models.estimator.coverage.Coverage`; outside the
  training data's joint states the residual fades out and physics alone remains. Where the
  coverage is in doubt (between full and no trust) the residual keeps its trust only inside
  the range of its training targets (:meth:`ResidualNet.range_trust`,
  ``residual_range_margin``): ``w_cov (1 - (1 - w_cov)(1 - w_range))``.

Causal: :meth:`HybridStep1.step` (sample by sample, several streams) and
:meth:`HybridStep1.run` / :meth:`HybridStep1.predict_sequence` give the same numbers. It can
stand where a :class:`~wrenchd.models.estimator.free_space.FreeSpaceModel` does (``kernel()``,
``predict_sequence``; no ``Xfer``). Units: features ``[q, dq]`` [rad, m; rad/s, m/s],
torques [N m; N]; the sample rate must be the training rate (the acceleration filter's).
The measured effect of each choice: ``docs/results.md`` (step 1 on real dVRK data).
"""

from __future__ import annotations

import io
import json
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator
from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.compiled import DEFERRED, compile_now, hybrid_kernels
from wrenchd.models.estimator.coverage import Coverage, CoverageConfig, smoothstep
from wrenchd.models.estimator.features import N_FEATURES, segments
from wrenchd.models.physics.causal_acceleration import (
    CausalAcceleration,
    CausalAccelerationConfig,
    accel_window,
    lookahead_samples,
)
from wrenchd.models.physics.dynamics import RigidBodyModel
from wrenchd.models.physics.hysteresis import play, play_step
from wrenchd.models.physics.least_squares import (
    N_INERTIAL,
    LeastSquaresConfig,
    RigidBodyFrictionModel,
    smoothed_acceleration,
)
from wrenchd.models.series import N_JOINTS, JointStates

#: :meth:`HybridStep1.run` steps a run of up to this many rows one by one (compiled)
STREAMED_ROWS = 8
FORMAT = "wrenchd-hybrid-step1"
FORMAT_VERSION = 1
#: The residual's trusted range: its training targets' quantiles this far in from each end
#: (the extremes of a recording are single spikes).
RANGE_QUANTILE = 0.001
#: Residual network inputs: ``[q, dq, ddq_hat]``.
N_RESIDUAL_INPUTS = 3 * N_JOINTS

#: The hybrid's default physics columns: the least-squares defaults plus a presliding
#: friction per joint [rad; m], keeping the directions excited above 1e-4 of the strongest.
HYBRID_PHYSICS = LeastSquaresConfig(hysteresis_width=(0.01, 0.01, 0.001, 0.01, 0.01, 0.01),
                                    rcond=1e-4)

#: A hybrid's streaming state: the acceleration filter's (B, taps, 6) velocity history and
#: (B,) started flags, then the (B, 6) play-operator followers [rad; m].
HybridState = tuple[np.ndarray, np.ndarray, np.ndarray]


class ResidualNetConfig(BaseModel):
    """Structure and training of the residual network."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    hidden: tuple[int, ...] = Field(default=(128, 128), description="tanh layer widths")
    epochs: int = Field(default=200, ge=1, description="passes over the training samples")
    lr: float = Field(default=3e-3, gt=0.0, description="Adam rate, cosine-annealed to 0")
    batch_size: int = Field(default=256, ge=1)
    weight_decay: float = Field(default=0.0, ge=0.0, description="Adam L2 penalty")
    seed: int = Field(default=0, description="initial weights and sample order")

    @field_validator("hidden")
    @classmethod
    def _widths(cls, value: tuple[int, ...]) -> tuple[int, ...]:
        if not all(w >= 1 for w in value):
            raise ValueError(f"every layer needs at least one unit, got {value}")
        return value


class HybridConfig(BaseModel):
    """A hybrid step 1: physics columns, acceleration filter, residual network, trust region."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    physics: LeastSquaresConfig = Field(default=HYBRID_PHYSICS,
                                        description="least-squares physics columns")
    acceleration: CausalAccelerationConfig = Field(default_factory=CausalAccelerationConfig,
                                                   description="causal acceleration filter")
    residual: ResidualNetConfig = Field(default_factory=ResidualNetConfig)
    coverage: CoverageConfig = Field(
        default_factory=lambda: CoverageConfig(acceleration_weight=0.3),
        description="trust region; the residual net reads accelerations, so they count")
    residual_range_margin: float | None = Field(
        default=0.25, gt=0.0,
        description="where the coverage is in doubt, the residual is trusted within the "
                    "range of its training targets (0.1 to 99.9 % per joint) and not at all "
                    "this fraction of that range beyond it; None: no such bound")
    max_gap_s: float = Field(default=0.05, gt=0.0, description="a longer step splits a series")


@dataclass(frozen=True)
class ResidualNet:
    """The residual network in NumPy (float64): ``layers`` of ``(W (in, out), b (out,))`` with
    tanh between them, inputs normalised by ``in_mean``/``in_scale``, outputs scaled by
    ``out_scale`` [N m; N]."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    in_mean: np.ndarray
    in_scale: np.ndarray
    out_scale: np.ndarray
    #: (2, 6) the training targets' 0.1 and 99.9 % quantiles per joint [N m; N]; None:
    #: unknown (a model saved without them)
    out_range: np.ndarray | None = None

    def __call__(self, inputs: np.ndarray) -> np.ndarray:
        """(N, 18) ``[q, dq, ddq_hat]`` -> (N, 6) residual torques."""
        h = (inputs - self.in_mean) / self.in_scale
        for k, (w, b) in enumerate(self.layers):
            h = h @ w + b
            if k < len(self.layers) - 1:
                h = np.tanh(h)
        return h * self.out_scale

    def range_trust(self, residual: np.ndarray, margin: float | None) -> np.ndarray | None:
        """(T,) trust of (T, 6) ``residual`` outputs by how far the farthest joint lies outside
        :attr:`out_range`: 1 inside it, 0 from ``margin`` times the range's width beyond it,
        smooth between; None where there is no bound (no range or no margin).

        A net asked about motion unlike its training (the same poses at half the speed, say)
        can answer with torques it never had to produce; the distance in ``[q, dq, ddq]``
        can still be near there, so the coverage alone would half-trust it.
        """
        if self.out_range is None or margin is None:
            return None
        low, high = self.out_range
        width = np.maximum(high - low, 1e-12)
        outside = np.maximum(np.maximum(low - residual, residual - high), 0.0) / width
        return 1.0 - smoothstep(outside.max(axis=1) / margin)


@dataclass(frozen=True)
class HybridParts:
    """One segment's prediction taken apart: (T, 6) arrays and the (T,) trust."""

    physics: np.ndarray
    residual: np.ndarray
    weight: np.ndarray
    acceleration: np.ndarray

    @property
    def torque(self) -> np.ndarray:
        return self.physics + self.weight[:, None] * self.residual


@dataclass
class HybridStep1:
    """Physics + trusted residual; streaming state (:data:`HybridState`): the acceleration
    filter's velocity history and the play operator's followers."""

    config: HybridConfig
    physics: RigidBodyFrictionModel
    acceleration: CausalAcceleration
    residual: ResidualNet
    coverage: Coverage
    info: dict[str, Any] = field(default_factory=dict)
    #: No LSTM layers: TwoStepEstimator then steps each stream on its own.
    layers: ClassVar[tuple] = ()

    def __post_init__(self) -> None:
        self._rigid = RigidBodyModel()
        w = self.physics.config.hysteresis_width
        self._width = None if w is None else np.array(w, dtype=np.float64)
        self._compiled: Any = DEFERRED            # the streaming kernels, built on first use

    def __getstate__(self) -> dict:
        # the compiled kernels stay in their process: the receiver fetches its own (the
        # DEFERRED marker itself would not survive a pickle as the same object)
        return {k: v for k, v in self.__dict__.items() if k != "_compiled"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._compiled = DEFERRED

    # -- batch ---------------------------------------------------------------------------
    def _combine(self, x: np.ndarray, acc: np.ndarray,
                 presliding: np.ndarray | None) -> HybridParts:
        q, dq = x[:, :N_JOINTS], x[:, N_JOINTS:]
        phys = self.physics.predict(q, dq, acc, self._rigid, presliding)
        with_acc = np.concatenate([x, acc], axis=1)                 # [q, dq, ddq_hat]
        res = self.residual(with_acc)
        weight = self.coverage.weight(x if self.coverage.width == N_FEATURES else with_acc)
        bound = self.residual.range_trust(res, self.config.residual_range_margin)
        if bound is not None:
            # the range decides only where the coverage doubts: w (1 - (1 - w)(1 - bound)),
            # the coverage's trust times "well inside it, or inside the residual's range"
            weight = weight * (1.0 - (1.0 - weight) * (1.0 - bound))
        return HybridParts(phys, res, weight, acc)

    def parts(self, features: np.ndarray) -> HybridParts:
        """Physics, residual, trust and acceleration of one gap-free segment of (T, 12) rows."""
        x = _rows(features)
        return self._combine(x, self.acceleration.estimate(x[:, N_JOINTS:]),
                             self.physics.presliding(x[:, :N_JOINTS], self.physics.config))

    def coverage_distance(self, features: np.ndarray) -> np.ndarray:
        """Normalised distance (T,) of one gap-free segment's rows to the training coverage
        (with the causal acceleration where the coverage holds accelerations)."""
        x = _rows(features)
        if self.coverage.width > N_FEATURES:
            x = np.concatenate([x, self.acceleration.estimate(x[:, N_JOINTS:])], axis=1)
        return self.coverage.distance(x)

    def predict_sequence(self, features: np.ndarray) -> np.ndarray:
        """Torques (T, 6) of one gap-free segment of (T, 12) rows, from a fresh state."""
        return self.parts(features).torque

    def predict_series(self, states: JointStates) -> np.ndarray:
        """Torques (N, 6) of a series, restarting at every gap (``config.max_gap_s``).

        Raises:
            DataError: a sample rate more than 10 % off the training rate.
        """
        if len(states) > 1:
            dt = float(np.median(np.diff(states.t)))
            if abs(dt / self.acceleration.dt_s - 1.0) > 0.1:
                raise DataError(f"sample period {dt:.4g} s; this model was trained at "
                                f"{self.acceleration.dt_s:.4g} s")
        out = np.zeros((len(states), N_JOINTS))
        x = np.concatenate([states.position, states.velocity], axis=1)
        for seg in segments(states.t, self.config.max_gap_s):
            out[seg] = self.predict_sequence(x[seg])
        return out

    # -- streaming -----------------------------------------------------------------------
    def kernel(self) -> HybridStep1:
        """The streaming kernel (``initial_state``, ``step``, ``run``): the model itself, whose
        arrays are read-only after fitting; its compiled step is built now (numba's cache
        read, or a compilation), not on the first sample, unless compilation is deferred
        (:func:`~wrenchd.models.estimator.compiled.deferred_compilation`)."""
        if self._compiled is DEFERRED and compile_now():
            self._compiled = self._streaming_kernels()
        return self

    def initial_state(self, batch: int = 1) -> HybridState:
        """Fresh state of ``batch`` streams."""
        return (*self.acceleration.initial_state(batch), np.zeros((batch, N_JOINTS)))

    def step(self, x: np.ndarray, state: HybridState | None = None
             ) -> tuple[np.ndarray, HybridState]:
        """One sample: (12,) or (B, 12) rows -> (6,) or (B, 6) torques and the new state
        (``state`` is not modified; None starts fresh streams). Compiled where numba is
        installed (:meth:`_step_compiled`), else in NumPy; the two agree to float64
        rounding."""
        x = np.asarray(x, dtype=np.float64)
        single = x.ndim == 1
        xb = _rows(x[None] if single else x)
        if state is None:
            state = self.initial_state(len(xb))
        if self._compiled_step() is not None:
            y, state = self._step_compiled(xb, state)
            return (y[0] if single else y), state
        history, started, follower = state
        acc, (history, new_started) = self.acceleration.step(xb[:, N_JOINTS:],
                                                             (history, started))
        width, presliding = self._width, None
        if width is not None:
            presliding, follower = play_step(xb[:, :N_JOINTS], width, follower, started)
        y = self._combine(xb, acc, presliding).torque
        return (y[0] if single else y), (history, new_started, follower)

    def _compiled_step(self) -> tuple | None:
        """What :meth:`_step_compiled` needs, built on first use; None: NumPy serves."""
        if self._compiled is DEFERRED:
            self._compiled = self._streaming_kernels()
        return self._compiled

    def _streaming_kernels(self) -> tuple | None:
        """``(motion, combine, rigid parameters, play widths, constants)`` of
        :meth:`_step_compiled`, or None: numba missing or switched off, or an acceleration
        filter that reads ahead (it cannot stream; the NumPy step says so)."""
        kernels = hybrid_kernels() if not self.acceleration.lookahead else None
        if kernels is None:
            return None
        phys, res = self.physics, self.residual
        friction = phys.coefficients[N_INERTIAL:].reshape(-1, N_JOINTS).copy()
        bounded = res.out_range is not None and self.config.residual_range_margin is not None
        low, high = (res.out_range if bounded else np.zeros((2, N_JOINTS)))
        cov = self.coverage.config
        constants = (friction, float(phys.config.coulomb_velocity or 0.0), phys.config.spring,
                     self._width is not None, cov.inner_distance, cov.outer_distance,
                     np.ascontiguousarray(low, dtype=np.float64),
                     np.ascontiguousarray(high, dtype=np.float64),
                     float(self.config.residual_range_margin) if bounded else 0.0)
        return (kernels["hybrid_motion"], kernels["hybrid_combine"],
                phys.coefficients[:N_INERTIAL].copy(),
                self._width if self._width is not None else np.zeros(0), constants)

    def _step_compiled(self, xb: np.ndarray, state: HybridState
                       ) -> tuple[np.ndarray, HybridState]:
        """:meth:`step` of (B, 12) checked rows in two compiled calls (the acceleration filter
        and the play operator; the friction, the trust and the sum) around the rigid body's
        regressor, the residual net and the coverage's distances."""
        motion, combine, theta, width, constants = self._compiled
        history, started, follower = state
        streams = (len(xb),)
        if (history.shape != streams + self.acceleration.weights.shape[::-1]
                or started.shape != streams or follower.shape != streams + (N_JOINTS,)):
            # the kernels do not check their indices: a state of another shape is refused
            raise DataError(f"a state of {history.shape[0]} streams for {len(xb)} rows "
                            f"(or not this model's: history {history.shape}, started "
                            f"{started.shape}, follower {follower.shape})")
        q = np.ascontiguousarray(xb[:, :N_JOINTS])
        dq = np.ascontiguousarray(xb[:, N_JOINTS:])
        acc, history, presliding, follower = motion(q, dq, history, started,
                                                    self.acceleration.weights, follower, width)
        rigid = self._rigid.rigid_torque(q, dq, acc, theta)
        with_acc = np.concatenate([xb, acc], axis=1)                 # [q, dq, ddq_hat]
        res = self.residual(with_acc)
        cov = self.coverage
        friction, v0, spring, play_on, inner, outer, low, high, margin = constants
        y = combine(rigid, q, dq, acc, presliding, friction, v0, spring, play_on, res,
                    xb if cov.width == N_FEATURES else with_acc, cov.mean, cov.scale,
                    cov.points, cov.norms, inner, outer, low, high, margin)
        return y, (history, np.ones_like(started), follower)

    def run(self, x: np.ndarray, state: HybridState) -> tuple[np.ndarray, HybridState]:
        """Consecutive samples of one stream: (T, 12) -> (T, 6) torques and the new state.
        A run of up to :data:`STREAMED_ROWS` (a daemon's pass) is stepped row by row by the
        compiled step where there is one (built on first use, as :meth:`step`'s); longer
        runs go through NumPy at once."""
        xb = _rows(x)
        if len(xb) <= STREAMED_ROWS and self._compiled_step() is not None:
            out = np.empty((len(xb), N_JOINTS))
            for k in range(len(xb)):
                y, state = self._step_compiled(xb[k:k + 1], state)
                out[k] = y[0]
            return out, state
        history, started, follower = state
        acc, (history, new_started) = self.acceleration.run(xb[:, N_JOINTS:],
                                                            (history, started))
        width, presliding = self._width, None
        if width is not None and len(xb):
            presliding, last = play(xb[:, :N_JOINTS], width,
                                    follower[0] if started[0] else None)
            follower = last[None]
        return self._combine(xb, acc, presliding).torque, (history, new_started, follower)

    # -- persistence ---------------------------------------------------------------------
    def arrays(self) -> dict[str, np.ndarray]:
        """Every learned array by name (float64): acceleration filter, coverage, residual."""
        out = {"acceleration_weights": self.acceleration.weights,
               "coverage_points": self.coverage.points, "coverage_mean": self.coverage.mean,
               "coverage_scale": self.coverage.scale, "in_mean": self.residual.in_mean,
               "in_scale": self.residual.in_scale, "out_scale": self.residual.out_scale}
        if self.residual.out_range is not None:
            out["out_range"] = self.residual.out_range
        for k, (w, b) in enumerate(self.residual.layers):
            out[f"layer{k}.weight"], out[f"layer{k}.bias"] = w, b
        return {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in out.items()}

    def description(self) -> dict[str, Any]:
        """Everything else, as JSON values: format, config, physics parameters, rate, info."""
        return {"format": FORMAT, "version": FORMAT_VERSION,
                "config": self.config.model_dump(mode="json"),
                "physics": self.physics.to_dict(), "dt_s": float(self.acceleration.dt_s),
                "info": self.info}

    @classmethod
    def from_parts(cls, arrays: dict[str, np.ndarray], description: dict[str, Any]
                   ) -> HybridStep1:
        """The model whose :meth:`arrays` and :meth:`description` these are.

        Raises:
            ConfigError: another format or version, or a missing or malformed part.
        """
        if description.get("format") != FORMAT:
            raise ConfigError(f"not a {FORMAT} model: format {description.get('format')!r}")
        if description.get("version") != FORMAT_VERSION:
            raise ConfigError(f"{FORMAT} version {description.get('version')} is not "
                              f"{FORMAT_VERSION}")
        try:
            config = HybridConfig.model_validate(description["config"])
            a = {k: np.asarray(v, dtype=np.float64) for k, v in arrays.items()}
            n_layers = len(config.residual.hidden) + 1
            layers = tuple((a[f"layer{k}.weight"], a[f"layer{k}.bias"]) for k in range(n_layers))
            return cls(config, RigidBodyFrictionModel.from_dict(description["physics"]),
                       CausalAcceleration(a["acceleration_weights"], description["dt_s"],
                                          lookahead_samples(config.acceleration,
                                                            description["dt_s"])),
                       ResidualNet(layers, a["in_mean"], a["in_scale"], a["out_scale"],
                                   a.get("out_range")),
                       Coverage(a["coverage_points"], a["coverage_mean"], a["coverage_scale"],
                                config.coverage), dict(description.get("info", {})))
        except (KeyError, ValueError, TypeError) as exc:
            raise ConfigError(f"incomplete {FORMAT} model: {exc}") from exc

    def save(self, path: str | os.PathLike[str]) -> None:
        """One file: the description as JSON text, the arrays as float64 tensors; :meth:`load`
        reads it with ``torch.load(weights_only=True)``."""
        import torch

        payload = {"format": FORMAT, "version": FORMAT_VERSION,
                   "description": json.dumps(self.description()),
                   "arrays": {k: torch.from_numpy(v) for k, v in self.arrays().items()}}
        buffer = io.BytesIO()
        torch.save(payload, buffer)
        with open(path, "wb") as file:
            file.write(buffer.getvalue())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> HybridStep1:
        """The model :meth:`save` wrote; ConfigError for another or a damaged file."""
        import torch

        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:                    # torch raises many types for bad files
            raise ConfigError(f"cannot read a hybrid step-1 file {path}: {exc}") from exc
        if not isinstance(payload, dict) or payload.get("format") != FORMAT:
            raise ConfigError(f"{path} is not a {FORMAT} file")
        try:
            description = json.loads(payload["description"])
            arrays = {k: v.numpy() for k, v in payload["arrays"].items()}
        except (KeyError, ValueError, TypeError, AttributeError) as exc:
            raise ConfigError(f"{path}: incomplete hybrid step-1 file: {exc}") from exc
        return cls.from_parts(arrays, description)


def _rows(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != N_FEATURES:
        raise DataError(f"features must have shape (T, {N_FEATURES}), got {x.shape}")
    if not np.isfinite(x).all():
        raise DataError("features contain NaN or Inf")
    return x


def _dt(series: Sequence[JointStates]) -> float:
    steps = np.concatenate([np.diff(s.t) for s in series if len(s) > 1])
    if steps.size == 0:
        raise DataError("training series need at least two samples")
    dt = float(np.median(steps))
    if not np.allclose([np.median(np.diff(s.t)) for s in series if len(s) > 1], dt, rtol=0.01):
        raise DataError("training series must share one sample rate")
    return dt


def fit_hybrid(series: Sequence[JointStates], config: HybridConfig | None = None,
               on_epoch: Callable[[int, float], None] | None = None) -> HybridStep1:
    """Identify the physics, fit the acceleration filter and train the residual network
    (``on_epoch(epoch, loss)`` after each of its epochs, e.g. for a progress bar).

    Every gap-free segment of ``series`` (free motion, no contact: the target is the
    measured effort) is used for all three; ``info`` records the fit's ranks and times.
    """
    config = config if config is not None else HybridConfig()
    if not series:
        raise DataError("fit_hybrid needs at least one series")
    dt = _dt(series)
    segs = [(np.concatenate([s.position, s.velocity], axis=1)[sl], s.effort[sl])
            for s in series for sl in segments(s.t, config.max_gap_s) if sl.stop - sl.start > 1]
    start = time.perf_counter()
    accel = CausalAcceleration.fit([x[:, N_JOINTS:] for x, _ in segs], dt, config.acceleration)
    acc = [accel.estimate(x[:, N_JOINTS:]) for x, _ in segs]
    x_all = np.concatenate([x for x, _ in segs])
    a_all, tau = np.concatenate(acc), np.concatenate([y for _, y in segs])
    # The physics is identified with the centred (offline) acceleration: its parameters then
    # describe the arm, not the causal filter's lag and noise (the residual sees those).
    ident = [(x, y, smoothed_acceleration(x[:, N_JOINTS:], dt, config.acceleration.target_window_s,
                                          config.acceleration.target_order))
             for x, y in segs if len(x) >= accel_window(config.acceleration, dt)]
    xi = np.concatenate([x for x, _, _ in ident])
    rigid = RigidBodyModel()
    physics = RigidBodyFrictionModel.fit(xi[:, :N_JOINTS], xi[:, N_JOINTS:],
                                         np.concatenate([a for _, _, a in ident]),
                                         np.concatenate([y for _, y, _ in ident]), rigid,
                                         config.physics,
                                         _presliding([x for x, _, _ in ident], config.physics))
    physics_s = time.perf_counter() - start
    inputs = np.concatenate([x_all, a_all], axis=1)
    residual_target = tau - physics.predict(x_all[:, :N_JOINTS], x_all[:, N_JOINTS:], a_all,
                                            rigid, _presliding([x for x, _ in segs],
                                                               config.physics))
    start = time.perf_counter()
    net, loss = train_residual(inputs, residual_target, config.residual, on_epoch)
    info = {"n_samples": len(x_all), "dt_s": dt, "physics_rank": physics.rank,
            "physics_fit_seconds": round(physics_s, 2),
            "residual_train_seconds": round(time.perf_counter() - start, 1),
            "residual_final_loss": loss}
    return HybridStep1(config, physics, accel, net,
                       Coverage.fit([np.concatenate([x, a], axis=1) if
                                     config.coverage.acceleration_weight > 0 else x
                                     for (x, _), a in zip(segs, acc)], config.coverage), info)


def _presliding(segments_x: Sequence[np.ndarray], config: LeastSquaresConfig
                ) -> np.ndarray | None:
    """Play-operator outputs of several (T, 12) segments, each started afresh, concatenated."""
    if config.hysteresis_width is None:
        return None
    return np.concatenate([RigidBodyFrictionModel.presliding(x[:, :N_JOINTS], config)
                           for x in segments_x])


def train_residual(inputs: np.ndarray, target: np.ndarray, config: ResidualNetConfig,
                   on_epoch: Callable[[int, float], None] | None = None
                   ) -> tuple[ResidualNet, float]:
    """Train the residual network on (N, 18) inputs and (N, 6) residual torques; returns it
    with the last epoch's mean normalised MSE. Seeded; runs on the CPU."""
    import torch

    mean, scale = inputs.mean(0), np.maximum(inputs.std(0), 1e-6)
    out_scale = np.maximum(target.std(0), 1e-9)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        widths = (N_RESIDUAL_INPUTS, *config.hidden, N_JOINTS)
        mods: list[torch.nn.Module] = []
        for k in range(len(widths) - 1):
            mods.append(torch.nn.Linear(widths[k], widths[k + 1]))
            if k < len(widths) - 2:
                mods.append(torch.nn.Tanh())
        net = torch.nn.Sequential(*mods)
        x = torch.as_tensor((inputs - mean) / scale, dtype=torch.float32)
        y = torch.as_tensor(target / out_scale, dtype=torch.float32)
        opt = torch.optim.Adam(net.parameters(), lr=config.lr, weight_decay=config.weight_decay)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, config.epochs)
        gen = torch.Generator().manual_seed(config.seed)
        loss_sum = 0.0
        for epoch in range(config.epochs):
            order = torch.randperm(len(x), generator=gen)
            loss_sum, batches = 0.0, 0
            for idx in torch.split(order, config.batch_size):
                loss = torch.mean((net(x[idx]) - y[idx]) ** 2)
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                loss_sum, batches = loss_sum + float(loss.detach()), batches + 1
            sched.step()
            loss_sum /= batches
            if on_epoch is not None:
                on_epoch(epoch, loss_sum)
    linears = [m for m in net if isinstance(m, torch.nn.Linear)]
    layers = tuple((m.weight.detach().double().numpy().T.copy(),
                    m.bias.detach().double().numpy().copy()) for m in linears)
    out_range = np.quantile(target, [RANGE_QUANTILE, 1.0 - RANGE_QUANTILE], axis=0)
    return ResidualNet(layers, mean, scale, out_scale, out_range), float(loss_sum)
