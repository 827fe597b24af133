"""Training of the step-1 recurrent networks (``Base`` on free motion, ``Troc`` on trocar
motion); ``Xfer`` trains its new layers with the same loop.

Recurrent models train with truncated back-propagation through time: every gap-free training
segment is cut into lanes of ``window * lane_windows`` samples (cut points shifted by a random
offset each epoch); a batch of lanes is walked window by window, the LSTM state carried
(detached) from one window to the next, as in streaming inference. Each joint group keeps the
weights of its best validation epoch (the paper trains one network per group); training stops
early when no group improved for ``patience`` epochs.

With a ``checkpoint`` path, :func:`train_recurrent` saves its whole state after every epoch
(weights, optimiser, schedule, best weights per group, history, patience count, the epoch
RNG) and, when the file is there at its start, goes on from the epoch after the saved one:
a run stopped at any point (a signal, a lost machine) and started again with the same data
and recipe ends with the same weights as one that never stopped. The file also adds up the
wall time of the epochs over every sitting (``train_seconds`` in the result). A run that
stopped early (``patience``) says so in its file, and starting it again only rebuilds the
result; one that reached its epoch ceiling goes on if started with a higher one.
"""

from __future__ import annotations

import copy
import time
from typing import Any, Callable, Sequence

import numpy as np
import torch

from wrenchd.models.errors import DataError
from wrenchd.models.estimator.checkpoint import load_training_state, save_training_state
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


#: Format of :func:`train_recurrent`'s checkpoint file.
CHECKPOINT_FORMAT = 1


def _fingerprint(model: GroupedTorqueModel, train: list[Segment], val: list[Segment],
                 config: TrainConfig) -> dict[str, Any]:
    """What a checkpoint must match to be continued: the recipe (its epoch ceiling aside),
    the model's parameter shapes and the data's sizes and sums."""
    recipe = {k: v for k, v in config.model_dump().items() if k != "epochs"}
    shapes = [list(p.shape) for p in model.state_dict().values()]
    data = [[len(x), float(np.sum(x)), float(np.sum(y))] for x, y in list(train) + list(val)]
    return {"format": CHECKPOINT_FORMAT, "recipe": recipe, "shapes": shapes, "data": data}


def train_recurrent(model: GroupedTorqueModel, train: list[Segment], val: list[Segment],
                    config: TrainConfig, on_epoch: Callable[[int, float], None] | None = None,
                    device: str | torch.device | None = "cpu",
                    checkpoint: Any = None) -> tuple[dict[str, Any], list[float]]:
    """Train ``model`` in place (normalisation already set). Returns (validation, history);
    the validation's ``converged`` says whether early stopping ended the training (validation
    stalled for ``patience`` epochs) rather than the epoch ceiling, its ``train_seconds`` the
    wall time of the training epochs and their validation, over every sitting of a resumed
    one (None when a checkpoint written before this was kept does not say).

    ``device``: where to train (None: CUDA when present); the model ends on the CPU.
    ``checkpoint``: a file (path) to save the training state to after every epoch and to go
    on from (module docstring; the file access is
    :mod:`wrenchd.models.estimator.checkpoint`'s). ``on_epoch(epoch, score)`` runs once the
    epoch is saved: an exception it raises (a stop request) ends the training there, and the
    checkpoint goes on from the next epoch.

    Raises:
        DataError: ``checkpoint`` holds another run's state, or cannot be read.
    """
    rng = np.random.default_rng(config.seed)
    device = training_device(device)
    fingerprint = _fingerprint(model, train, val, config) if checkpoint is not None else None
    saved = load_training_state(checkpoint, fingerprint) if checkpoint is not None else None
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
    history, stale, first, finished = [], 0, 0, False
    spent: float | None = 0.0                  # wall time of the epochs, every sitting's
    if saved is not None:
        spent = saved.get("train_seconds")
        model.load_state_dict(saved["model"])
        opt.load_state_dict(saved["optimizer"])
        if sched is not None:
            sched.load_state_dict(saved["scheduler"])
        best, best_state = list(saved["best"]), saved["best_state"]
        history, stale = list(saved["history"]), int(saved["stale"])
        rng.bit_generator.state = saved["rng"]
        torch.set_rng_state(saved["torch_rng"])
        if saved.get("cuda_rng") is not None and device.type == "cuda":
            torch.cuda.set_rng_state_all(saved["cuda_rng"])
        first, finished = len(history), bool(saved["finished"])
    lane_len = config.window * config.lane_windows
    for epoch in range(first, 0 if finished else config.epochs):
        began = time.perf_counter()
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
        stale = 0 if improved else stale + 1
        finished = config.patience is not None and stale >= config.patience
        if spent is not None:
            spent += time.perf_counter() - began
        if checkpoint is not None:
            save_training_state(checkpoint, {
                "fingerprint": fingerprint, "model": model.state_dict(),
                "optimizer": opt.state_dict(),
                "scheduler": sched.state_dict() if sched is not None else None,
                "best": best, "best_state": best_state, "history": history, "stale": stale,
                "rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
                "cuda_rng": torch.cuda.get_rng_state_all() if device.type == "cuda" else None,
                "finished": finished, "train_seconds": spent})
        if on_epoch is not None:        # after the save: a callback that raises (a stop
            on_epoch(epoch, history[-1])  # request) leaves the epoch it saw resumable
        if finished:
            break
    for net, state in zip(model.nets, best_state):
        net.load_state_dict(state)
    model.to("cpu")
    model.eval()
    pred = np.concatenate([model.predict_sequence(x) for x, _ in val])
    target = np.concatenate([y for _, y in val])
    report = rmse_report(pred, target, model.out_mean.double().numpy(),
                          model.out_std.double().numpy())
    return {**report, "epochs_run": len(history), "converged": finished,
            "train_seconds": None if spent is None else round(spent, 2)}, history


def fit_free_space(series: Sequence[JointStates], model_config: FreeSpaceConfig | None = None,
                   config: TrainConfig | None = None, data: dict[str, Any] | None = None,
                   on_epoch: Callable[[int, float], None] | None = None,
                   device: str | torch.device | None = "cpu",
                   checkpoint: Any = None) -> TrainResult:
    """Train a step-1 model on free-space series (or on trocar series: the ``Troc`` model).

    ``device``: where to train (``None``: CUDA when present, else the CPU); the returned model
    is on the CPU. ``checkpoint``: save and resume the training there (:func:`train_recurrent`).
    """
    config = config if config is not None else RECIPES["free-space"]
    train, val = split_series(series, config.val_fraction, config.max_gap_s)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = FreeSpaceModel(model_config)
        model.set_input_normalisation(np.concatenate([x for x, _ in train]))
        model.set_output_normalisation(np.concatenate([y for _, y in train]))
        validation, history = train_recurrent(model, train, val, config, on_epoch, device,
                                              checkpoint)
    return TrainResult("free_space", model, config, describe_data(series, data, config),
                       validation, history)
