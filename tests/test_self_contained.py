"""The repository explains itself: a reader has only its files.

No tracked text file may point at things a reader does not have -- an issue
tracker's numbers (the tracker's issues and work stops, its review rounds and
adversarial-review reports), the design notes' old home outside the repository, or a
machine-local path -- and the licence that pyproject.toml declares must ship
with the code.  The patterns are assembled from pieces so that this file does
not match them itself.
"""

from __future__ import annotations

import re
import subprocess
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: folders and top-level files read when git is not there (an unpacked sdist)
FALLBACK = ("jaxrecog", "kernels", "hardware", "tests", "docs", "scripts", "benchmarks", "examples",
            "README.md", "Makefile", "pyproject.toml", "LICENSE")

_NUMBERS = "one|two|three|four|five|six|seven|eight|nine|ten"
#: what a self-contained file never says, matched in lower case; each pattern
#: opens with its literal word, which keeps the scan fast (a word boundary
#: before it is checked apart, in :func:`mentions`)
FORBIDDEN = {
    "a tracker issue number": re.compile("iss" + r"ues? ?#?\d+\b"),
    "a tracker stop number": re.compile("st" + r"ops? ?[-#]?\d+\b"),
    "a tracker review round": re.compile("rou" + rf"nd (?:{_NUMBERS})\b"),
    "an adversarial-review report": re.compile("red" + r"[- ]team\b"),
    "a path outside the repository": re.compile(re.escape(".." + "/shared")),
    "a machine-local path": re.compile(re.escape("/" + "work" + "/")),
}
_WORDS = ("a tracker issue number", "a tracker stop number", "a tracker review round", "an adversarial-review report")


def tracked_files() -> list[Path]:
    """The files git tracks (present on disk), else every file under :data:`FALLBACK`."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
        paths = [ROOT / p for p in out.decode().split("\0") if p]
    except (OSError, subprocess.CalledProcessError):
        paths = [p for name in FALLBACK for p in ([ROOT / name] if (ROOT / name).is_file()
                                                  else sorted((ROOT / name).rglob("*")))]
    return [p for p in paths if p.is_file() and not p.is_symlink()]


def text_of(path: Path) -> str | None:
    """The file as UTF-8 text, or None for a binary file (a NUL byte or not UTF-8)."""
    data = path.read_bytes()
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def mentions(text: str) -> list[tuple[int, str, str]]:
    """(line number, what, the match) for every forbidden mention in ``text``."""
    low = text.lower()
    found = []
    for what, pattern in FORBIDDEN.items():
        for m in pattern.finditer(low):
            before = low[m.start() - 1] if m.start() else " "
            if what in _WORDS and (before.isalnum() or before == "_"):
                continue  # inside a longer word ("tissue 3"), not the word itself
            found.append((low.count("\n", 0, m.start()) + 1, what, m.group(0)))
    return found


def test_the_patterns_catch_tracker_references_and_spare_plain_words():
    caught = ["see Iss" + "ue #12", "(iss" + "ues 5 and 6)", "St" + "op 39: recipe", "st" + "op-39",
              "the fourth red" + " team", "round" + " three", "../" + "shared/DESIGN.md", "/" + "work/cache"]
    for line in caught:
        assert mentions(line), line
    spared = ["6→7 stopped 13, 6→7 limit 1", "thesis stop (the turntable table)", "the stop rule",
              "an issue with the rig", "a round trip", "tissue 3", "nonstop 5", "docs/design.md §3", "workdir = out/thesis"]
    for line in spared:
        assert not mentions(line), line


def test_no_tracked_text_file_points_outside_the_repository():
    files = tracked_files()
    assert any(p.name == "README.md" for p in files), f"no files found under {ROOT}"
    found = [f"{path.relative_to(ROOT)}:{n}: {what}: {match!r}"
             for path in files if (text := text_of(path)) is not None
             for n, what, match in mentions(text)]
    assert not found, ("say what and why instead (a reader has only the repository):\n"
                       + "\n".join(found[:50]) + (f"\n... {len(found)} in all" if len(found) > 50 else ""))


def test_the_declared_licence_is_a_file_that_ships():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    licence = (ROOT / "LICENSE").read_text()
    assert licence.startswith("MIT License") and "the jaxrecog authors" in licence
