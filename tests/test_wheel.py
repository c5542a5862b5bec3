"""The wheel: built from a copy of the sources (what ``python -m build``
packs), it holds every module of every package -- jaxrecog, the kernels and
the hardware subpackages mapped under it by ``package-dir`` -- and nothing
else: no tests, no scripts, no data (the demo renders its own).  Installing
it into a fresh environment and running the quick demo is
``scripts/check_wheel.sh`` (minutes, not a test)."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: source folder -> its package in the wheel (pyproject.toml's package-dir)
SOURCES = {"jaxrecog": "jaxrecog", "kernels": "jaxrecog/kernels", "hardware": "jaxrecog/hardware"}


def _expected_modules() -> set[str]:
    """Every ``.py`` file of every package (a folder with ``__init__.py``), as the wheel names it."""
    out = set()
    for folder, package in SOURCES.items():
        for init in (ROOT / folder).rglob("__init__.py"):
            for py in init.parent.glob("*.py"):
                out.add(f"{package}/{py.relative_to(ROOT / folder).as_posix()}")
    return out


def test_the_wheel_holds_every_package_and_no_tests_or_data(tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    for folder in SOURCES:
        shutil.copytree(ROOT / folder, src / folder, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    dist = tmp_path / "dist"
    proc = subprocess.run([sys.executable, "-c", f"from setuptools import build_meta; build_meta.build_wheel({str(dist)!r})"],
                          cwd=src, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    (wheel,) = dist.glob("jaxrecog-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    info = [n for n in names if n.split("/")[0].endswith(".dist-info")]
    files = set(names) - set(info)
    expected = _expected_modules()
    assert {"jaxrecog/kernels/__init__.py", "jaxrecog/hardware/devices/pan_tilt_drivers/__init__.py"} <= expected
    missing = sorted(expected - files)
    assert not missing, f"the wheel lacks {missing[:5]}: list their packages in pyproject.toml"
    assert files == expected, f"the wheel holds more than the packages' modules: {sorted(files - expected)[:5]}"
    assert not any(n.startswith(("tests/", "scripts/", "data/")) or "/tests/" in n for n in names)
    entry = zipfile.ZipFile(wheel).read(next(n for n in info if n.endswith("entry_points.txt"))).decode()
    assert "jaxrecog = jaxrecog.cli:main" in entry
