"""The options ``wrenchd replay`` and ``wrenchd compare`` share, and their ``--config`` file.

``--config`` is a TOML or JSON file with the pipeline's settings: a ``PipelineConfig`` table,
or a daemon settings file (its first arm's ``pipeline``). ``--seed`` sets the adaptation's
seed. Torch and NumPy's BLAS run on one thread, so a replay repeats bit for bit.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from wrenchd.models.errors import ConfigError


def load_pipeline_config(path: str | None, seed: int | None = None):
    """The base ``PipelineConfig`` of a replay (see the module docstring)."""
    from wrenchd.service.pipeline import PipelineConfig

    data: dict = {}
    if path:
        text = Path(path).read_text()
        if path.endswith(".json"):
            data = json.loads(text)
        else:
            import tomllib

            data = tomllib.loads(text)
        if "arms" in data:
            data = (data["arms"] or [{}])[0].get("pipeline", {})
        elif "pipeline" in data:
            data = data["pipeline"]
    if seed is not None:
        data = {**data, "adaptation": {**data.get("adaptation", {}), "seed": seed}}
    try:
        return PipelineConfig.model_validate(data)
    except ValueError as exc:
        raise ConfigError(f"pipeline config {path}: {exc}") from exc


def common_options() -> argparse.ArgumentParser:
    """A parent parser with ``--config``, ``--seed`` and ``--model``."""
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--config", help="pipeline settings (TOML/JSON; a daemon file works)")
    common.add_argument("--seed", type=int, default=None, help="adaptation seed")
    common.add_argument("--model", default="seal",
                        help="step-1 model: shipped name (base, seal, paper-base, paper-seal) or checkpoint")
    return common
