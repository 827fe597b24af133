"""``wrenchd effects``: the effect vocabulary of model files, with parameters and defaults."""

from __future__ import annotations

import argparse


def list_effects(args: argparse.Namespace) -> int:
    from wrenchd.models.physics.effects import EFFECTS

    for name, cls in sorted(EFFECTS.items()):
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        print(f"{name}: {doc}")
        for field, info in cls.Params.model_fields.items():
            default = "required" if info.is_required() else repr(info.default)
            print(f"    {field} = {default}  # {info.description or ''}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("effects", help="list the effects a model file can use")
    p.set_defaults(func=list_effects)
