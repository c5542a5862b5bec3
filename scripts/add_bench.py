#!/usr/bin/env python
"""Adding objects (``train --add``) against training at once, on the real turntable photos.

On one grid (default 30°) the script builds three one-camera turntable
databases from the photos (:func:`jaxrecog.photo_turntable.build_photo_database`:
training views on the grid, 4 poses 90° apart, ``test`` views halfway between,
``calib`` views 5° off): ALL (objects 0..OLD+NEW-1), OLD (objects 0..OLD-1) and
NEW (objects OLD..OLD+NEW-1 alone; photos ``obj1..`` are objects ``0..``).  Then, through the CLI as a user would::

    jaxrecog train ALL --out full.npz --kind DB1 --samples 100 --components 20
    jaxrecog train OLD --out old.npz  --kind DB1 --samples 100 --components 20
    jaxrecog train --add NEW --to old.npz --out add.npz [--no-calibrate]
    jaxrecog experiment --rig dataset:ALL --model M --trials 30

It times each training command two ways, each the median of ``--repeats``
runs: *cold*, a fresh ``python -m jaxrecog.cli`` process (start-up, imports
and XLA compilation included), and *warm*, the command run again in this
process after a first run (what the work itself costs once JAX is up and its
programs are compiled).
It prints one markdown table (the docs/results.md one) and writes it with the
numbers as JSON into ``--out``.  ``--quick`` is the CI form (2 + 1 objects on
the 40° grid, small models, one trial per object, no cold runs).

Example (the docs/results.md table)::

    python scripts/add_bench.py --out out/add-bench
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from jaxrecog.cli import main as cli_main
from jaxrecog.photo_turntable import PhotoSet, build_photo_database, scan_photos
from jaxrecog.results import format_rate
from photo_bench import bench_args, bench_options, planner_metrics   # scripts/ is this script's folder

QUICK = {"grid": 40, "old": 2, "new": 1, "trials": 1, "samples": 10, "components": 4, "repeats": 0}


def _cli(*args) -> float:
    """``jaxrecog --quiet ARGS`` in this process; its wall time in seconds."""
    argv = ["--quiet", *map(str, args)]
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli_main(argv)
    seconds = time.perf_counter() - t0
    if rc:
        raise SystemExit(f"add_bench: command failed ({rc}): jaxrecog {' '.join(argv)}\n{err.getvalue()}")
    return seconds


def _cold(*args) -> float:
    """``python -m jaxrecog.cli --quiet ARGS`` in a fresh process; its wall time."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "jaxrecog.cli", "--quiet", *map(str, args)], check=True,
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _rate(exp: Path) -> dict:
    """The model recipe's planner's metrics of an ``experiment --out EXP`` (rate and
    confident errors in % of trials, each with its standard error and its 95 % Wilson interval)."""
    report = json.loads((exp / "case_dataset.json").read_text())
    planner = next(iter(report["tables"]))
    m = planner_metrics(exp / "work", planner, report["settings"]["p_threshold"])
    keys = ("recognition_rate", "recognition_rate_se", "recognition_rate_ci", "confident_error_pct_of_trials",
            "confident_error_pct_of_trials_se", "confident_error_pct_of_trials_ci")
    return {"planner": planner, "trials": m["trials"], **{k: m[k] for k in keys}}


def run(out: Path, *, photos: Path, grid: int, old: int, new: int, trials: int, samples: int, components: int,
        repeats: int) -> list[dict]:
    ps = scan_photos(photos)
    if old + new > ps.n_objects:
        raise SystemExit(f"add_bench: {old} + {new} objects, the photos have {ps.n_objects}")
    dbs = {"all": out / "db-all", "old": out / "db-old", "new": out / "db-new"}
    for d in dbs.values():
        if d.exists():
            shutil.rmtree(d)
    build_photo_database(dbs["all"], grid, photos=ps, objects=old + new)
    build_photo_database(dbs["old"], grid, photos=ps, objects=old)
    build_photo_database(dbs["new"], grid, photos=PhotoSet(ps.folder, ps.files[old:old + new], ps.step))
    fit = ("--kind", "DB1", "--samples", samples, "--components", components)
    commands = {
        "train at once": ("train", dbs["all"], "--out", out / "full.npz", *fit),
        f"train objects 0-{old - 1}": ("train", dbs["old"], "--out", out / "old.npz", *fit),
        "train --add (recalibrates)": ("train", "--add", dbs["new"], "--to", out / "old.npz", "--out", out / "add.npz"),
        "train --add --no-calibrate": ("train", "--add", dbs["new"], "--to", out / "old.npz", "--out",
                                       out / "add-nc.npz", "--no-calibrate"),
    }
    models = {"train at once": "full.npz", "train --add (recalibrates)": "add.npz",
              "train --add --no-calibrate": "add-nc.npz"}
    rows = []
    for name, cmd in commands.items():
        cold = statistics.median([_cold(*cmd) for _ in range(repeats)]) if repeats else math.nan
        _cli(*cmd)                       # the first run in this process compiles
        warm = statistics.median([_cli(*cmd) for _ in range(repeats)]) if repeats else math.nan
        row = {"variant": name, "command": "jaxrecog " + " ".join(map(str, cmd)), "cold_s": cold, "warm_s": warm}
        if name in models:
            exp = out / f"exp-{Path(models[name]).stem}"
            if exp.exists():
                shutil.rmtree(exp)
            _cli("experiment", "--rig", f"dataset:{dbs['all']}", "--model", out / models[name], "--trials", trials,
                 "--out", exp)
            row.update(_rate(exp))
        rows.append(row)
        print(_line(row, rows[0]), flush=True)
    return rows


HEADER = ("| command | cold s (share of at once) | warm s (share of at once) | rate % [95 % CI] | confident errors % [95 % CI] |\n"
          "|---|---:|---:|---:|---:|")


def _line(r: dict, full: dict) -> str:
    def share(k):
        return f"{r[k]:.2f} ({100 * r[k] / full[k]:.0f} %)" if math.isfinite(r[k]) else "-"

    rate = (f"{format_rate(r['recognition_rate'], r['recognition_rate_ci'])} | "
            f"{format_rate(r['confident_error_pct_of_trials'], r['confident_error_pct_of_trials_ci'])}"
            if "recognition_rate" in r else "- | -")
    return f"| {r['variant']} | {share('cold_s')} | {share('warm_s')} | {rate} |"


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("out/add-bench"))
    ap.add_argument("--grid", type=int, default=30, help="grid step in degrees")
    ap.add_argument("--old", type=int, default=8, help="objects of the model added to")
    ap.add_argument("--new", type=int, default=2, help="objects added")
    ap.add_argument("--repeats", type=int, default=3, help="cold and warm runs of each training command (median)")
    return bench_options(ap, QUICK)


def main(argv=None) -> int:
    args = bench_args(build_parser().parse_args(argv), QUICK)
    print(HEADER, flush=True)
    rows = run(args.out, photos=args.photos, grid=args.grid, old=args.old, new=args.new, trials=args.trials,
               samples=args.samples, components=args.components, repeats=args.repeats)
    md = "\n".join([HEADER, *(_line(r, rows[0]) for r in rows)])
    (args.out / "add_bench.md").write_text(md + "\n")
    (args.out / "add_bench.json").write_text(json.dumps(
        {"rows": rows, "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}},
        indent=2))
    print(f"wrote {args.out / 'add_bench.md'}, {args.out / 'add_bench.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
