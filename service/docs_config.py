"""The defaults tables of ``docs/configuration.md``, generated from the settings models.

    python -m wrenchd.service.docs_config           # print the generated section
    python -m wrenchd.service.docs_config --write   # put it into docs/configuration.md

Every key of the daemon's settings file, table by table (``[arms.pipeline.gate]`` and the
rest of the per-arm pipeline included), with its default and the field's description, read
from :class:`~wrenchd.service.runtime.settings.ServiceSettings` and the models it nests. The
page holds the section between two markers; a test regenerates it and compares, so the page
cannot drift from the code.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, Iterator

from pydantic import BaseModel

PAGE = Path(__file__).resolve().parents[1] / "docs" / "configuration.md"
BEGIN = ("<!-- defaults: generated from the settings models by "
         "`python -m wrenchd.service.docs_config --write`; edit the models, not this table -->")
END = "<!-- defaults: end -->"


def _default(value: Any) -> str:
    """A default as it is written in the TOML file (``unset`` for None)."""
    if value is None:
        return "unset"
    if isinstance(value, BaseModel):
        value = value.model_dump(mode="json")
    text = json.dumps(value, default=str, ensure_ascii=False)
    return "`" + text.replace("|", "\\|") + "`"


def _text(description: str | None) -> str:
    return " ".join((description or "").split()).replace("|", "\\|")


def _tables(model: BaseModel, path: str, title: str
            ) -> Iterator[tuple[str, str, list[tuple[str, str, str]]]]:
    """(table title, model class, rows of key, default, meaning) of ``model`` and of the
    models it nests, with the defaults of the instance ``model`` (a nested default may differ
    from its class's, as the daemon's zenoh listen address does)."""
    rows, nested = [], []
    for key, field in type(model).model_fields.items():
        value = getattr(model, key)
        inner = f"{path}.{key}" if path else key
        if isinstance(value, BaseModel):
            nested.append((value, inner, f"[{inner}]"))
        elif (isinstance(value, list) and value
              and all(isinstance(v, BaseModel) for v in value)):
            nested.append((value[0], inner, f"[[{inner}]]"))
        else:
            rows.append((key, _default(value), _text(field.description)))
    yield title, type(model).__name__, rows
    for value, inner, inner_title in nested:
        yield from _tables(value, inner, inner_title)


def markdown() -> str:
    """The generated section: one table per settings table, in the order of the models."""
    from wrenchd.service.runtime.settings import ServiceSettings

    defaults = ServiceSettings.model_construct(**{
        k: f.get_default(call_default_factory=True)
        for k, f in ServiceSettings.model_fields.items()})
    out = [BEGIN, "", "## Every key and its default", "",
           "Read from the settings models (`service/runtime/settings.py` and the models it "
           "nests); `unset` is None. The tables nested in `[[arms]]` are written "
           "`[arms.pipeline.gate]` and so on, as in the example above.", ""]
    for title, model_name, rows in _tables(defaults, "", "top level"):
        if not rows:
            continue
        out += [f"### {title if title == 'top level' else f'`{title}`'} ({model_name})", "",
                "| key | default | meaning |", "|---|---|---|"]
        out += [f"| `{k}` | {d} | {m} |" for k, d, m in rows]
        out.append("")
    out.append(END)
    return "\n".join(out) + "\n"


def render_page(page: str) -> str:
    """``page`` with its generated section replaced by a fresh one (appended if absent)."""
    section = markdown()
    if BEGIN in page and END in page:
        head, rest = page.split(BEGIN, 1)
        tail = rest.split(END, 1)[1]
        return head + section.rstrip("\n") + tail
    return page.rstrip("\n") + "\n\n" + section


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m wrenchd.service.docs_config",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true",
                        help=f"update the section of {PAGE.name} in place")
    args = parser.parse_args(argv)
    if args.write:
        PAGE.write_text(render_page(PAGE.read_text()))
    else:
        print(markdown(), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
