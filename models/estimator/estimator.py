"""The two-step estimator: joint states and measured efforts in, tip wrench out.

``predicted = step 2(step 1(q, dq))``, ``external = measured - predicted``,
``wrench = damped (J^T)^-1 external`` (Wu, Yilmaz, Kazanzides, Tumerdem, arXiv 2012.01479).
Step 2 is optional: a :class:`~wrenchd.models.estimator.correction.Corr` adds a correction to the
step-1 prediction; an :class:`~wrenchd.models.estimator.correction.Xfer` replaces it (it contains the
step-1 LSTMs, frozen).

One object serves two drivers with the same numbers: :meth:`TwoStepEstimator.step_one` for the
service (one sample at a time, NumPy kernels) and :meth:`TwoStepEstimator.predict_batch` for
offline use (torch over whole segments). Both restart the recurrent state and the history
window at the first sample, after a gap longer than ``max_gap_s`` and when time does not
advance.

The kernels are snapshots of the networks taken at construction: call :meth:`refresh` after
changing weights.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator import joint_streams
from wrenchd.models.estimator.correction import Corr, CorrKernel, HistoryWindow, Xfer
from wrenchd.models.estimator.features import position_jumps, segments
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.estimator.wrench import WrenchMap, WrenchMapConfig
from wrenchd.models.series import N_JOINTS, JointStates, all_finite


class EstimatorConfig(BaseModel):
    """Streaming behaviour of the estimator."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_gap_s: float = Field(default=0.05, gt=0.0,
                             description="a longer time step restarts the state [s]")
    max_jump: tuple[float, float, float, float, float, float] | None = Field(
        default=(0.05, 0.05, 0.005, 0.1, 0.1, 0.1),
        description="a joint position further than this from where its velocity carried it "
                    "restarts the state (a splice of two streams, an encoder re-zeroed) "
                    "[rad; m on insertion]; None: never")
    wrench: WrenchMapConfig = Field(default_factory=WrenchMapConfig)

    @field_validator("max_jump")
    @classmethod
    def _positive_jumps(cls, value: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if value is not None and not all(v > 0 for v in value):
            raise ValueError(f"every joint's jump must be > 0 (None: never), got {value}")
        return value


@dataclass(frozen=True)
class EstimatorOutput:
    """One sample's estimate.

    Attributes:
        t: sample time [s].
        predicted_torque: (6,) torque of the robot's own motion [N m; N].
        external_torque: (6,) measured minus predicted [N m; N].
        wrench: (6,) tip wrench [N, N m], base axes, torque about the tip.
        restarted: whether the state was restarted at this sample.
        step1_torque: (6,) step-1 prediction before any ``Corr`` correction [N m; N].
        window: (W, 12) the ``Corr`` input history of this sample (None without ``Corr``).
    """

    t: float
    predicted_torque: np.ndarray
    external_torque: np.ndarray
    wrench: np.ndarray
    restarted: bool
    step1_torque: np.ndarray | None = None
    window: np.ndarray | None = None

    def __init__(self, t: float, predicted_torque: np.ndarray, external_torque: np.ndarray,
                 wrench: np.ndarray, restarted: bool, step1_torque: np.ndarray | None = None,
                 window: np.ndarray | None = None) -> None:
        # One per sample: a dict update instead of the generated frozen __init__'s
        # object.__setattr__ per field; immutable all the same.
        self.__dict__.update(t=t, predicted_torque=predicted_torque,
                             external_torque=external_torque, wrench=wrench,
                             restarted=restarted, step1_torque=step1_torque, window=window)


@dataclass(frozen=True)
class EstimatorBatch:
    """Estimates of a series: (N, 6) arrays as in :class:`EstimatorOutput`, (N,) restarts."""

    t: np.ndarray
    predicted_torque: np.ndarray
    external_torque: np.ndarray
    wrench: np.ndarray
    restarted: np.ndarray


def _segments(restart: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` of the runs between restarts (the first run starts at 0)."""
    starts = np.flatnonzero(restart).tolist()
    if not starts or starts[0] != 0:
        starts = [0] + starts
    return list(zip(starts, starts[1:] + [len(restart)]))


class TwoStepEstimator:
    """Step 1 + optional step 2 + wrench map.

    Args:
        free_space: the step-1 model.
        correction: None, a :class:`Corr` or an :class:`Xfer` built on ``free_space``.
        config: gap handling and damping.
        wrench_map: a prepared map (else built from ``config.wrench``).
    Raises:
        ConfigError: an ``Xfer`` whose frozen layers are not ``free_space``'s.

    A 2 N push along the base frame's z at the tip, on top of the arm's own torques:

    >>> from wrenchd.models.estimator.pretrained import load_pretrained
    >>> est = TwoStepEstimator(load_pretrained("base"))
    >>> q, dq = np.array([0.1, -0.2, 0.12, 0.0, 0.1, 0.1]), np.zeros(6)   # [rad, m]; at rest
    >>> own = est.step_one(0.0, q, dq, np.zeros(6)).predicted_torque
    >>> push = est.wrench_map.kinematics.jacobian(q, "hybrid").T @ [0, 0, 2.0, 0, 0, 0]
    >>> out = est.step_one(0.001, q, dq, own + push)                # 1 ms later
    >>> round(float(out.wrench[2]), 1), bool(abs(out.wrench[:2]).max() < 0.5)
    (2.1, True)
    """

    def __init__(self, free_space: FreeSpaceModel, correction: Corr | Xfer | None = None,
                 config: EstimatorConfig | None = None, wrench_map: WrenchMap | None = None
                 ) -> None:
        if correction is not None and not isinstance(correction, (Corr, Xfer)):
            raise ConfigError(f"correction must be Corr, Xfer or None, got {type(correction)}")
        if isinstance(correction, Xfer) and not correction.uses_base(free_space):
            raise ConfigError("the Xfer model was not built on this free-space model")
        self.free_space, self._correction = free_space, correction
        self._correction_state: dict[str, np.ndarray] | None = None   # swapped in, not yet a Corr
        self.config = config if config is not None else EstimatorConfig()
        self.wrench_map = wrench_map if wrench_map is not None else WrenchMap(self.config.wrench)
        jump = self.config.max_jump
        self._max_jump = None if jump is None else np.asarray(jump, dtype=np.float64)
        self._jump_list = None if jump is None else [float(v) for v in jump]
        self.refresh()

    @property
    def correction(self) -> Corr | Xfer | None:
        """The step-2 model. After :meth:`swap_correction_state` the torch module is built
        here, on first use (serving needs only the kernel)."""
        if self._correction_state is not None:
            self._correction = Corr.from_state(self._correction.config, self._correction_state)
            self._correction_state = None
        return self._correction

    @property
    def mode(self) -> str:
        """``"base"``, ``"corr"`` or ``"xfer"``."""
        if isinstance(self._correction, Corr):
            return "corr"
        return "xfer" if isinstance(self._correction, Xfer) else "base"

    def refresh(self) -> None:
        """Rebuild the streaming kernels from the current weights and restart the state."""
        recurrent = self.correction if isinstance(self.correction, Xfer) else self.free_space
        self._recurrent = recurrent.kernel()
        self._corr = self.correction.kernel() if isinstance(self.correction, Corr) else None
        self._window = HistoryWindow(self.correction.window) if self._corr is not None else None
        self.reset_state()

    @property
    def step1_kernel(self):
        """The streaming step-1 kernel (shared by arms of one model, :meth:`share_step1`)."""
        return self._recurrent

    def share_step1(self, other: TwoStepEstimator) -> None:
        """Use ``other``'s step-1 kernel (read-only weights) instead of an own copy.

        Arms of one daemon that run the same step-1 model then stream through one copy of
        its weights (about 1 MB), which stays in cache; each estimator keeps its own state.
        """
        if other.free_space is not self.free_space or other.mode != self.mode:
            raise ConfigError("share_step1 needs estimators of the same step-1 model and mode")
        self._recurrent = other._recurrent

    def swap_correction(self, correction: Corr) -> None:
        """Replace the ``Corr`` weights between two samples without restarting the state.

        The lifelong adaptation uses this to swap in a better correction net atomically: the
        LSTM state and the history window carry on.
        """
        if not isinstance(correction, Corr) or not isinstance(self.correction, Corr):
            raise ConfigError("swap_correction needs a Corr estimator and a Corr")
        if correction.window != self.correction.window:
            raise ConfigError(f"window {correction.window} != {self.correction.window}")
        kernel = correction.kernel()
        self._correction, self._corr, self._correction_state = correction, kernel, None

    def swap_correction_state(self, state: dict[str, np.ndarray],
                              kernel: CorrKernel | None = None) -> None:
        """:meth:`swap_correction` from a ``Corr`` state dict of NumPy arrays (the adaptation
        worker's output), with its kernel if the sender built it: a reference swap on the
        thread that estimates, no torch module made (a fresh ``Corr`` runs its random
        initialisation: ~0.5 ms). :attr:`correction` builds the module when asked for.
        """
        if self.mode != "corr":
            raise ConfigError("swap_correction_state needs a Corr estimator")
        window = self._correction.window
        if kernel is None:
            kernel = CorrKernel.from_state(state, window)
        elif kernel.window != window:
            raise ConfigError(f"window {kernel.window} != {window}")
        self._corr, self._correction_state = kernel, state

    def reset_state(self) -> None:
        """Forget the past: the next sample starts a new segment."""
        self._state = None
        self._t_last: float | None = None
        self._q_last = self._dq_last = np.zeros(N_JOINTS)
        if self._window is not None:
            self._window.reset()

    def _jumped(self, t: float, q: np.ndarray, dq: np.ndarray) -> bool:
        """The position ``q`` (6,) at ``t`` [s] jumped from the last sample's (see
        :func:`~wrenchd.models.estimator.features.position_jumps`)."""
        jump = self._max_jump
        if jump is None:
            return False
        # six Python floats, in NumPy's order of operations (the same bits): the per-sample
        # path, where six-element array operations cost more than the arithmetic
        half = 0.5 * (t - self._t_last)
        for a, b, v, w, limit in zip(q.tolist(), self._q_last.tolist(), dq.tolist(),
                                     self._dq_last.tolist(), self._jump_list):
            if abs(a - b - (v + w) * half) > limit:
                return True
        return False

    def step_one(self, t: float, q: np.ndarray, dq: np.ndarray,
                 tau_measured: np.ndarray) -> EstimatorOutput:
        """Estimate one sample.

        Args:
            t: sample time [s].
            q, dq: (6,) joint positions [rad; m] and velocities [rad/s; m/s].
            tau_measured: (6,) measured joint efforts [N m; N].
        Raises:
            DataError: wrong shapes or non-finite values.
        """
        q, dq = np.asarray(q, dtype=np.float64), np.asarray(dq, dtype=np.float64)
        tau_measured = np.asarray(tau_measured, dtype=np.float64)
        if not q.shape == dq.shape == tau_measured.shape == (N_JOINTS,):
            raise DataError(f"q, dq and tau_measured must have shape (6,), got {q.shape}, "
                            f"{dq.shape}, {tau_measured.shape}")
        x = np.concatenate([q, dq])                              # (12,) [q, dq]
        if not (math.isfinite(t) and all_finite(x, tau_measured)):
            raise DataError("joint state contains NaN or Inf")
        restart = (self._t_last is None or not 0.0 < t - self._t_last <= self.config.max_gap_s
                   or self._jumped(t, q, dq))
        if restart:
            self.reset_state()
        self._t_last, self._q_last, self._dq_last = float(t), q, dq
        if self._state is None:
            self._state = self._recurrent.initial_state(1)
        y, self._state = self._recurrent.step(x[None, :], self._state)
        return self._finish_one(float(t), q, x, tau_measured, restart, y[0].astype(np.float64), y)

    def _finish_one(self, t: float, q: np.ndarray, x: np.ndarray, tau_measured: np.ndarray,
                    restart: bool, step1: np.ndarray, corr_in: np.ndarray) -> EstimatorOutput:
        """Corr, external torque and wrench of one sample whose step 1 is known (one stream's
        step, or one arm's share of arms stepped together): ``step1`` (6,) float64, and
        ``corr_in`` (1, 6) the same as the ``Corr`` takes it."""
        window = None
        predicted = step1
        if self._corr is not None:
            if restart:
                self._window.reset()
            window = self._window.push(x)
            predicted = self._corr.correct(window[None], corr_in)[0].astype(np.float64)
        external = tau_measured - predicted
        return EstimatorOutput(t, predicted, external, self.wrench_map.wrench(q, external),
                               restart, step1, None if window is None else window.copy())

    def step_many(self, t: np.ndarray, q: np.ndarray, dq: np.ndarray,
                  tau_measured: np.ndarray) -> list[EstimatorOutput]:
        """Estimate consecutive samples of the stream at once: what ``len(t)`` calls of
        :meth:`step_one` return, up to float32 rounding (restarts included).

        The recurrence still runs sample by sample, but the input projection, the output
        heads, the correction net and (for 4 samples or more) the wrench map run once over
        all of them: a backlog is worked off at a fraction of the per-sample cost.

        Args:
            t: (N,) sample times [s]; q, dq, tau_measured: (N, 6) as in :meth:`step_one`.
        Raises:
            DataError: wrong shapes or non-finite values (nothing is estimated then).
        """
        t, q, x, tau_measured, restart = self._check_many(t, q, dq, tau_measured)
        if len(t) == 0:
            return []
        step1 = np.empty((len(t), N_JOINTS), dtype=np.float64)
        for a, b in _segments(restart):
            if restart[a]:
                self._state = None
            if self._state is None:
                self._state = self._recurrent.initial_state(1)
            step1[a:b], self._state = self._recurrent.run(x[a:b], self._state)
        return self._finish_many(t, q, x, tau_measured, restart, step1)

    @staticmethod
    def step_many_joint(estimators: list[TwoStepEstimator],
                        batches: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
                        ) -> list[list[EstimatorOutput]]:
        """Several streams sharing one step-1 kernel, stepped as one batch
        (:func:`wrenchd.models.estimator.joint_streams.step_many_joint`)."""
        return joint_streams.step_many_joint(estimators, batches)
    def _check_many(self, t, q, dq, tau_measured):
        """Validated ``(t, q, x = [q, dq], tau, restart)`` of a run of samples; ``restart``
        (N,) says where the state restarts (first sample, gaps, time not advancing)."""
        t = np.asarray(t, dtype=np.float64)
        q, dq = np.asarray(q, dtype=np.float64), np.asarray(dq, dtype=np.float64)
        tau_measured = np.asarray(tau_measured, dtype=np.float64)
        n = len(t)
        if t.shape != (n,) or not q.shape == dq.shape == tau_measured.shape == (n, N_JOINTS):
            raise DataError(f"t must be (N,) and q, dq, tau_measured (N, 6); got {t.shape}, "
                            f"{q.shape}, {dq.shape}, {tau_measured.shape}")
        x = np.concatenate([q, dq], axis=1)                      # (N, 12) [q, dq]
        if not (np.isfinite(t).all() and np.isfinite(x).all()
                and np.isfinite(tau_measured).all()):
            raise DataError("joint state contains NaN or Inf")
        restart = np.empty(n, dtype=bool)
        if n:
            max_gap = self.config.max_gap_s
            last = self._t_last
            restart[0] = (last is None or not 0.0 < t[0] - last <= max_gap
                          or self._jumped(float(t[0]), q[0], dq[0]))
            step = np.diff(t)
            restart[1:] = ~((step > 0.0) & (step <= max_gap))
            if self._max_jump is not None and n > 1:
                restart[1:] |= position_jumps(t, q, dq, self._max_jump)
        return t, q, x, tau_measured, restart

    def _finish_many(self, t, q, x, tau_measured, restart, step1) -> list[EstimatorOutput]:
        """Corr, external torque and wrench of a run of samples whose step 1 is known."""
        n = len(t)
        self._t_last, self._q_last, self._dq_last = float(t[-1]), q[-1], x[-1, N_JOINTS:]
        if n == 1:                                      # the common case, without the runs
            return [self._finish_one(float(t[0]), q[0], x[0], tau_measured[0], bool(restart[0]),
                                     step1[0], step1.astype(np.float32))]
        if self._corr is not None:
            windows = []
            for a, b in _segments(restart):
                if restart[a]:
                    self._window.reset()
                windows += [self._window.push(row).copy() for row in x[a:b]]
            win = np.stack(windows)
            predicted = self._corr.correct(win, step1.astype(np.float32)).astype(np.float64)
        else:
            win, predicted = None, step1
        external = tau_measured - predicted
        if n >= 4:
            wrench = self.wrench_map.wrench_batch(q, external)
        else:
            wrench = np.stack([self.wrench_map.wrench(q[i], external[i]) for i in range(n)])
        return [EstimatorOutput(float(t[i]), predicted[i], external[i], wrench[i],
                                bool(restart[i]), step1[i],
                                None if win is None else win[i]) for i in range(n)]

    def predict_torque(self, features: np.ndarray) -> np.ndarray:
        """Predicted torques of one gap-free segment: (T, 12) -> (T, 6), from a fresh state."""
        if isinstance(self.correction, Xfer):
            return self.correction.predict_sequence(features)
        step1 = self.free_space.predict_sequence(features)
        if isinstance(self.correction, Corr):
            return self.correction.correct_sequence(features, step1)
        return step1

    def predict_batch(self, states: JointStates) -> EstimatorBatch:
        """Estimates of a whole series, the same numbers as :meth:`step_one` sample by sample.

        Does not touch the streaming state.
        """
        n = len(states)
        predicted = np.zeros((n, N_JOINTS))
        restarted = np.zeros(n, dtype=bool)
        x = np.concatenate([states.position, states.velocity], axis=1)
        for seg in segments(states.t, self.config.max_gap_s, states.position, states.velocity,
                            self.config.max_jump):
            predicted[seg] = self.predict_torque(x[seg])
            restarted[seg.start] = True
        external = states.effort - predicted
        wrench = self.wrench_map.wrench_batch(states.position, external)
        return EstimatorBatch(states.t.copy(), predicted, external, wrench, restarted)
