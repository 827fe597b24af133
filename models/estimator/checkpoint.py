"""Self-describing checkpoints of the estimator's networks, and the training loop's resumable
state (:func:`save_training_state`; plain values and tensors too).

A checkpoint is one ``torch.save``'d dict of plain values and tensors::

    {"format": "wrenchd.estimator", "version": 1, "kind": "free_space" | "corr" | "xfer",
     "config": JSON string {"model": {...}, "train": {...} or null},
     "state_dict": {name: tensor}, "dtype": "float32" | "float64",
     "data": {...}, "validation": {...}}

It is read back with ``torch.load(weights_only=True)``: a file holding anything but plain
containers, numbers, strings and tensors (a pickled object) is refused by the loader before
any of it runs, and anything that is not this dict is refused after.
"""

from __future__ import annotations

import json
import os
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from pydantic import BaseModel, ValidationError

from wrenchd.models.errors import ConfigError, DataError
from wrenchd.models.estimator.correction import Corr, CorrConfig, Xfer, XferConfig
from wrenchd.models.estimator.free_space import FreeSpaceConfig, FreeSpaceModel
from wrenchd.models.estimator.training import TrainConfig, TrainResult

FORMAT = "wrenchd.estimator"
VERSION = 1
KINDS: dict[str, tuple[type[BaseModel], type[torch.nn.Module]]] = {
    "free_space": (FreeSpaceConfig, FreeSpaceModel),
    "corr": (CorrConfig, Corr),
    "xfer": (XferConfig, Xfer),
}
_DTYPES = {"float32": torch.float32, "float64": torch.float64}


@dataclass(frozen=True)
class Checkpoint:
    """A loaded checkpoint: the rebuilt model (eval mode) and what was recorded with it."""

    kind: str
    model: torch.nn.Module
    train_config: TrainConfig | None
    data: dict[str, Any]
    validation: dict[str, Any]
    version: int


def _kind_of(model: torch.nn.Module) -> str:
    for kind, (_, cls) in KINDS.items():
        if type(model) is cls:
            return kind
    raise ConfigError(f"cannot checkpoint a {type(model).__name__}; expected one of "
                      f"{[c.__name__ for _, c in KINDS.values()]}")


def _plain(value: Any, what: str) -> Any:
    try:
        return json.loads(json.dumps(value if value is not None else {}))
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{what} must be JSON-serialisable: {exc}") from exc


def save_checkpoint(path: str | os.PathLike, model: torch.nn.Module,
                    train_config: TrainConfig | None = None, data: dict[str, Any] | None = None,
                    validation: dict[str, Any] | None = None) -> None:
    """Write ``model`` with its configs, data description and validation score to ``path``."""
    kind = _kind_of(model)
    dtype = next(model.buffers()).dtype
    config = {"model": model.config.model_dump(mode="json"),
              "train": None if train_config is None else train_config.model_dump(mode="json")}
    payload = {
        "format": FORMAT, "version": VERSION, "kind": kind, "config": json.dumps(config),
        "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
        "dtype": str(dtype).removeprefix("torch."),
        "data": _plain(data, "data"), "validation": _plain(validation, "validation"),
    }
    torch.save(payload, os.fspath(path))


def prune_checkpoints(directory: str | os.PathLike, pattern: str, keep: int,
                      protect: set[str] = frozenset()) -> list[tuple[str, int]]:
    """Remove the checkpoints named ``pattern`` (a glob) in ``directory`` but the newest
    ``keep`` (by modification time, then name) and those in ``protect`` (paths).

    Returns the removed files and their sizes [B], oldest first.

    Raises:
        OSError: a file could not be removed (those before it are; a file removed by someone
            else meanwhile is skipped).
    """
    if keep < 1:
        raise ValueError(f"keep must be at least 1, got {keep}")
    files = []
    for path in Path(directory).glob(pattern):
        try:
            st = path.stat()
        except FileNotFoundError:
            continue
        files.append((st.st_mtime, path.name, st.st_size, path))
    files.sort()
    kept = {os.path.abspath(p) for p in protect}
    removed = []
    for _, _, size, path in files[:max(len(files) - keep, 0)]:
        if os.path.abspath(path) in kept:
            continue
        try:
            path.unlink()
        except FileNotFoundError:
            continue
        removed.append((str(path), size))
    return removed


def save_result(path: str | os.PathLike, result: TrainResult) -> None:
    """Write a :class:`TrainResult` as a checkpoint."""
    save_checkpoint(path, result.model, result.train_config, result.data, result.validation)


def load_checkpoint(path: str | os.PathLike) -> Checkpoint:
    """Read and rebuild a checkpoint written by :func:`save_checkpoint`.

    Raises:
        ConfigError: the file is unreadable, holds pickled objects, is not a wrenchd estimator
            checkpoint, has another version, or its weights do not fit its config.
    """
    where = os.fspath(path)
    try:
        payload = torch.load(where, map_location="cpu", weights_only=True)
    except FileNotFoundError as exc:
        raise ConfigError(f"{where}: no such checkpoint") from exc
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, OSError) as exc:
        raise ConfigError(f"{where}: refused, not a safe wrenchd checkpoint "
                          f"(torch.load weights_only): {exc}") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise ConfigError(f"{where}: refused, not a wrenchd estimator checkpoint "
                          f"(got {type(payload).__name__})")
    if payload.get("version") != VERSION:
        raise ConfigError(f"{where}: checkpoint version {payload.get('version')!r}, "
                          f"this wrenchd reads version {VERSION}")
    kind, dtype = payload.get("kind"), _DTYPES.get(payload.get("dtype"))
    if kind not in KINDS or dtype is None:
        raise ConfigError(f"{where}: unknown kind {kind!r} or dtype {payload.get('dtype')!r}")
    config_cls, model_cls = KINDS[kind]
    try:
        config = json.loads(payload["config"])
        model = model_cls(config_cls(**config["model"])).to(dtype)
        train = None if config.get("train") is None else TrainConfig(**config["train"])
        state = payload["state_dict"]
        if not (isinstance(state, dict)
                and all(isinstance(v, torch.Tensor) for v in state.values())):
            raise TypeError("state_dict must map names to tensors")
        model.load_state_dict(state, strict=True)
    except (KeyError, TypeError, ValueError, RuntimeError, ValidationError) as exc:
        raise ConfigError(f"{where}: invalid checkpoint content: {exc}") from exc
    model.eval()
    rmse = (payload.get("validation") or {}).get("rmse")
    if kind == "free_space" and rmse is not None:
        # the free-motion residual scale of step 1, for the pipeline's calibration guard
        model.validation_rmse = tuple(float(v) for v in rmse)
    return Checkpoint(kind, model, train, dict(payload.get("data") or {}),
                      dict(payload.get("validation") or {}), VERSION)


def save_training_state(path: str | os.PathLike, state: dict[str, Any]) -> None:
    """Write a training loop's state (:func:`~wrenchd.models.estimator.free_space_training.
    train_recurrent`) to ``path`` atomically: a stop while writing leaves the last one."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def load_training_state(path: str | os.PathLike, fingerprint: dict[str, Any]
                        ) -> dict[str, Any] | None:
    """The training state saved at ``path`` (None: no file yet).

    Raises:
        DataError: the file cannot be read, or holds another run's state (its
            ``fingerprint`` differs: recipe, model or data).
    """
    path = Path(path)
    if not path.is_file():
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:                       # noqa: BLE001 - any unreadable file
        raise DataError(f"{path}: not a readable training checkpoint ({exc})") from None
    if not isinstance(state, dict) or state.get("fingerprint") != fingerprint:
        raise DataError(f"{path}: a checkpoint of another training run (recipe, model or "
                        "data differ); remove it to start afresh")
    return state
