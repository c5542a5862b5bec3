"""Layering rules that keep the seams cheap to change (issue 14)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRODUCT = ("jaxrecog", "kernels", "hardware", "scripts", "benchmarks")


def _imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            yield node


def test_nothing_imports_another_modules_private_names():
    """``from m import _name`` reaches into m; a private *module* (``from . import
    _engine``, ``from ._grid import lse``) is fine, it is its package's own."""
    found = []
    for folder in PRODUCT:
        for path in (ROOT / folder).rglob("*.py"):
            for node in _imports(path):
                for alias in node.names:
                    if alias.name.startswith("_") and not alias.name.startswith("__"):
                        if node.module is None:  # from . import _private_module
                            continue
                        found.append(f"{path.relative_to(ROOT)}: from {node.module} import {alias.name}")
    assert not found, "\n".join(found)


def test_kernels_import_nothing_from_jaxrecog_or_hardware():
    for path in (ROOT / "kernels").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""] if node.level == 0 else []
                assert node.level <= 1, f"{path.name}: relative import leaves the kernels package"
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for n in names:
                assert not n.startswith("jaxrecog"), f"{path.name} imports {n}"
