"""Benchmark manifest validation at 100,000 rows.

Target: a 100k-row manifest validates in <= 5 s and <= 500 MB (an earlier
version's ``inspect`` took 25 s and 4 GB, and one mistyped position 999999 made
``train`` take 54 s and 2.1 GB).  Each case runs in a fresh subprocess so its
peak resident memory (``ru_maxrss``, the whole process with NumPy/OpenCV
imported) is its own:

- ``validate``: parse + check 100k rows (:func:`parse_manifest` +
  :func:`check_rows`: ranges, dense indices, duplicates), no image read;
- ``mistyped``: :func:`read_folder` of a 100k-row turntable-style folder
  (64 shared 24x32 image files) with position 999999 in one row and object
  1000000 in another: the error naming both rows;
- ``load``: the same folder, clean: the validated database in memory.

Writes JSON (default out/bench/manifest.json).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROWS = 100_000
_CHILD = r"""
import resource, sys, time
from pathlib import Path
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
from jaxrecog.dbformat import DatabaseError, check_rows, parse_manifest, read_folder
case, folder = sys.argv[1], Path(sys.argv[2])
t0 = time.perf_counter()
note = ""
if case == "validate":
    rows, problems = parse_manifest((folder / "manifest.csv").read_bytes(), str(folder))
    problems += check_rows(rows)
    note = f"{len(rows)} rows, {len(problems)} problems"
else:
    try:
        db = read_folder(folder)
        note = f"{db.n_rows} rows loaded, images {db.images.shape}"
    except DatabaseError as e:
        note = " | ".join(e.problems)
dt = time.perf_counter() - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(f"{dt}\t{peak / 1024}\t{base / 1024}\t{note}")
"""


def make_folder(root: Path, mistyped: bool) -> None:
    import cv2
    import numpy as np

    root.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for k in range(64):
        cv2.imwrite(str(root / f"img{k}.png"), rng.integers(0, 256, (24, 32), dtype=np.uint8))
    lines = ["path,camera,position,object,pose,split"]
    r = 0
    for v in range(100):
        for m in range(250):
            for p in range(4):
                r += 1
                pos, obj = v, m
                if mistyped and r == 50_000:
                    pos = 999_999
                if mistyped and r == 70_000:
                    obj = 1_000_000
                lines.append(f"img{r % 64}.png,0,{pos},{obj},{p},train")
    assert r == ROWS
    (root / "manifest.csv").write_text("\n".join(lines) + "\n")


def run_case(case: str, folder: Path) -> dict:
    out = subprocess.run([sys.executable, "-c", _CHILD, case, str(folder)], capture_output=True, text=True,
                         check=True)
    dt, peak, base, note = out.stdout.strip().split("\t", 3)
    return {"seconds": round(float(dt), 3), "peak_mb": round(float(peak), 1),
            "peak_mb_after_imports": round(float(base), 1), "result": note[:400]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/bench/manifest.json")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        clean, bad = Path(tmp) / "clean", Path(tmp) / "mistyped"
        make_folder(clean, mistyped=False)
        make_folder(bad, mistyped=True)
        res = {"rows": ROWS, "validate": run_case("validate", clean), "mistyped": run_case("mistyped", bad),
               "load": run_case("load", clean)}
    res["target"] = "validate <= 5 s and <= 500 MB"
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=2) + "\n")
    print(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
