"""Replay a session through the daemon's pipeline in simulated time, fast and deterministic.

The samples go through :meth:`wrenchd.service.pipeline.arm.ArmPipeline.process`, the very method the
daemon calls (validation, gate, drift, policy, delay line, adaptation, model swaps), in
simulated time; the session's bounds are checked in one vectorised pass first, and
``process`` skips its per-sample bounds check for the samples within them
(``checked=True``; the others it refuses as usual). The adaptation runs in a forked worker by default
(:class:`~wrenchd.service.replay.worker.WorkerAdaptation`: a round's net serves ``result_delay_s``
of sample time after the round fell due, as in the daemon) or inline
(:class:`~wrenchd.service.pipeline.adaptation.InlineAdaptation`: a round runs at the sample at which it falls
due and its model is used from the next sample on); either way the outcome depends only on
the session, the config, the seed and the delay.

Fast path (``batched=True``, the default): step 1 of the estimator (the LSTMs) never adapts,
so :class:`BatchedEstimator` computes it for every gap-free segment ahead of the pipeline,
with torch on a thread of idle priority (in chunks carrying the LSTM states, bit for bit one
:meth:`FreeSpaceModel.predict_sequence` call; torch releases the GIL, so it overlaps the
pipeline; a thread of normal priority takes over where a busy machine starves it), and the
``Corr`` correction and the damped ``J^-T`` wrench map in blocks of samples, recomputed
from the next sample on whenever the pipeline swaps the correction net (the wrench gains
are computed in chunks when needed or while the pipeline waits for the adaptation worker).
It stands in for the pipeline's estimator and returns the same :class:`EstimatorOutput` per
sample; the rest of ``process`` is untouched. Its step-1
numbers come by default from torch's float32 LSTM instead of the NumPy float32 kernel of the
streaming path: they agree to float32 rounding (about 1e-6 relative); ``step1="kernel"``
gives the streaming path's numbers bit for bit (a parity test checks it).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch

from wrenchd.models.errors import ConfigError
from wrenchd.models.estimator.compiled import deferred_compilation
from wrenchd.models.estimator.estimator import EstimatorOutput, TwoStepEstimator
from wrenchd.models.estimator.features import segment_starts
from wrenchd.models.estimator.free_space import FreeSpaceModel
from wrenchd.models.series import N_JOINTS, Session
from wrenchd.models.adaptation import normalisation_of
from wrenchd.service.pipeline import ArmPipeline, Event, PipelineConfig
from wrenchd.service.pipeline.validation import accepted_indices
from wrenchd.service.replay.source import joint_state_messages
from wrenchd.service.replay.worker import WorkerAdaptation
from wrenchd.service.runtime import stopping
from wrenchd.service.runtime.scheduling import idle_priority


#: Rows per torch step-1 call (about 22 ms of CPU; a call has a cost of its own, most of it
#: the pipeline's, which hands the GIL over for it), and on the idle-time thread once it finds
#: itself starved (its last call took over 4x its CPU time in wall time): 3 ms of CPU, how long
#: it may still run once the pipeline has taken over (its end is waited for).
STEP1_CHUNK, STEP1_CHUNK_IDLE = 2048, 256
#: The pipeline waits this long for the idle-time thread's rows before a thread of normal
#: priority takes over [s]
STEP1_TAKEOVER_S = 0.5
#: Samples per chunk of wrench gains (pinocchio Jacobians, ~2 ms).
GAIN_CHUNK = 256


class BatchedEstimator(TwoStepEstimator):
    """The pipeline's estimator with step 1 precomputed for a known sequence of samples.

    Args:
        base: the pipeline's estimator (its step-1 model, correction, config, wrench map).
        t: (N,) times [s] of the samples that will reach :meth:`step_one`, in order.
        features: (N, 12) ``[q, dq]`` of those samples.
        effort: (N, 6) their measured efforts [N m; N].
        block: samples per ``Corr`` + wrench block.
        step1: ``"kernel"``: step 1 by the streaming NumPy kernel, sample by sample, bit
            for bit what :meth:`step_one` computes (adaptation is chaotic in float32
            rounding: Adam turns 1e-7 differences of its inputs into different nets);
            ``"torch"``: one torch LSTM call per segment, several times faster, equal to
            float32 rounding only.
    """

    def __init__(self, base: TwoStepEstimator, t: np.ndarray, features: np.ndarray,
                 effort: np.ndarray, block: int = 256, step1: str = "kernel") -> None:
        super().__init__(base.free_space, base.correction, base.config, base.wrench_map)
        if self.mode != "corr":
            raise ConfigError("the batched replay needs a Corr estimator")
        self.t = np.asarray(t, dtype=np.float64)
        self.features = np.asarray(features, dtype=np.float64)
        self.effort = np.asarray(effort, dtype=np.float64)
        self.block = int(block)
        n = len(self.t)
        starts = segment_starts(self.t, self.config.max_gap_s, self.features[:, :N_JOINTS],
                                self.features[:, N_JOINTS:], self.config.max_jump)
        self.restarted = np.zeros(n, dtype=bool)
        self.restarted[starts] = True
        self._n = n                                      # per-sample look-ups as Python lists
        self._t_list = self.t.tolist()
        self._restarted_list = self.restarted.tolist()
        self.segment_start = starts[np.searchsorted(starts, np.arange(n), side="right") - 1] \
            if n else np.zeros(0, dtype=np.int64)
        # (N, 6) step-1 torques, float32 like the streaming kernel's output
        self.step1 = np.zeros((n, N_JOINTS), dtype=np.float32)
        self._segments = list(zip(starts.tolist(), np.append(starts[1:], n).tolist()))
        self._ready = 0                         # step-1 rows computed so far
        # where step 1 goes on from: (segment, row, LSTM states), and which step-1 thread
        # may go on (0: the idle-time one; 1: the one that took over from it)
        self._pos: tuple[int, int, Any] = (0, 0, None)
        self._generation = 0
        self.step1_taken_over = False           # a thread of normal priority took over
        self.cursor = 0                         # index of the next sample step_one expects
        self._threads: list[threading.Thread] = []
        self._stop = False
        self._failure: BaseException | None = None
        self._progress = threading.Condition()
        if not isinstance(self.free_space, torch.nn.Module):
            # a NumPy step 1 (the hybrid): its batch path is the streaming one, per segment
            for a, b in self._segments:
                self.step1[a:b] = self.free_space.predict_sequence(self.features[a:b])
            self._ready = n
        elif step1 == "torch" and not self.free_space.training:
            # torch's LSTM releases the GIL: computed on a thread while the replay runs
            self._start_step1(0)
        elif step1 == "torch":
            for a, b in self._segments:
                self.step1[a:b] = self.free_space.predict_sequence(self.features[a:b])
            self._ready = n
        else:
            for a, b in self._segments:   # the streaming kernel, the same calls as step_one
                kernel, state = self._recurrent, self._recurrent.initial_state(1)
                for k in range(a, b):
                    y, state = kernel.step(self.features[k][None, :], state)
                    self.step1[k] = y[0]
            self._ready = n
        # (N, 6, 6) wrench gains, computed in chunks when first needed or while the replay
        # waits for the adaptation worker (idle_work)
        self.gain = np.zeros((n, N_JOINTS, N_JOINTS))
        self._gain_ready = 0
        self._b0 = self._b1 = 0
        self._blk: tuple[np.ndarray, ...] = ()

    def _step1_chunk(self, pos: tuple[int, int, Any], size: int):
        """Step 1 by torch on the next ``size`` rows at most from ``pos`` (segment, row, LSTM
        states), within one segment: ``(a, b, rows (b - a, 6), pos after)``, None past the
        last row. Chunks carrying the states give bit for bit
        :meth:`FreeSpaceModel.predict_sequence` of the whole segment (tested)."""
        seg, k, states = pos
        while seg < len(self._segments) and k >= self._segments[seg][1]:
            seg, states = seg + 1, None                 # the next segment starts afresh
        if seg >= len(self._segments):
            return None
        k = max(k, self._segments[seg][0])
        stop = min(self._segments[seg][1], k + size)
        fs = self.free_space
        with torch.inference_mode():
            x = torch.as_tensor(self.features[k:stop], dtype=fs.in_mean.dtype)
            ys, states = fs.forward_normalised(x[None], states)
            y = torch.cat(ys, dim=-1) * fs.out_std + fs.out_mean
        return k, stop, y[0].to(torch.float64).numpy(), (seg, stop, states)

    def _start_step1(self, generation: int) -> None:
        thread = threading.Thread(target=self._torch_step1, args=(generation,), daemon=True,
                                  name=f"wrenchd-replay-step1-{generation}")
        self._threads.append(thread)
        thread.start()

    def _torch_step1(self, generation: int) -> None:
        """A step-1 thread: chunk after chunk from ``_pos``, each published (``_ready``) while
        ``generation`` is the current one.

        The pipeline and the adaptation worker wait on each other (a round's net serves a
        second of samples after it fell due), so each core idles for part of a replay. The
        first thread (generation 0) runs in ``SCHED_IDLE``: only on that idle time, never on
        theirs. On a machine busy with other work it may get next to none: when it keeps the
        pipeline waiting :data:`STEP1_TAKEOVER_S`, a thread of normal priority takes over
        from where it got to (:meth:`_wait_step1`). The rows do not depend on who computes
        them when."""
        idle, size = generation == 0, STEP1_CHUNK
        try:
            if idle:
                idle_priority()
            while True:
                with self._progress:
                    if self._stop or generation != self._generation:
                        return
                    pos = self._pos
                wall, cpu = time.perf_counter(), time.thread_time()
                got = self._step1_chunk(pos, size)
                if idle:
                    starved = time.perf_counter() - wall > 4.0 * (time.thread_time() - cpu)
                    size = STEP1_CHUNK_IDLE if starved else STEP1_CHUNK
                with self._progress:
                    if got is None or self._stop or generation != self._generation:
                        return
                    a, b, rows, self._pos = got
                    self.step1[a:b] = rows
                    self._ready = b
                    self._progress.notify_all()
        except BaseException as exc:  # noqa: BLE001 - raised on the replay's thread
            with self._progress:
                if generation == self._generation:
                    self._failure = exc
                self._progress.notify_all()

    def _wait_step1(self, stop: int) -> None:
        """Block until step-1 rows up to ``stop`` are computed; a thread of normal priority
        takes over from the idle-time one after :data:`STEP1_TAKEOVER_S` of waiting."""
        with self._progress:
            deadline = time.monotonic() + STEP1_TAKEOVER_S
            while self._ready < stop and self._failure is None:
                left = deadline - time.monotonic()
                if left <= 0 and self._generation == 0:
                    self._generation = 1        # the idle-time thread publishes no more
                    self.step1_taken_over = True
                    self._start_step1(1)
                self._progress.wait(left if left > 0 else None)
        if self._failure is not None:
            raise RuntimeError("batched replay: step 1 failed") from self._failure

    def close(self) -> None:
        """Stop and join the step-1 threads (before anything forks again)."""
        self._stop = True
        with self._progress:
            self._progress.notify_all()
        for thread in self._threads:
            thread.join()
        self._threads = []

    def idle_work(self) -> bool:
        """Compute the next chunk of wrench gains ahead of need; False when all are done
        (the replay calls it while it waits for the adaptation worker)."""
        if self._gain_ready >= self._n:
            return False
        self._gains_upto(self._gain_ready + 1)
        return True

    def _gains_upto(self, stop: int) -> None:
        while self._gain_ready < stop:
            a = self._gain_ready
            b = min(self._n, a + GAIN_CHUNK)
            self.gain[a:b] = self.wrench_map.gains(self.features[a:b, :N_JOINTS])
            self._gain_ready = b

    def _compute_block(self, i: int) -> None:
        w = self.correction.window
        b1 = min(i + self.block, len(self.t))
        if self._ready < b1:
            self._wait_step1(b1)
        if self._gain_ready < b1:
            self._gains_upto(b1)
        rows = np.arange(i, b1)
        idx = rows[:, None] - (w - 1) + np.arange(w)[None, :]
        idx = np.maximum(idx, self.segment_start[rows][:, None])
        windows = self.features[idx]                                        # (B, W, 12)
        predicted = self._corr.correct(windows, self.step1[i:b1]).astype(np.float64)
        external = self.effort[i:b1] - predicted
        wrench = np.einsum("nij,nj->ni", self.gain[i:b1], external)
        self._b0, self._b1 = i, b1
        self._blk = (windows, predicted, external, wrench, self.step1[i:b1].astype(np.float64))

    def step_one(self, t, q, dq, tau_measured) -> EstimatorOutput:
        i = self.cursor
        if i >= self._n or self._t_list[i] != t:
            raise ConfigError(f"batched replay: sample at t={t} s is not the next precomputed "
                              f"one; the pipeline accepted samples the pre-pass did not expect")
        self.cursor = i + 1
        if not self._b0 <= i < self._b1:
            self._compute_block(i)
        k = i - self._b0
        windows, predicted, external, wrench, step1 = self._blk
        return EstimatorOutput(float(t), predicted[k], external[k], wrench[k],
                               self._restarted_list[i], step1[k], windows[k])

    def swap_correction(self, correction) -> None:
        super().swap_correction(correction)
        self._b1 = min(self._b1, self.cursor)          # recompute from the next sample on

    def swap_correction_state(self, state, kernel=None) -> None:
        super().swap_correction_state(state, kernel)
        self._b1 = min(self._b1, self.cursor)


@dataclass
class ReplayResult:
    """Per-sample outputs (rows of the samples the pipeline estimated) and what happened.

    Arrays: ``t`` (N,) [s], ``stamp_ns`` (N,), ``wrench`` (N, 6) [N, N m], ``external``
    and ``predicted`` (N, 6) [N m; N], ``free`` (N,), ``score`` (N,) [std], ``model_version``
    (N,), ``restarted`` (N,) the estimator's state restarted there (a segment's first
    sample), ``sample`` (N,) index of each row in the session.
    """

    t: np.ndarray
    stamp_ns: np.ndarray
    sample: np.ndarray
    wrench: np.ndarray
    external: np.ndarray
    predicted: np.ndarray
    free: np.ndarray
    score: np.ndarray
    model_version: np.ndarray
    restarted: np.ndarray
    events: list[Event]
    offered_t: np.ndarray
    status: dict[str, Any]
    config: dict[str, Any]
    policy: str
    wall_s: float
    samples_in: int
    meta: dict[str, Any] = field(default_factory=dict)


def replay(session: Session, free_space: FreeSpaceModel, config: PipelineConfig | None = None,
           *, policy: str = "", batched: bool = True, arm: str = "PSM1", block: int = 256,
           step1: str = "torch", adaptation: str = "worker", result_delay_s: float = 1.0,
           pipeline_hook: Callable[[ArmPipeline], None] | None = None,
           setup_changes: Sequence[tuple[float, dict[str, Any]]] = ()) -> ReplayResult:
    """Run ``session`` through a fresh :class:`ArmPipeline` in simulated time.

    Args:
        session: joint states (truth is not used here; see :mod:`wrenchd.service.replay.metrics`).
        free_space: the step-1 model.
        config: the pipeline config (a policy's, :mod:`wrenchd.service.replay.policies`).
        policy: the policy's name, recorded in the result.
        batched: use :class:`BatchedEstimator` (same numbers, several times faster).
        step1: the batched step 1, ``"torch"`` or ``"kernel"`` (see :class:`BatchedEstimator`).
        adaptation: ``"worker"``: rounds in a forked process, their nets serving from
            ``result_delay_s`` of sample time after they fell due
            (:class:`~wrenchd.service.replay.worker.WorkerAdaptation`); ``"inline"``: each round at
            its sample, serving from the next one.
        result_delay_s: see ``adaptation`` [s].
        pipeline_hook: called with the pipeline before the first sample (tests, tracing).
        setup_changes: set-up changes to announce, ``(time [s], detail)`` each, as the daemon's
            ``setup`` key would (:meth:`ArmPipeline.setup_change`): each before the first
            sample at or after its time (:func:`wrenchd.service.replay.source.announced_changes`).
    Returns:
        the :class:`ReplayResult`.
    """
    config = config if config is not None else PipelineConfig()
    if adaptation not in ("worker", "inline"):
        raise ConfigError(f"adaptation must be 'worker' or 'inline', got {adaptation!r}")
    # step 1 runs in batches and each accepted round brings a correction net: the compiled
    # forms of the kernels are built where a kernel first streams, if ever
    with deferred_compilation():
        return _replay(session, free_space, config, policy, batched, arm, block, step1,
                       adaptation, result_delay_s, pipeline_hook, setup_changes)


def _replay(session, free_space, config, policy, batched, arm, block, step1, adaptation,
            result_delay_s, pipeline_hook, setup_changes) -> ReplayResult:
    msgs = joint_state_messages(session.joint_states)
    backend = None
    if (adaptation == "worker" and config.adaptation.enabled
            and config.policy.name != "frozen"):
        backend = WorkerAdaptation(config.adaptation, normalisation_of(free_space),
                                   result_delay_s)
    pipeline = ArmPipeline(arm, free_space, config, backend)
    try:
        return _run(pipeline, session, msgs, config, policy, batched, block, step1,
                    pipeline_hook, adaptation, result_delay_s, setup_changes)
    finally:
        if isinstance(pipeline.estimator, BatchedEstimator):
            pipeline.estimator.close()
        pipeline.close()


def _run(pipeline: ArmPipeline, session: Session, msgs, config: PipelineConfig, policy: str,
         batched: bool, block: int, step1: str, pipeline_hook, adaptation: str,
         result_delay_s: float, setup_changes: Sequence[tuple[float, dict[str, Any]]] = ()
         ) -> ReplayResult:
    offered: list[np.ndarray] = []
    pipeline.on_offer = offered.append
    start = time.perf_counter()
    js = session.joint_states
    # checked in one pass: process() skips its per-sample check of these (not of the others)
    valid = pipeline.validator.within(js.position, js.velocity, js.effort)
    checked = valid.tolist()
    if batched:
        stamps = np.array([m.stamp_ns for m in msgs], dtype=np.int64)
        keep = accepted_indices(valid, stamps)
        t = stamps[keep] / 1e9
        feats = np.concatenate([js.position[keep], js.velocity[keep]], axis=1)
        pipeline.estimator = BatchedEstimator(pipeline.estimator, t, feats, js.effort[keep],
                                              block, step1)
        if isinstance(pipeline.backend, WorkerAdaptation):
            pipeline.backend.idle_work = pipeline.estimator.idle_work
    if pipeline_hook is not None:
        pipeline_hook(pipeline)
    n = len(msgs)
    wrench, external, predicted = (np.zeros((n, N_JOINTS)) for _ in range(3))
    free, score, restarted = np.zeros(n, dtype=bool), np.zeros(n), np.zeros(n, dtype=bool)
    version, stamp, sample = (np.zeros(n, dtype=np.int64) for _ in range(3))
    events: list[Event] = []
    k = 0
    # the estimates are kept and copied into the arrays a batch at a time (row by row costs
    # more than the rest of the loop; a batch keeps at most a few estimator blocks alive)
    ests: list = []
    rows: list[int] = []
    keep_est, keep_row = ests.append, rows.append

    def flush() -> None:
        nonlocal k
        if not ests:
            return
        b = k + len(ests)
        m = b - k                    # concatenated: several times faster than from a list
        wrench[k:b] = np.concatenate([e.wrench for e in ests]).reshape(m, N_JOINTS)
        external[k:b] = np.concatenate([e.external_torque for e in ests]).reshape(m, N_JOINTS)
        predicted[k:b] = np.concatenate([e.predicted_torque for e in ests]).reshape(m, N_JOINTS)
        free[k:b] = [e.free for e in ests]
        restarted[k:b] = [e.restarted for e in ests]
        score[k:b] = [e.score for e in ests]
        version[k:b] = [e.model_version for e in ests]
        stamp[k:b] = [e.stamp_ns for e in ests]
        sample[k:b] = rows
        k = b
        ests.clear()
        rows.clear()
        stopping.check()            # SIGINT/SIGTERM: stop between batches (~0.3 s apart)

    process = pipeline.process
    changes = sorted(setup_changes, key=lambda c: c[0])
    next_ns = round(changes[0][0] * 1e9) if changes else None
    for i, (msg, ok) in enumerate(zip(msgs, checked)):
        while next_ns is not None and msg.stamp_ns >= next_ns:
            t_change, detail = changes.pop(0)
            events.extend(pipeline.setup_change(t_change, detail))
            next_ns = round(changes[0][0] * 1e9) if changes else None
        est, evs = process(msg, ok)
        if evs:
            events.extend(evs)
        if est is None:
            continue
        keep_est(est)
        keep_row(i)
        if len(rows) >= 4096:
            flush()
    flush()
    wall = time.perf_counter() - start
    status = pipeline.status()
    return ReplayResult(
        t=stamp[:k] / 1e9, stamp_ns=stamp[:k], sample=sample[:k], wrench=wrench[:k],
        external=external[:k], predicted=predicted[:k], free=free[:k], score=score[:k],
        model_version=version[:k], restarted=restarted[:k], events=events,
        offered_t=np.concatenate(offered) if offered else np.zeros(0),
        status=status, config=config.model_dump(mode="json"),
        policy=policy or config.policy.name, wall_s=wall, samples_in=n,
        meta={"batched": batched, "step1": step1 if batched else "stream",
              "adaptation": adaptation, "result_delay_s": result_delay_s,
              "rounds_waited": getattr(pipeline.backend, "rounds_waited", None),
              "step1_taken_over": getattr(pipeline.estimator, "step1_taken_over", None),
              "blocked_on_worker_s": getattr(pipeline.backend, "blocked_s", None),
              "setup_changes": [[float(t), d] for t, d in sorted(setup_changes,
                                                                 key=lambda c: c[0])],
              "source": session.metadata.get("source")})
