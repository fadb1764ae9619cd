"""Layers: ``sb3_pola.common`` never imports the algorithm (``sb3_pola.pola``); the peers worker runs without ``sb3_pola``."""

from __future__ import annotations

import ast
import pathlib
import subprocess
import sys

import sb3_pola

PACKAGE = pathlib.Path(sb3_pola.__file__).resolve().parent
COMMON = PACKAGE / "common"


def imported_modules(path: pathlib.Path) -> list[str]:
    """Every module a file imports, at the top, in functions or under ``TYPE_CHECKING`` (relative imports resolved)."""
    package = list(path.relative_to(PACKAGE.parent).parts[:-1])  # e.g. ["sb3_pola", "common"]
    names = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            parts = [node.module] if node.module else []
            if node.level:  # "from . import x" is the file's package, each further dot one package up
                parts = package[: len(package) - node.level + 1] + parts
            base = ".".join(parts)
            names += [base, *(f"{base}.{alias.name}" for alias in node.names)]
    return names


def test_common_never_imports_pola() -> None:
    files = sorted(COMMON.glob("*.py"))
    assert len(files) > 5 and COMMON / "checkpoint.py" in files
    offenders = {
        f"{path.name}: {name}"
        for path in files
        for name in imported_modules(path)
        if name == "sb3_pola.pola" or name.startswith("sb3_pola.pola.") or name in ("sb3_pola.POLA", "sb3_pola.MlpPolicy")
    }
    assert not offenders, sorted(offenders)


def test_common_modules_import_without_pola() -> None:
    """In a fresh interpreter, with the package's ``__init__`` (which imports POLA) bypassed: import every common module."""
    code = f"""
import importlib, pathlib, sys, types
package = types.ModuleType("sb3_pola")
package.__path__ = [{str(PACKAGE)!r}]
sys.modules["sb3_pola"] = package
names = sorted(p.stem for p in pathlib.Path({str(COMMON)!r}).glob("*.py") if p.stem != "__init__")
for name in names:
    importlib.import_module("sb3_pola.common." + name)
loaded = sorted(m for m in sys.modules if m == "sb3_pola.pola" or m.startswith("sb3_pola.pola."))
print(len(names), loaded)
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    count, loaded = result.stdout.split(" ", 1)
    assert int(count) == len([p for p in COMMON.glob("*.py") if p.stem != "__init__"])
    assert loaded.strip() == "[]", loaded


def test_the_imported_names_are_found() -> None:
    """The check above reads real imports: checkpoint.py's own are found."""
    names = imported_modules(COMMON / "checkpoint.py")
    assert "sb3_pola.common.errors" in names and "sb3_pola.common.offline_algorithm" in names


def test_peers_worker_loads_without_sb3_pola() -> None:
    """The d3rlpy venv has no ``sb3_pola``: the worker (and the normalised score it loads by path) must not need it."""
    worker = PACKAGE / "experiments" / "peers_worker.py"
    code = f"""
import runpy, sys
sys.modules["sb3_pola"] = None  # any import of the package fails
namespace = runpy.run_path({str(worker)!r}, run_name="peers_worker")
print(namespace["normalized_scores"]([0.0, 15.0], 0.0, 30.0).tolist())
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[0.0, 50.0]"
