"""Test support lives with the tests: the product (the installed packages and
the scripts users run) imports none of the oracles, builders or the compile
counter, read from each file's ``import`` statements with ``ast``."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PRODUCT = ("jaxrecog", "kernels", "hardware", "scripts")
TESTS = Path(__file__).resolve().parent
# every module of tests/ (conftest, the test files, oracles, builders, ...) and
# the names they had while they shipped in the package
TEST_SUPPORT = {p.stem for p in TESTS.glob("*.py")} | {"tests", "jaxrecog.testing", "jaxrecog.kernels.reference"}
# a folder's package name once installed (pyproject's package-dir)
PACKAGE = {"jaxrecog": "jaxrecog", "kernels": "jaxrecog.kernels", "hardware": "jaxrecog.hardware"}


def imported_modules(path: Path, root: Path = ROOT) -> set[str]:
    """The absolute names of the modules ``path`` (under ``root``) imports
    (``from x import y`` gives ``x`` and ``x.y``; relative imports resolved
    against the installed package name)."""
    here = path.relative_to(root).parts
    package = [*PACKAGE[here[0]].split("."), *here[1:-1]] if here[0] in PACKAGE else []
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1] if node.level <= len(package) else []
                parent = ".".join([*base, *([node.module] if node.module else [])])
            else:
                parent = node.module or ""
            out.add(parent)
            out.update(f"{parent}.{a.name}" if parent else a.name for a in node.names)
    return out


def product_files() -> list[Path]:
    return sorted(p for folder in PRODUCT for p in (ROOT / folder).rglob("*.py"))


def offending(modules: set[str]) -> set[str]:
    return {m for m in modules if m in TEST_SUPPORT or m.split(".")[0] in TEST_SUPPORT}


def test_the_scan_sees_every_import_form(tmp_path):
    # the checker itself must be able to fail: absolute, dotted, relative and local forms
    f = tmp_path / "kernels" / "x.py"
    f.parent.mkdir()
    f.write_text("import oracles\nfrom builders import make_database\nfrom .. import testing\n"
                 "from . import reference\nimport numpy as np\nfrom .belief import update\n\n"
                 "def f():\n    from compiles import count_compiles\n")
    assert offending(imported_modules(f, tmp_path)) == {
        "oracles", "builders", "builders.make_database", "jaxrecog.testing", "jaxrecog.kernels.reference",
        "compiles", "compiles.count_compiles"}


def test_the_old_homes_are_gone():
    assert not (ROOT / "jaxrecog" / "testing.py").exists()
    assert not (ROOT / "kernels" / "reference.py").exists()


def test_the_product_imports_no_test_support():
    files = product_files()
    assert len(files) > 20 and ROOT / "jaxrecog" / "recognizer.py" in files
    bad = {str(p.relative_to(ROOT)): sorted(offending(imported_modules(p))) for p in files}
    assert not {k: v for k, v in bad.items() if v}
