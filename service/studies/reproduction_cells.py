"""A reproduction run's finished cells, each in a small file that goes into version control.

A paper-scale run takes days of CPU in sittings of a few hours, on whichever machine is free.
Its per-epoch checkpoints (``OUT/checkpoints``, tens of MB) stay on the machine that wrote
them; a cell's scores do not need them. After each (training seed, length) cell the run
writes ``OUT/cells/seed{S}-L{length}.npz``: every trained configuration's per-trial scores,
training time and fit. A later sitting, on this machine or on a fresh clone, reads the cells
it finds instead of training them again, so the tables and intervals come out as if the run
had never stopped.

A cell names the configuration it was run under (:func:`fingerprint`); a cell of another
configuration in the same folder is refused, never mixed in.
"""

from __future__ import annotations

import hashlib
import json
import os
import zipfile
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

from wrenchd.models.errors import DataError
from wrenchd.service.studies.reproduction_config import ReproductionConfig
from wrenchd.service.studies.reproduction_results import Fit
from wrenchd.service.studies.reproduction_scoring import ModelScores

#: the folder under ``--out`` that holds the finished cells
CELLS = "cells"
FORMAT = 1
_TABLES = ("contact", "no_contact")


class Cell(BaseModel):
    """One finished (training seed, length) cell as :meth:`Collected.add_cell` takes it."""

    model_config = ConfigDict(arbitrary_types_allowed=True, frozen=True)

    seed: int
    length_s: float
    seconds: dict[str, float]
    fits: dict[str, Fit]
    scores: ModelScores


def fingerprint(config: ReproductionConfig) -> str:
    """SHA-256 (16 hex digits) of every field of ``config``: what makes the cells' numbers."""
    return hashlib.sha256(config.model_dump_json().encode()).hexdigest()[:16]


def cell_path(folder: Path, seed: int, length_s: float) -> Path:
    return Path(folder) / f"seed{seed}-L{length_s:g}.npz"


def save_cell(folder: Path, config: ReproductionConfig, cell: Cell) -> Path:
    """Write ``cell`` (to a temporary file, then renamed: a stop leaves no half cell)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {}
    for table in _TABLES:
        for name, trial in getattr(cell.scores, table).items():
            for ref, metrics in trial.items():
                for metric, value in metrics.items():
                    arrays[f"{table}/{name}/{ref}/{metric}"] = np.asarray(value)
    meta = {"format": FORMAT, "fingerprint": fingerprint(config), "seed": cell.seed,
            "length_s": cell.length_s, "seconds": cell.seconds,
            "fits": {k: f.model_dump(mode="json") for k, f in cell.fits.items()}}
    path = cell_path(folder, cell.seed, cell.length_s)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, meta=np.array(json.dumps(meta)), **arrays)
    os.replace(tmp, path)
    return path


def load_cell(folder: Path, config: ReproductionConfig, seed: int,
              length_s: float) -> Cell | None:
    """The cell of ``seed`` and ``length_s`` under ``folder``, or None when there is none.

    Raises:
        DataError: the file is not a cell, or a cell of another configuration.
    """
    path = cell_path(folder, seed, length_s)
    if not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in z.files if k != "meta"}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise DataError(f"{path}: not a reproduction cell ({exc})") from exc
    if meta.get("format") != FORMAT:
        raise DataError(f"{path}: cell format {meta.get('format')!r}, this wrenchd reads "
                        f"{FORMAT}")
    if meta.get("fingerprint") != fingerprint(config):
        raise DataError(f"{path}: a cell of another configuration (fingerprint "
                        f"{meta.get('fingerprint')}, this run's {fingerprint(config)}); "
                        "give this run its own --out, or remove the cells")
    if meta.get("seed") != seed or float(meta.get("length_s")) != float(length_s):
        raise DataError(f"{path}: holds seed {meta.get('seed')} at {meta.get('length_s')} s")
    tables: dict[str, dict] = {t: {} for t in _TABLES}
    for key, value in arrays.items():
        table, name, ref, metric = key.split("/")
        tables[table].setdefault(name, {}).setdefault(ref, {})[metric] = value
    return Cell(seed=seed, length_s=float(length_s),
                seconds={k: float(v) for k, v in meta["seconds"].items()},
                fits={k: Fit.model_validate(v) for k, v in meta["fits"].items()},
                scores=ModelScores(**tables))
