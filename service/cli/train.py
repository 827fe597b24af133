"""``wrenchd train``: train one network of the two-step estimator from a config file.

Training is a command of its own so that a network's checkpoint follows from one file: the
config (TOML or JSON, a :class:`TrainCommandConfig`, example below and in
docs/estimator-and-training.md) names the configuration (base, troc, corr or xfer), the
recipe, the seed of every random choice, the data (simulated scenarios or recordings) and the
output. Relative paths (data, output, base checkpoint) are taken from the working directory.
Training runs on the CPU, or on a CUDA GPU when torch sees one (``--device`` overrides). The
checkpoint carries the config, the format version, a description of the data, the validation
score (the last ``val_fraction`` of every series, see
:mod:`wrenchd.models.estimator.training`) and the provenance of the run.
"""

from __future__ import annotations

import argparse
import json

#: a config file, shown by ``wrenchd train --help``
EXAMPLE = """\
example config:

    configuration = "base"            # base | troc | corr | xfer
    recipe = "free-space"             # a name of wrenchd.models.estimator.training.RECIPES (default
                                      # per configuration: free-space, troc, corr, xfer)
    seed = 0                          # every random choice (weights, order, dropout)
    output = "sim-base.pt"
    base_checkpoint = "pretrained:base"   # corr and xfer only: a path or pretrained:<name>

    [overrides]                       # fields of the recipe (TrainConfig) replaced
    epochs = 60

    [[data]]                          # simulated data: a scenario, a length and a seed
    scenario = "free-space"
    duration_s = 60
    seed = 100

    [[data]]                          # or a recording: MCAP or CSV (WPI or paper layout)
    path = "sessions/psm1.mcap"
"""


def train_network(args: argparse.Namespace) -> int:
    import torch

    from wrenchd.service.studies.training import read_train_config, train

    if args.threads:
        torch.set_num_threads(args.threads)
    config = read_train_config(args.config)
    summary = train(config, output=args.output, device=args.device,
                    progress=not args.no_progress)
    print(json.dumps(summary, indent=2))
    return 0


def register(subparsers) -> None:
    """Add ``wrenchd train`` to the CLI."""
    p = subparsers.add_parser("train", help="train a step-1 or step-2 network from a config",
                              description=__doc__, epilog=EXAMPLE,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, help="training config (.toml or .json)")
    p.add_argument("--output", help="checkpoint path (replaces the config's output)")
    p.add_argument("--device", help="cpu, cuda, cuda:1 ... (default: CUDA when present)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=train_network)
