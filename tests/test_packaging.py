"""One import name: the installed project is ``wrenchd`` and nothing else."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FLOORS = ("models", "adapters", "service")


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def test_every_package_folder_is_installed_under_wrenchd():
    listed = set(_pyproject()["tool"]["setuptools"]["packages"])
    folders = {"wrenchd"} | {
        "wrenchd." + ".".join(init.parent.relative_to(ROOT).parts)
        for floor in FLOORS for init in (ROOT / floor).rglob("__init__.py")}
    assert listed == folders, (sorted(listed - folders), sorted(folders - listed))


def test_the_floors_import_only_under_wrenchd(tmp_path):
    """From a folder that is not the repository, as a user's script would."""
    ok = subprocess.run([sys.executable, "-c",
                         "import wrenchd.models, wrenchd.adapters, wrenchd.service, wrenchd;"
                         "print(wrenchd.__version__)"],
                        cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0, ok.stderr
    for floor in FLOORS:
        bare = subprocess.run([sys.executable, "-c", f"import {floor}"], cwd=tmp_path,
                              capture_output=True, text=True, timeout=60)
        assert bare.returncode != 0 and "Error" in bare.stderr, (floor, bare.stderr)
    # from the repository itself the folder is on sys.path, and the guard refuses it
    guarded = subprocess.run([sys.executable, "-c", "import models"], cwd=ROOT,
                             capture_output=True, text=True, timeout=60)
    assert guarded.returncode != 0 and "import wrenchd.models" in guarded.stderr
