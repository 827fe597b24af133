"""Training of the step-1 recurrent networks (``Base`` on free motion, ``Troc`` on trocar
motion); ``Xfer`` trains its new layers with the same loop.

Recurrent models train with truncated back-propagation through time: every gap-free training
segment is cut into lanes of ``window * lane_windows`` samples (cut points shifted by a random
offset each epoch); a batch of lanes is walked window by window, the LSTM state carried
(detached) from one window to the next, as in streaming inference. Each joint group keeps the
weights of its best validation epoch (the paper trains one network per group); training stops
early when no group improved for ``patience`` epochs.
"""

from __future__ import annotations

import copy
from typing import Any, Callable, Sequence

import numpy as np
import torch

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.free_space import FreeSpaceConfig, FreeSpaceModel, GroupedTorqueModel
from wrenchd.models.estimator.training import (
    RECIPES,
    Segment,
    TrainConfig,
    TrainResult,
    describe_data,
    rmse_report,
    split_series,
    training_device,
)
from wrenchd.models.series import JointStates


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
    report = rmse_report(pred, target, model.out_mean.double().numpy(),
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
