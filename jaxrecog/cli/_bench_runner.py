"""Run benchmark scripts in subprocesses and merge their JSON (``jaxrecog bench``).

Each ``bench_NAME.py`` runs as ``python bench_NAME.py --out NAME.json`` with a
time limit; its JSON (or an ``{"error": ...}`` record: the last stderr line, a
timeout, unreadable JSON) goes under ``NAME`` in the merged dict.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

__all__ = ["Outcome", "find_scripts", "headline", "run_all", "run_script"]


class Outcome(NamedTuple):
    """One script's result: ``status`` is ok, failed, timeout or bad JSON."""

    name: str
    status: str
    wall_s: float
    record: dict[str, Any]


def find_scripts(folder: Path, only: Sequence[str] | None = None) -> list[Path]:
    """``bench_*.py`` in ``folder`` (sorted), or those named by ``only``
    (``render`` or ``bench_render`` or ``bench_render.py``)."""
    scripts = sorted(folder.glob("bench_*.py")) if folder.is_dir() else []
    if only:
        want = {n.removeprefix("bench_").removesuffix(".py") for n in only}
        scripts = [s for s in scripts if s.stem.removeprefix("bench_") in want]
    return scripts


def run_script(script: Path, out: Path, timeout: float) -> Outcome:
    """Run one script with ``--out out/NAME.json`` and read what it wrote."""
    name = script.stem.removeprefix("bench_")
    target = out / f"{name}.json"
    t0 = time.perf_counter()
    try:
        proc = subprocess.run([sys.executable, str(script), "--out", str(target)], capture_output=True,
                              text=True, timeout=timeout)
        rc = proc.returncode
        err = (proc.stderr.strip().splitlines() or [""])[-1]
    except subprocess.TimeoutExpired:
        rc, err = None, f"timed out after {timeout} s"
    wall = time.perf_counter() - t0
    if rc == 0 and target.is_file():
        try:
            return Outcome(name, "ok", wall, json.loads(target.read_text()))
        except ValueError:
            return Outcome(name, "bad JSON", wall, {"error": "unreadable JSON"})
    return Outcome(name, "failed" if rc is not None else "timeout", wall, {"error": err or f"exit code {rc}"})


def run_all(scripts: Sequence[Path], out: Path, timeout: float,
            progress: Callable[[int], object] | None = None) -> list[Outcome]:
    """:func:`run_script` for each script, one after the other."""
    out.mkdir(parents=True, exist_ok=True)
    outcomes = []
    for s in scripts:
        outcomes.append(run_script(s, out, timeout))
        if progress is not None:
            progress(1)
    return outcomes


_NOT_HEADLINES = {"cpus", "seed", "repeats", "version", "format_version"}


def headline(d: Any, limit: int = 4) -> str:
    """A few timing numbers of a benchmark's JSON: leaves named like a median,
    a rate or a wall time, at any depth (``mi.J=1.uniform/state.median_ms``);
    other top-level numbers when there are none."""
    if not isinstance(d, dict):
        return ""
    if "error" in d:
        return str(d["error"])[:60]
    timing = ("median_ms", "median", "wall_s", "seconds", "fps_clean", "trials_per_s", "peak_rss_mb")
    found: list[tuple[str, float]] = []

    def walk(node: Any, path: str) -> None:
        for k, v in node.items():
            key = f"{path}.{k}" if path else str(k)
            if isinstance(v, dict):
                walk(v, key)
            elif isinstance(v, list):
                for i, item in enumerate(v):
                    if isinstance(item, dict):
                        walk(item, f"{key}[{item.get('planner', i)}]")
            elif (k in timing or str(k).startswith("median")) and isinstance(v, (int, float)) and not isinstance(v, bool):
                found.append((key, float(v)))

    walk(d, "")
    if not found:
        found = [(k, v) for k, v in d.items()
                 if k not in _NOT_HEADLINES and isinstance(v, (int, float)) and not isinstance(v, bool)]
    return ", ".join(f"{k}={v:.4g}" for k, v in found[:limit])
