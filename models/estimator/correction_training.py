"""Training of the step-2 networks on top of a frozen step-1 model: ``Xfer`` (new layers on
the step-1 LSTM, the recurrent loop) and ``Corr`` (the feed-forward correction, mini-batch Adam
over step-1 torques and history windows computed once)."""

from __future__ import annotations

import copy
from typing import Any, Callable, Sequence

import numpy as np
import torch

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.correction import Corr, CorrConfig, Xfer, XferConfig
from wrenchd.models.estimator.features import history_windows
from wrenchd.models.estimator.free_space import FreeSpaceModel, GroupedTorqueModel
from wrenchd.models.estimator.free_space_training import train_recurrent
from wrenchd.models.estimator.training import (
    RECIPES,
    TrainConfig,
    TrainResult,
    describe_data,
    rmse_report,
    split_series,
)
from wrenchd.models.series import JointStates


def fit_xfer(base: FreeSpaceModel, series: Sequence[JointStates],
             xfer_config: XferConfig | None = None, config: TrainConfig | None = None,
             data: dict[str, Any] | None = None,
             on_epoch: Callable[[int, float], None] | None = None,
             device: str | torch.device | None = "cpu") -> TrainResult:
    """Train the new layers of an ``Xfer`` on ``base`` with trocar series (no contact)."""
    config = config if config is not None else RECIPES["xfer"]
    train, val = split_series(series, config.val_fraction, config.max_gap_s)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = Xfer(xfer_config, base=base)
        model.set_output_normalisation(np.concatenate([y for _, y in train]))
        validation, history = train_recurrent(model, train, val, config, on_epoch, device)
    return TrainResult("xfer", model, config, describe_data(series, data, config),
                       validation, history)


def predict_segments(model: GroupedTorqueModel, features: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Eval-mode torques of several gap-free segments in one batched pass (a step 1 that is
    no torch module, the hybrid, runs each segment through its own ``predict_sequence``).

    Each segment starts from the zero state, exactly as ``model.predict_sequence`` of each
    alone: the shorter ones are padded at their end (an LSTM is causal, padding after a
    segment cannot change its outputs) and the padding is cut off again.

    Args:
        features: (T_k, 12) raw feature rows per segment.
    Returns:
        (T_k, 6) torques per segment, float64.
    """
    if not features:
        return []
    if not isinstance(model, torch.nn.Module):      # a NumPy step 1 (the hybrid): per segment
        return [np.asarray(model.predict_sequence(x), dtype=np.float64) for x in features]
    lengths = [len(x) for x in features]
    longest = max(lengths)
    padded = np.stack([np.concatenate([x, np.repeat(x[-1:], longest - len(x), axis=0)])
                       if len(x) < longest else x for x in features])
    was_training = model.training
    model.eval()
    try:
        with torch.inference_mode():
            out = model(torch.as_tensor(padded, dtype=model.in_mean.dtype)).double().numpy()
    finally:
        model.train(was_training)
    return [out[k, :n] for k, n in enumerate(lengths)]


def corr_inputs(base: FreeSpaceModel, features: Sequence[np.ndarray], window: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """What a ``Corr`` reads, computed once: history windows and step-1 torques.

    Args:
        base: the frozen step-1 model.
        features: (T_k, 12) raw feature rows of gap-free segments.
        window: the Corr's history length [samples].
    Returns:
        windows (N, window, 12) and step-1 torques (N, 6), segments concatenated in order.
    """
    step1 = predict_segments(base, features)
    return (np.concatenate([history_windows(x, window) for x in features]),
            np.concatenate(step1))


class CorrTrainer:
    """Mini-batch Adam on a ``Corr`` over precomputed inputs (see :func:`corr_inputs`).

    One object per correction network, kept across calls: :func:`fit_corr` runs it epoch by
    epoch; lifelong adaptation can run a few :meth:`steps` on fresh windows whenever it
    wants (the optimiser's moments carry over). The loss is the MSE of the correction in
    units of the Corr's ``tau_std`` (its normalisation must already be set); the L2 penalty is
    Adam's ``weight_decay`` of ``config``.

    Args:
        corr: the network, trained in place.
        config: lr, weight_decay, batch_size, grad_clip, lr_halving_epochs and seed are used.
    """

    def __init__(self, corr: Corr, config: TrainConfig) -> None:
        self.corr, self.config = corr, config
        self.optimizer = torch.optim.Adam(corr.parameters(), lr=config.lr,
                                          weight_decay=config.weight_decay)
        self.scheduler = (torch.optim.lr_scheduler.StepLR(self.optimizer,
                                                          config.lr_halving_epochs, gamma=0.5)
                          if config.lr_halving_epochs else None)
        self.generator = torch.Generator().manual_seed(config.seed)
        self._epochs = 0

    def _tensors(self, windows, step1, measured):
        """Network inputs (N, W * 12 + 6), normalised once, and targets (N, 6)."""
        dtype = self.corr.in_mean.dtype
        w, s, y = (torch.as_tensor(a, dtype=dtype) for a in (windows, step1, measured))
        if not (w.ndim == 3 and s.ndim == 2 and s.shape == y.shape and len(w) == len(s)):
            raise DataError(f"expected (N, W, 12) windows and (N, 6) step-1 and measured "
                            f"torques, got {tuple(w.shape)}, {tuple(s.shape)}, {tuple(y.shape)}")
        with torch.no_grad():
            return self.corr.normalised_input(w, s), (y - s) / self.corr.tau_std

    def _step(self, inputs, target) -> float:
        loss = torch.mean((self.corr.net(inputs) - target) ** 2)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.config.grad_clip:
            torch.nn.utils.clip_grad_norm_(self.corr.parameters(), self.config.grad_clip)
        self.optimizer.step()
        return float(loss.detach())

    def epoch(self, windows, step1, measured, prepared=None) -> float:
        """One pass in random order (over every ``sample_stride``-th sample); mean batch loss.

        Args:
            windows: (N, W, 12) history windows; step1, measured: (N, 6) torques [N m; N].
            prepared: :meth:`prepare`'s result for these arrays, to skip normalising again.
        """
        inputs, target = prepared if prepared is not None else self._tensors(windows, step1,
                                                                             measured)
        stride = self.config.sample_stride
        if stride > 1:
            offset = self._epochs % stride
            inputs, target = inputs[offset::stride], target[offset::stride]
        self._epochs += 1
        self.corr.train()
        order = torch.randperm(len(inputs), generator=self.generator)
        losses = [self._step(inputs[idx], target[idx])
                  for idx in torch.split(order, self.config.batch_size)]
        if self.scheduler is not None:
            self.scheduler.step()
        self.corr.eval()
        return float(np.mean(losses))

    def prepare(self, windows, step1, measured) -> tuple[torch.Tensor, torch.Tensor]:
        """Normalised inputs and targets of a training set, for repeated :meth:`epoch` calls."""
        return self._tensors(windows, step1, measured)

    def steps(self, windows, step1, measured, n_steps: int) -> float:
        """``n_steps`` mini-batches drawn at random from the samples; returns the mean loss."""
        inputs, target = self._tensors(windows, step1, measured)
        self.corr.train()
        losses = []
        for _ in range(n_steps):
            idx = torch.randint(len(inputs), (min(self.config.batch_size, len(inputs)),),
                                generator=self.generator)
            losses.append(self._step(inputs[idx], target[idx]))
        self.corr.eval()
        return float(np.mean(losses)) if losses else float("nan")


def fit_corr(base: FreeSpaceModel, series: Sequence[JointStates],
             corr_config: CorrConfig | None = None, config: TrainConfig | None = None,
             data: dict[str, Any] | None = None,
             on_epoch: Callable[[int, float], None] | None = None) -> TrainResult:
    """Train a ``Corr`` on top of the frozen step-1 ``base`` with trocar series (no contact).

    The step-1 torques are computed once (batched over segments), then the correction net
    trains for ``config.epochs`` on them (:class:`CorrTrainer`), keeping the weights of the
    best validation epoch. ``recipe("corr")`` is the paper's; ``recipe("corr-fast")`` trains
    in a few seconds on a CPU (see :data:`RECIPES`).
    """
    config = config if config is not None else RECIPES["corr"]
    train, val = split_series(series, config.val_fraction, config.max_gap_s)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        # float32 unless the step 1 is a float64 torch model; the hybrid is NumPy (float32 net)
        corr = Corr(corr_config).to(getattr(base, "in_mean", torch.zeros(0)).dtype)
        w_tr, s_tr = corr_inputs(base, [x for x, _ in train], corr.window)
        w_va, s_va = corr_inputs(base, [x for x, _ in val], corr.window)
        y_tr = np.concatenate([y for _, y in train])
        y_va = np.concatenate([y for _, y in val])
        corr.set_normalisation(np.concatenate([x for x, _ in train]), s_tr)
        dtype = corr.in_mean.dtype
        w_va_t, s_va_t = (torch.as_tensor(a, dtype=dtype) for a in (w_va, s_va))
        trainer = CorrTrainer(corr, config)
        scale = np.maximum(y_tr.std(0), 1e-6)
        best, best_state, history, stale = np.inf, copy.deepcopy(corr.state_dict()), [], 0
        prepared = trainer.prepare(w_tr, s_tr, y_tr)
        for epoch in range(config.epochs):
            trainer.epoch(w_tr, s_tr, y_tr, prepared)
            with torch.no_grad():
                pred = corr(w_va_t, s_va_t).double().numpy()
            history.append(float(np.mean(np.sqrt(np.mean((pred - y_va) ** 2, 0)) / scale)))
            if on_epoch is not None:
                on_epoch(epoch, history[-1])
            if history[-1] < best:
                best, best_state, stale = history[-1], copy.deepcopy(corr.state_dict()), 0
            else:
                stale += 1
            if config.patience is not None and stale >= config.patience:
                break
        corr.load_state_dict(best_state)
        corr.eval()
        with torch.no_grad():
            pred = corr(w_va_t, s_va_t).double().numpy()
    report = rmse_report(pred, y_va, y_tr.mean(0), scale)
    step1 = np.sqrt(np.mean((s_va - y_va) ** 2, axis=0))
    validation = {**report, "step1_rmse": step1.tolist(), "epochs_run": len(history)}
    return TrainResult("corr", corr, config, describe_data(series, data, config), validation,
                       history)
