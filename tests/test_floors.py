"""The three floors, checked on the source: every import of every ``.py`` under ``models/``,
``adapters/`` and ``service/`` (absolute and relative, at module level or inside functions,
and ``importlib.import_module`` of a literal name) is read with :mod:`ast`.

* ``models`` (the pure core) imports nothing of ``wrenchd.adapters`` or ``wrenchd.service``,
  and no library that does I/O: only :data:`MODELS_MAY_IMPORT`, and the few file modules of
  :data:`MODELS_FILE_ACCESS` where a model reads or writes its own state.
* ``adapters`` (I/O at the edges) imports nothing of ``wrenchd.service``.
* ``service`` reaches the wire and file-format libraries (:data:`WIRE_LIBRARIES`) only through
  ``adapters``, but for :data:`SERVICE_WIRE_EXCEPTIONS`.

The second half plants upward imports in a tree of its own and checks that each is reported:
a checker that cannot fail proves nothing.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "wrenchd"
#: the floors, lowest first: a floor imports only its own and those below it
FLOORS = ("models", "adapters", "service")

#: what models may import: the numerical libraries and the standard library's computation
#: (json: text of a model's own description; time: clocks that time a fit)
MODELS_MAY_IMPORT = frozenset({
    "numpy", "scipy", "torch", "pinocchio", "river", "pydantic", "sklearn", "statsmodels",
    "numba", "__future__", "abc", "array", "bisect", "cmath", "collections", "contextlib", "copy",
    "dataclasses", "enum", "fractions", "functools", "heapq", "itertools", "json", "math",
    "numbers", "operator", "random", "re", "statistics", "string", "textwrap", "time", "types",
    "typing", "warnings", "weakref",
})
#: file access in models, where a model saves and loads its own state (checkpoints, fitted
#: parameters, the weights shipped with the package), and the compiled kernels' switch in
#: the environment: {file: modules}
MODELS_FILE_ACCESS = {
    "models/estimator/checkpoint.py": {"os", "pathlib", "pickle"},
    "models/estimator/compiled.py": {"os", "tempfile"},
    "models/estimator/hybrid.py": {"io", "os"},
    "models/estimator/pretrained.py": {"pathlib"},
    "models/physics/model.py": {"pathlib"},
}
#: the wire and file-format libraries, which service uses through adapters
WIRE_LIBRARIES = frozenset({"zenoh", "mcap", "mcap_ros2", "rosbags", "foxglove", "zstandard",
                            "websockets"})
#: {(file, library): why it imports the library itself}
SERVICE_WIRE_EXCEPTIONS = {
    ("service/bench/stop_signals.py", "mcap"):
        "a benchmark that looks, as an outside observer would, whether the daemon it stopped "
        "left finished log files (an MCAP summary): it checks the adapters' work, not uses it",
}


def _package_of(path: Path, root: Path) -> list[str]:
    """The import name of the package holding ``path`` (``models/estimator/x.py``:
    ``wrenchd.models.estimator``), as parts."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return [PACKAGE, *parts[:-1]]


def imported_modules(path: Path, root: Path) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in the file at ``path``; a relative
    import is resolved against the file's package, and ``from wrenchd.X import name`` also
    names ``wrenchd.X.name`` (it may be a module: ``from wrenchd import service``)."""
    package = _package_of(path, root)
    out: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            out.append((node.lineno, module))
            if module.split(".")[0] == PACKAGE:        # a name there may be a floor's module
                out += [(node.lineno, f"{module}.{alias.name}") for alias in node.names
                        if alias.name != "*"]
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
              and node.func.attr == "import_module" and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            out.append((node.lineno, node.args[0].value))
    return out


def _floor_of(module: str) -> str | None:
    parts = module.split(".")
    if len(parts) > 1 and parts[0] == PACKAGE and parts[1] in FLOORS:
        return parts[1]
    return None


def floor_violations(root: Path) -> list[str]:
    """Every import under ``root``'s floors that breaks a rule (module docstring), as
    ``file:line: what``."""
    found = []
    for floor in FLOORS:
        for path in sorted((root / floor).rglob("*.py")):
            where = path.relative_to(root).as_posix()
            for line, module in imported_modules(path, root):
                top = module.split(".")[0]
                target = _floor_of(module)
                if target is not None and FLOORS.index(target) > FLOORS.index(floor):
                    found.append(f"{where}:{line}: {floor} imports {module}, a floor above it")
                elif (floor == "models" and top != PACKAGE and top not in MODELS_MAY_IMPORT
                      and top not in MODELS_FILE_ACCESS.get(where, ())):
                    found.append(f"{where}:{line}: models imports {module}, not computation")
                elif (floor == "service" and top in WIRE_LIBRARIES
                      and (where, top) not in SERVICE_WIRE_EXCEPTIONS):
                    found.append(f"{where}:{line}: service imports {module}, not through "
                                 f"adapters")
    return sorted(set(found))


def test_the_floors_hold():
    assert floor_violations(ROOT) == []


def test_every_exception_is_still_needed():
    """An exception whose import is gone goes too, so the lists say what is true."""
    for where, modules in MODELS_FILE_ACCESS.items():
        used = {m.split(".")[0] for _, m in imported_modules(ROOT / where, ROOT)}
        assert modules <= used, (where, modules - used)
    for where, library in SERVICE_WIRE_EXCEPTIONS:
        used = {m.split(".")[0] for _, m in imported_modules(ROOT / where, ROOT)}
        assert library in used, (where, library)


def _plant(root: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_checker_reports_upward_imports(tmp_path):
    _plant(tmp_path, {
        "models/__init__.py": "",
        "models/fine.py": "import math\nimport numpy as np\nfrom . import series\n"
                          "from .physics import model\nfrom wrenchd.models.errors import X\n",
        "models/physics/__init__.py": "",
        "models/physics/up.py": "from ...service import pipeline\n",
        "models/physics/up2.py": "def f():\n    from ...adapters.messages import decode\n",
        "models/absolute.py": "import wrenchd.adapters.zenoh_io\n",
        "models/wire.py": "import zenoh\n",
        "models/net.py": "import socket\nimport subprocess\n",
        "models/dynamic.py": "import importlib\nimportlib.import_module('wrenchd.service.cli')\n",
        "adapters/__init__.py": "",
        "adapters/fine.py": "import zenoh\nfrom wrenchd.models.series import JointStates\n"
                            "from . import ros2_msgs\n",
        "adapters/up.py": "from ..service.replay import loop\n",
        "adapters/from_root.py": "from wrenchd import service\n",
        "service/__init__.py": "",
        "service/fine.py": "from wrenchd.adapters.zenoh_io import open_session\n"
                           "from ..models import series\nimport subprocess\n",
        "service/wire.py": "def f():\n    from mcap.reader import make_reader\n",
    })
    found = floor_violations(tmp_path)
    reported = {line.split(":")[0] for line in found}
    assert reported == {
        "models/physics/up.py", "models/physics/up2.py", "models/absolute.py",
        "models/wire.py", "models/net.py", "models/dynamic.py", "adapters/up.py",
        "adapters/from_root.py", "service/wire.py"}, found
    assert "models/physics/up.py:1: models imports wrenchd.service, a floor above it" in found
    assert ("models/physics/up2.py:2: models imports wrenchd.adapters.messages, a floor above "
            "it") in found
    assert "adapters/up.py:1: adapters imports wrenchd.service.replay, a floor above it" in found
    assert "service/wire.py:2: service imports mcap.reader, not through adapters" in found
    assert len([line for line in found if line.startswith("models/net.py")]) == 2
