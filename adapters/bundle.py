"""Model bundles: one directory with everything a fitted arm model needs to be served.

Layout (format ``wrenchd.bundle``, version 1)::

    manifest.json   format, version, arm, origin ("robot" or "simulator"), creation time (UTC),
                    wrenchd version, sha256 of the data files it was fitted on, sha256 of every
                    other file of the bundle, the step-1 weights' configuration
    physics.json    the identified physics model (a JSON object, e.g. PhysicsModel.to_dict())
    step1.pt        optional: step-1 network weights, a state dict {name: tensor}
    report.md       the fit report for people
    report.json     the same figures for programs

Reading checks the format and version, that every file the manifest lists is there with its
digest and that nothing else is, and loads the weights with ``torch.load(weights_only=True)``
(a pickled object is refused before any of it runs). The bundle's own digest, sha256 over the
names and digests of all its files (manifest included), identifies it in status and logs.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import importlib.metadata
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from wrenchd.models.errors import AdapterError, ConfigError, DataError

FORMAT = "wrenchd.bundle"
VERSION = 1
ORIGINS = ("robot", "simulator")
MANIFEST = "manifest.json"
PHYSICS = "physics.json"
WEIGHTS = "step1.pt"
REPORT_MD = "report.md"
REPORT_JSON = "report.json"
_ARM = re.compile(r"^[A-Za-z][A-Za-z0-9_-]{0,31}$")
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
_CHUNK = 1 << 20


@dataclass(frozen=True)
class Bundle:
    """A model bundle's content.

    Attributes:
        arm: the arm it was fitted for, e.g. ``"PSM1"``.
        origin: ``"robot"`` (real recordings) or ``"simulator"``.
        physics: the identified physics model (JSON object).
        report_md, report: the fit report, text and JSON.
        data: ``{file name: sha256}`` of the data it was fitted on.
        weights: step-1 state dict ``{name: torch.Tensor}``, or None.
        weights_config: what rebuilds the step-1 network (JSON object), or None.
        created_utc: ISO 8601 creation time, ``...Z``.
        wrenchd_version: the package version that wrote it.
        digest: sha256 over the bundle's files (:func:`bundle_digest`); equality of two
            bundles compares it, not the weight tensors (whose file it covers).
        path: where it was read from or written to.
    """

    arm: str
    origin: str
    physics: dict[str, Any]
    report_md: str
    report: dict[str, Any]
    data: dict[str, str]
    weights: dict[str, Any] | None = field(default=None, compare=False)
    weights_config: dict[str, Any] | None = None
    created_utc: str = ""
    wrenchd_version: str = ""
    digest: str = ""
    path: Path | None = field(default=None, compare=False)


def file_sha256(path: str | os.PathLike[str]) -> str:
    """sha256 (hex) of a file's bytes, or of a directory (a rosbag2): over each file's
    relative path and sha256, in sorted order."""
    path = Path(path)
    try:
        if path.is_dir():
            lines = [f"{p.relative_to(path).as_posix()}\0{file_sha256(p)}\n"
                     for p in sorted(path.rglob("*")) if p.is_file()]
            return hashlib.sha256("".join(lines).encode()).hexdigest()
        h = hashlib.sha256()
        with open(path, "rb") as f:
            while chunk := f.read(_CHUNK):
                h.update(chunk)
        return h.hexdigest()
    except OSError as exc:
        raise AdapterError(f"cannot read {path}: {exc}") from None


def _digest_of(files: Mapping[str, str]) -> str:
    lines = "".join(f"{name}\0{files[name]}\n" for name in sorted(files))
    return hashlib.sha256(lines.encode()).hexdigest()


def bundle_digest(path: str | os.PathLike[str]) -> str:
    """sha256 over the names and sha256 of every file in the bundle directory."""
    path = Path(path)
    return _digest_of({p.name: file_sha256(p) for p in path.iterdir() if p.is_file()})


def _plain(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"{type(value).__name__} is not JSON-serialisable")


def _json_text(value: Any, what: str) -> str:
    if not isinstance(value, dict):
        raise DataError(f"{what} must be a JSON object (dict), got {type(value).__name__}")
    try:
        return json.dumps(value, default=_plain, allow_nan=False, indent=2) + "\n"
    except (TypeError, ValueError) as exc:
        raise DataError(f"{what} must be JSON-serialisable with finite numbers: {exc}") from None


def _check_weights(weights: Any, where: str) -> dict[str, Any]:
    import torch

    if not isinstance(weights, dict) or not all(
            isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in weights.items()):
        raise ConfigError(f"{where}: step-1 weights must be a state dict {{name: tensor}}")
    return weights


def _utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def write_bundle(path: str | os.PathLike[str], *, arm: str, origin: str,
                 physics: dict[str, Any], report_md: str, report: dict[str, Any],
                 data_files: Sequence[str | os.PathLike[str]],
                 weights: dict[str, Any] | None = None,
                 weights_config: dict[str, Any] | None = None,
                 created_utc: str | None = None) -> Bundle:
    """Writes a new bundle directory at ``path`` and returns it as read back.

    Args:
        arm: arm name (letters, digits, ``_``, ``-``; e.g. ``PSM1``).
        origin: ``"robot"`` or ``"simulator"``.
        physics: the identified physics model, a JSON object (numpy arrays become lists).
        report_md, report: the fit report, as Markdown and as a JSON object.
        data_files: the files (or rosbag2 directories) it was fitted on; at least one; their
            base names must differ.
        weights: optional step-1 state dict ``{name: tensor}`` (saved with ``torch.save``).
        weights_config: optional JSON object that rebuilds the step-1 network.
        created_utc: ISO 8601 time to record (default: now).

    Raises:
        DataError: a bad argument (origin, arm, non-JSON content, no data files, ...).
        ConfigError: ``weights`` is not a state dict.
        AdapterError: ``path`` exists, a data file cannot be read, or writing fails.
    """
    path = Path(path)
    if origin not in ORIGINS:
        raise DataError(f"origin must be one of {list(ORIGINS)}, got {origin!r}")
    if not isinstance(arm, str) or not _ARM.match(arm):
        raise DataError(f"arm must be a name like 'PSM1', got {arm!r}")
    if not isinstance(report_md, str):
        raise DataError("report_md must be text")
    if not data_files:
        raise DataError("a bundle records the data it was fitted on: give data_files")
    data: dict[str, str] = {}
    for f in data_files:
        name = Path(f).name
        if name in data:
            raise DataError(f"two data files are named {name!r}; rename one")
        if not Path(f).exists():
            raise AdapterError(f"data file {f} does not exist")
        data[name] = file_sha256(f)
    texts = {PHYSICS: _json_text(physics, "physics"), REPORT_JSON: _json_text(report, "report"),
             REPORT_MD: report_md}
    if weights_config is not None:
        _json_text(weights_config, "weights_config")
    if weights is None and weights_config is not None:
        raise DataError("weights_config given without weights")
    if path.exists():
        raise AdapterError(f"{path} exists; a bundle is written to a new path")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{path.name}-", dir=path.parent))
    except OSError as exc:
        raise AdapterError(f"cannot write bundle {path}: {exc}") from None
    try:
        for name, text in texts.items():
            (staging / name).write_text(text, encoding="utf-8")
        if weights is not None:
            import torch

            _check_weights(weights, "write_bundle")
            torch.save({k: v.detach().cpu().clone() for k, v in weights.items()},
                       staging / WEIGHTS)
        files = {p.name: file_sha256(p) for p in sorted(staging.iterdir())}
        manifest = {
            "format": FORMAT, "version": VERSION, "arm": arm, "origin": origin,
            "created_utc": created_utc or _utc_now(),
            "wrenchd_version": importlib.metadata.version("wrenchd"),
            "data": data, "files": files,
            "weights": None if weights is None else {"file": WEIGHTS, "config": weights_config},
        }
        (staging / MANIFEST).write_text(_json_text(manifest, "manifest"), encoding="utf-8")
        staging.rename(path)
    except OSError as exc:
        raise AdapterError(f"cannot write bundle {path}: {exc}") from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return read_bundle(path)


def _load_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise AdapterError(f"cannot read {path}: {exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: {what} is not JSON: {exc}") from None


def _manifest(path: Path) -> dict[str, Any]:
    if not path.is_dir():
        raise AdapterError(f"no bundle directory at {path}")
    if not (path / MANIFEST).is_file():
        raise ConfigError(f"{path} is not a model bundle: it has no {MANIFEST}")
    m = _load_json(path / MANIFEST, "the manifest")
    where = path / MANIFEST
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        got = m.get("format") if isinstance(m, dict) else type(m).__name__
        raise ConfigError(f"{where}: format is {got!r}, expected {FORMAT!r}")
    if "version" not in m:
        raise ConfigError(f"{where}: no format version; this wrenchd reads version {VERSION}")
    if m["version"] != VERSION:
        raise ConfigError(f"{where}: format version {m['version']!r} is unknown; this wrenchd "
                          f"reads version {VERSION}")
    required = ("arm", "origin", "created_utc", "wrenchd_version", "data", "files", "weights")
    missing = [k for k in required if k not in m]
    if missing:
        raise ConfigError(f"{where}: missing {missing}")
    if m["origin"] not in ORIGINS:
        raise ConfigError(f"{where}: origin {m['origin']!r} is not one of {list(ORIGINS)}")
    for key in ("data", "files"):
        table = m[key]
        if not isinstance(table, dict) or not all(
                isinstance(v, str) and _SHA256.match(v) for v in table.values()):
            raise ConfigError(f"{where}: {key!r} must map names to sha256 digests")
    if not m["data"]:
        raise ConfigError(f"{where}: records no data files")
    return m


def read_bundle(path: str | os.PathLike[str]) -> Bundle:
    """Reads and verifies a bundle directory.

    Raises:
        AdapterError: no such directory, or a file cannot be read.
        ConfigError: not a bundle, missing or unknown format version, a file missing, extra,
            or not matching its digest, content of the wrong kind.
    """
    path = Path(path)
    m = _manifest(path)
    files: dict[str, str] = m["files"]
    for name in (PHYSICS, REPORT_MD, REPORT_JSON):
        if name not in files:
            raise ConfigError(f"{path / MANIFEST}: does not list {name}")
    weights_entry = m["weights"]
    if (weights_entry is not None) != (WEIGHTS in files):
        raise ConfigError(f"{path / MANIFEST}: the weights entry and the listed files disagree")
    present = {p.name for p in path.iterdir()} - {MANIFEST}
    extra, absent = sorted(present - set(files)), sorted(set(files) - present)
    if absent:
        raise ConfigError(f"bundle {path}: {absent} listed in the manifest but missing")
    if extra:
        raise ConfigError(f"bundle {path}: {extra} not listed in the manifest (a bundle is "
                          f"written whole; make a new one instead of adding files)")
    for name, expected in files.items():
        got = file_sha256(path / name)
        if got != expected:
            raise ConfigError(f"bundle {path}: {name} has sha256 {got[:12]}..., the manifest "
                              f"records {expected[:12]}...: the file changed after writing")
    physics = _load_json(path / PHYSICS, "physics")
    report = _load_json(path / REPORT_JSON, "the report")
    for what, value in (("physics", physics), ("report.json", report)):
        if not isinstance(value, dict):
            raise ConfigError(f"bundle {path}: {what} must be a JSON object")
    weights = config = None
    if weights_entry is not None:
        import pickle

        import torch

        try:
            weights = torch.load(path / WEIGHTS, map_location="cpu", weights_only=True)
        except (pickle.UnpicklingError, RuntimeError, EOFError) as exc:
            raise ConfigError(f"bundle {path}: {WEIGHTS} is not a plain state dict: "
                              f"{str(exc).splitlines()[0]}") from None
        _check_weights(weights, f"bundle {path}")
        config = weights_entry.get("config") if isinstance(weights_entry, dict) else None
    return Bundle(arm=m["arm"], origin=m["origin"], physics=physics,
                  report_md=(path / REPORT_MD).read_text(encoding="utf-8"), report=report,
                  data=dict(m["data"]), weights=weights, weights_config=config,
                  created_utc=m["created_utc"], wrenchd_version=m["wrenchd_version"],
                  digest=bundle_digest(path), path=path)


def check_data(bundle: Bundle, data_files: Sequence[str | os.PathLike[str]]) -> None:
    """Checks that ``data_files`` are the data the bundle was fitted on (same names, digests).

    Raises:
        DataError: a file the bundle does not know, or whose digest differs.
    """
    for f in data_files:
        name = Path(f).name
        if name not in bundle.data:
            raise DataError(f"{name} is not among the data the bundle was fitted on: "
                            f"{sorted(bundle.data)}")
        got = file_sha256(f)
        if got != bundle.data[name]:
            raise DataError(f"{f}: sha256 {got[:12]}... differs from the {bundle.data[name][:12]}"
                            f"... the bundle was fitted on")
