"""Training loops of the two-step estimator: step 1 (free space, ``Troc``), ``Xfer``, ``Corr``.

Recipes follow Wu, Yilmaz, Kazanzides, Tumerdem (arXiv 2012.01479): Adam at a learning rate
of 1e-3; the step-1 networks 1000 epochs with the rate halved every 125 epochs; the
correction network 400 epochs with L2 weight decay 0.01 (Adam's coupled ``weight_decay``,
i.e. an L2 penalty, not AdamW). The ``Xfer`` recipe reuses the step-1 schedule (an assumption).

Recurrent models train with truncated back-propagation through time: every gap-free training
segment is cut into lanes of ``window * lane_windows`` samples (cut points shifted by a random
offset each epoch); a batch of lanes is walked window by window, the LSTM state carried
(detached) from one window to the next, as in streaming inference. Each joint group keeps the
weights of its best validation epoch (the paper trains one network per group); training stops
early when no group improved for ``patience`` epochs.

The validation split is the last ``val_fraction`` of every series (contiguous in time). All
randomness (initial weights, dropout, lane order) comes from ``seed``. Train on motion without
contact: the target is the measured effort.

The paper's variants, as (function, recipe, data):

=======  ===============================  ==========================================
Base     ``fit_free_space``, free-space   free motion, no trocar
Troc     ``fit_free_space``, ``"troc"``   trocar motion only (step-1 structure)
Corr     ``fit_corr`` on Base, ``"corr"``  trocar motion, a few minutes
Xfer     ``fit_xfer`` on Base, ``"xfer"``  trocar motion, a few minutes
=======  ===============================  ==========================================
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.correction import Corr, CorrConfig, Xfer, XferConfig
from wrenchd.models.estimator.features import history_windows, segments
from wrenchd.models.estimator.free_space import FreeSpaceConfig, FreeSpaceModel, GroupedTorqueModel
from wrenchd.models.series import JointStates

Segment = tuple[np.ndarray, np.ndarray]          # (T, 12) features, (T, 6) measured torques


class TrainConfig(BaseModel):
    """Optimisation of one network."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    epochs: int = Field(default=1000, ge=1, description="maximum number of epochs")
    lr: float = Field(default=1e-3, gt=0.0, description="Adam learning rate")
    lr_halving_epochs: int | None = Field(default=125, ge=1,
                                          description="halve the rate every N epochs; None: never")
    batch_size: int = Field(default=16, ge=1, description="lanes (recurrent) or samples (Corr)")
    window: int = Field(default=100, ge=2, description="truncated-BPTT window [samples]")
    lane_windows: int = Field(default=8, ge=1, description="windows per lane (state carried)")
    weight_decay: float = Field(default=0.0, ge=0.0, description="L2 penalty (Adam weight_decay)")
    grad_clip: float | None = Field(default=1.0, gt=0.0, description="max gradient norm per group")
    patience: int | None = Field(default=100, ge=1, description="early-stopping patience [epochs]")
    val_fraction: float = Field(default=0.2, gt=0.0, lt=1.0, description="validation tail share")
    max_gap_s: float = Field(default=0.05, gt=0.0, description="gap that splits a series [s]")
    seed: int = Field(default=0, description="seed of every random choice")
    sample_stride: int = Field(default=1, ge=1,
                               description="Corr: epoch k uses every n-th sample from offset "
                                           "k mod n (200 Hz neighbours are near duplicates)")


#: Named recipes. ``troc`` is the step-1 structure trained directly on trocar data.
RECIPES: dict[str, TrainConfig] = {
    "free-space": TrainConfig(epochs=1000, lr_halving_epochs=125),
    "troc": TrainConfig(epochs=1000, lr_halving_epochs=125),
    "xfer": TrainConfig(epochs=1000, lr_halving_epochs=125),
    "corr": TrainConfig(epochs=400, lr_halving_epochs=None, weight_decay=0.01, batch_size=256),
    # Adaptation in seconds on a CPU (deliverable 6 of issue 3): large batches, a ten times
    # higher rate halved every 5 epochs, 16 epochs over a quarter of the samples each (the
    # offset rotates, so 4 passes over the data in all), no early stop. Measured beside the
    # paper's recipe in reports/paper-reproduction.
    "corr-fast": TrainConfig(epochs=16, lr=1e-2, lr_halving_epochs=5, weight_decay=0.01,
                             batch_size=1024, sample_stride=4, patience=None),
}


def recipe(name: str, **overrides: Any) -> TrainConfig:
    """The named recipe with fields overridden (e.g. ``recipe("corr", epochs=20)``)."""
    try:
        base = RECIPES[name]
    except KeyError:
        raise ConfigError(f"unknown recipe {name!r}; choose one of {sorted(RECIPES)}") from None
    return TrainConfig(**{**base.model_dump(), **overrides})       # validates the overrides


@dataclass
class TrainResult:
    """A trained model with what a checkpoint records about it."""

    kind: str                                   # "free_space", "xfer" or "corr"
    model: torch.nn.Module
    train_config: TrainConfig
    data: dict[str, Any]
    validation: dict[str, Any]
    history: list[float] = field(default_factory=list)   # validation score per epoch


def split_series(series: Sequence[JointStates], val_fraction: float, max_gap_s: float
                 ) -> tuple[list[Segment], list[Segment]]:
    """Training and validation segments: the last ``val_fraction`` of each series validates."""
    train, val = [], []
    for s in series:
        x = np.concatenate([s.position, s.velocity], axis=1)
        cut = len(s) - int(round(len(s) * val_fraction))
        for part, out in ((slice(0, cut), train), (slice(cut, len(s)), val)):
            t = s.t[part]
            for seg in segments(t, max_gap_s):
                if seg.stop - seg.start >= 2:
                    out.append((x[part][seg], s.effort[part][seg]))
    if not train or not val:
        raise DataError("not enough samples for a training and a validation split")
    return train, val


def describe_data(series: Sequence[JointStates], data: dict[str, Any] | None,
                  config: TrainConfig) -> dict[str, Any]:
    """The data description a checkpoint stores: the caller's labels plus counts."""
    return {**(data or {}), "n_series": len(series), "n_samples": int(sum(len(s) for s in series)),
            "duration_s": float(sum(s.t[-1] - s.t[0] for s in series if len(s) > 1)),
            "rate_hz": [s.rate_hz for s in series], "val_fraction": config.val_fraction}


def _rmse_report(pred: np.ndarray, target: np.ndarray, baseline_mean: np.ndarray,
                 scale: np.ndarray) -> dict[str, Any]:
    rmse = np.sqrt(np.mean((pred - target) ** 2, axis=0))
    base = np.sqrt(np.mean((target - baseline_mean) ** 2, axis=0))
    return {"rmse": rmse.tolist(), "baseline_rmse": base.tolist(),
            "score": float(np.mean(rmse / scale))}


# -- recurrent models (step 1, Troc, Xfer) ------------------------------------------------
def _lanes(segs: list[Segment], length: int, offset: int) -> tuple[np.ndarray, np.ndarray]:
    xs, ys = [], []
    for x, y in segs:
        start = offset if len(x) - offset >= length else 0
        n = (len(x) - start) // length
        for k in range(n):
            sl = slice(start + k * length, start + (k + 1) * length)
            xs.append(x[sl])
            ys.append(y[sl])
    if not xs:
        raise DataError(f"no training segment holds a full lane of {length} samples")
    return np.stack(xs), np.stack(ys)


def _detach(state):
    if isinstance(state, torch.Tensor):
        return state.detach()
    return None if state is None else tuple(_detach(s) for s in state)


def training_device(device: str | torch.device | None = None) -> torch.device:
    """The device to train on: ``device`` if given, else CUDA when present, else the CPU."""
    if device is not None:
        return torch.device(device)
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def _group_val_losses(model: GroupedTorqueModel, val: list[Segment]) -> np.ndarray:
    """Normalised MSE per joint over the validation segments (eval mode)."""
    model.eval()
    sq, n = 0.0, 0
    with torch.no_grad():
        dtype, device = model.in_mean.dtype, model.in_mean.device
        for x, y in val:
            ys, _ = model.forward_normalised(torch.as_tensor(x, dtype=dtype, device=device)[None])
            pred = torch.cat(ys, -1)[0].double().cpu().numpy()
            yn = (y - model.out_mean.double().cpu().numpy()) / model.out_std.double().cpu().numpy()
            sq, n = sq + ((pred - yn) ** 2).sum(0), n + len(y)
    return sq / n


def train_recurrent(model: GroupedTorqueModel, train: list[Segment], val: list[Segment],
                    config: TrainConfig, on_epoch: Callable[[int, float], None] | None = None,
                    device: str | torch.device | None = "cpu"
                    ) -> tuple[dict[str, Any], list[float]]:
    """Train ``model`` in place (normalisation already set). Returns (validation, history).

    ``device``: where to train (None: CUDA when present); the model ends on the CPU.
    """
    rng = np.random.default_rng(config.seed)
    device = training_device(device)
    model.to(device)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.Adam(params, lr=config.lr, weight_decay=config.weight_decay)
    sched = (torch.optim.lr_scheduler.StepLR(opt, config.lr_halving_epochs, gamma=0.5)
             if config.lr_halving_epochs else None)
    dtype = model.in_mean.dtype
    mean, std = model.out_mean, model.out_std
    groups = [list(g) for g in model.groups]
    best = [np.inf] * len(groups)
    best_state = [copy.deepcopy(net.state_dict()) for net in model.nets]
    history, stale = [], 0
    lane_len = config.window * config.lane_windows
    for epoch in range(config.epochs):
        model.train()
        xs, ys = _lanes(train, lane_len, int(rng.integers(config.window)))
        order = rng.permutation(len(xs))
        for b in range(0, len(order), config.batch_size):
            idx = order[b:b + config.batch_size]
            xb = torch.as_tensor(xs[idx], dtype=dtype, device=device)
            yb = (torch.as_tensor(ys[idx], dtype=dtype, device=device) - mean) / std
            states = None
            for w in range(config.lane_windows):
                sl = slice(w * config.window, (w + 1) * config.window)
                outs, states = model.forward_normalised(xb[:, sl], states)
                states = [_detach(s) for s in states]
                loss = sum(torch.mean((o - yb[:, sl][..., g]) ** 2) for o, g in zip(outs, groups))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                if config.grad_clip:
                    for net in model.nets:
                        torch.nn.utils.clip_grad_norm_(
                            [p for p in net.parameters() if p.requires_grad], config.grad_clip)
                opt.step()
        if sched is not None:
            sched.step()
        per_joint = _group_val_losses(model, val)
        improved = False
        for k, g in enumerate(groups):
            loss_g = float(per_joint[g].mean())
            if loss_g < best[k]:
                best[k], improved = loss_g, True
                best_state[k] = copy.deepcopy(model.nets[k].state_dict())
        history.append(float(np.sqrt(per_joint).mean()))
        if on_epoch is not None:
            on_epoch(epoch, history[-1])
        stale = 0 if improved else stale + 1
        if config.patience is not None and stale >= config.patience:
            break
    for net, state in zip(model.nets, best_state):
        net.load_state_dict(state)
    model.to("cpu")
    model.eval()
    pred = np.concatenate([model.predict_sequence(x) for x, _ in val])
    target = np.concatenate([y for _, y in val])
    report = _rmse_report(pred, target, model.out_mean.double().numpy(),
                          model.out_std.double().numpy())
    return {**report, "epochs_run": len(history)}, history


def fit_free_space(series: Sequence[JointStates], model_config: FreeSpaceConfig | None = None,
                   config: TrainConfig | None = None, data: dict[str, Any] | None = None,
                   on_epoch: Callable[[int, float], None] | None = None,
                   device: str | torch.device | None = "cpu") -> TrainResult:
    """Train a step-1 model on free-space series (or on trocar series: the ``Troc`` model).

    ``device``: where to train (``None``: CUDA when present, else the CPU); the returned model
    is on the CPU.
    """
    config = config if config is not None else RECIPES["free-space"]
    train, val = split_series(series, config.val_fraction, config.max_gap_s)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = FreeSpaceModel(model_config)
        model.set_input_normalisation(np.concatenate([x for x, _ in train]))
        model.set_output_normalisation(np.concatenate([y for _, y in train]))
        validation, history = train_recurrent(model, train, val, config, on_epoch, device)
    return TrainResult("free_space", model, config, describe_data(series, data, config),
                       validation, history)


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


# -- the correction network ---------------------------------------------------------------
def predict_segments(model: GroupedTorqueModel, features: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Eval-mode torques of several gap-free segments in one batched pass.

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
        corr = Corr(corr_config).to(base.in_mean.dtype)
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
    report = _rmse_report(pred, y_va, y_tr.mean(0), scale)
    step1 = np.sqrt(np.mean((s_va - y_va) ** 2, axis=0))
    validation = {**report, "step1_rmse": step1.tolist(), "epochs_run": len(history)}
    return TrainResult("corr", corr, config, describe_data(series, data, config), validation,
                       history)
