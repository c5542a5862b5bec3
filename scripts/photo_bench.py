#!/usr/bin/env python
"""The real-photo benchmark: every recipe on turntable photos, test views between the training views.

For each grid (default 20°, 30°, 40°) the script builds a one-camera
turntable database from the photos (:func:`jaxrecog.photo_turntable.build_photo_database`:
training views on the grid, 4 poses 90° apart, ``test`` views halfway between
grid views, ``calib`` views 5° off the grid), then for every recipe (and,
with ``--approaches``, the other approaches measured in docs/results.md)
runs, through the CLI as a user would::

    jaxrecog train DB --out MODEL --kind DB1 --recipe R [approach flags]
    jaxrecog experiment --rig dataset:DB --model MODEL --trials N [--planners ...]

(the default planners: the model's recipe's planner and ``random`` on the
same trials, and the stop rule from the model's recipe).  It writes
``photo_bench.md`` (one table: rate, views, confident errors, ECE, mean exit
probability, each with its standard error where one applies),
``photo_bench.json`` and ``photo_bench_confident_errors.png`` (confident
errors against the test views' offset from the grid) into ``--out``.
Nothing is fitted or chosen on the test views: they are only replayed.

``--photos DIR`` runs another photo set of the same naming (``objM__I.png``,
M from 1, I the angle index); ``--quick`` is the CI form (one grid, a few
objects and trials, small models: it checks the pipeline, not the numbers).

Example (the docs/results.md table; 730 s on 2 cores)::

    python scripts/photo_bench.py --out out/photo-bench --approaches
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import shutil
import sys
import time
from pathlib import Path

from jaxrecog.cli import main as cli_main
from jaxrecog.metrics import campaign_metrics
from jaxrecog.modelfile import load_model_meta
from jaxrecog.photo_turntable import PHOTOS, build_photo_database, scan_photos
from jaxrecog.recipes import RECIPES
from jaxrecog.results import TrialStore, format_rate

#: Other approaches measured beside the recipes: name -> (train flags, experiment flags)
APPROACHES: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "thesis + calibrate": (("--recipe", "thesis", "--calibrate"), ()),
    "student-t, 2 views, xv": (("--recipe", "thesis", "--likelihood", "student-t", "--calibrate"),
                               ("--min-views", "2", "--exclude-visited")),
    "student-t, robust stop": (("--recipe", "robust", "--likelihood", "student-t", "--interpolate", "0"), ()),
    "robust, thesis stop": (("--recipe", "robust",), ("--min-views", "1", "--no-exclude-visited")),
    "robust, linear interpolation": (("--recipe", "robust", "--interpolation", "linear"), ()),
    "robust, diagonal mixture": (("--recipe", "robust", "--likelihood", "view-mixture"), ()),
    "robust, plain MI planner": (("--recipe", "robust"), ("--planners", "mi-class-pairwise")),
    "robust, 4 interpolated views": (("--recipe", "robust", "--interpolate", "4"), ()),
    "robust, 3 views": (("--recipe", "robust",), ("--min-views", "3")),
    "robust, P_th 0.95 (version 3)": (("--recipe", "robust",), ("--threshold", "0.95")),
    # the adaptive scale (recipe robust version 3): off = recipe robust version 2; one explained view
    "robust, adaptive scale off": (("--recipe", "robust",), ("--adaptive-scale", "1")),
    "robust, 1 explained view": (("--recipe", "robust",), ("--min-views", "1")),
    "robust, tempered MI planner (no stability)": (("--recipe", "robust",), ("--planners", "mi-class-pairwise-robust")),
    # version 5: the planner's stability weight fitted on the calib split; these force it / allow revisits
    "robust, stability weight 0": (("--recipe", "robust", "--stability", "0"), ()),
    "robust, revisits allowed": (("--recipe", "robust",), ("--no-exclude-visited",)),
    "robust, not calibrated": (("--recipe", "robust", "--no-calibrate"), ()),
    # version 6: the calibration factors pooled per camera; this keeps each position's own (version 5)
    "robust, calibration not pooled": (("--recipe", "robust", "--no-calib-pool"), ()),
}
QUICK = {"grids": [40], "objects": 2, "trials": 3, "samples": 10, "components": 6}


def _cli(*args, log) -> None:
    """``jaxrecog ARGS`` (the CLI's own ``main``, in this process: one JAX
    start-up and compilation cache for the whole benchmark); its output goes to ``log``."""
    argv = ["--quiet", *map(str, args)]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = cli_main(argv)
    log.write(f"$ jaxrecog {' '.join(argv)}\n{out.getvalue()}{err.getvalue()}\n")
    if rc:
        last = err.getvalue().strip().splitlines()
        raise SystemExit(f"photo_bench: command failed ({rc}): jaxrecog {' '.join(argv)}\n{last[-1] if last else ''}")


def planner_metrics(workdir: Path, planner: str, p_threshold: float) -> dict:
    """:func:`~jaxrecog.metrics.campaign_metrics` of ``planner``'s trial store in
    an experiment's ``workdir``, with the standard errors of the rate, the
    confident errors and the mean views (also ``scripts/add_bench.py``'s)."""
    files = sorted((workdir / "trials").glob(f"dataset-{planner}-*.jsonl"))
    if len(files) != 1:
        raise SystemExit(f"photo_bench: expected one trial store of {planner} in {workdir}, found {len(files)}")
    results = list(TrialStore(files[0]).load().values())
    m = campaign_metrics(results, p_threshold)
    n = m["trials"]
    for k, pct in (("recognition_rate", True), ("confident_error_pct_of_trials", True)):
        p = m[k] / 100.0
        m[k + "_se"] = 100.0 * math.sqrt(max(p * (1 - p), 0.0) / n) if n else math.nan
    views = [r.steps for r in results]
    mean = sum(views) / n
    m["mean_views_se"] = math.sqrt(sum((v - mean) ** 2 for v in views) / max(n - 1, 1) / n)
    return m


def run(out: Path, *, photos: Path, grids, recipes, approaches, trials: int, objects: int | None,
        samples: int, components: int, log=None) -> list[dict]:
    """``approaches``: ``True`` (all of :data:`APPROACHES`), ``False`` or a list of their names."""
    ps = scan_photos(photos)
    variants: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
        f"recipe {r}": (("--recipe", r), ()) for r in recipes}
    if approaches:
        variants.update(APPROACHES if approaches is True else {a: APPROACHES[a] for a in approaches})
    rows = []
    for grid in grids:
        db = out / "work" / f"grid{grid}" / "db"
        if db.exists():
            shutil.rmtree(db)
        build_photo_database(db, grid, photos=ps, objects=objects)
        for name, (train_flags, exp_flags) in variants.items():
            tag = "".join(ch if ch.isalnum() else "_" for ch in name)
            model = out / "work" / f"grid{grid}" / f"{tag}.npz"
            t0 = time.perf_counter()
            _cli("train", db, "--out", model, "--kind", "DB1", "--samples", samples, "--components", components,
                 *train_flags, log=log)
            train_s = time.perf_counter() - t0
            exp = out / "work" / f"grid{grid}" / f"{tag}-campaign"
            if exp.exists():
                shutil.rmtree(exp)
            _cli("experiment", "--rig", f"dataset:{db}", "--model", model, "--trials", trials, "--out", exp,
                 *exp_flags, log=log)
            report = json.loads((exp / "case_dataset.json").read_text())
            settings = report["settings"]
            weight = load_model_meta(model).get("stability")
            for planner in report["tables"]:   # the model recipe's planner and random unless --planners
                m = planner_metrics(exp / "work", planner, settings["p_threshold"])
                rows.append({"grid": grid, "offset": grid / 2, "variant": name, "planner": planner,
                             "train_s": train_s, "min_views": settings["min_views"],
                             "exclude_visited": settings["exclude_visited_positions"],
                             "p_threshold": settings["p_threshold"],
                             "stability": weight, **m})
                print(_line(rows[-1]), flush=True)
    return rows


def _line(r: dict) -> str:
    return (f"| {r['grid']}° / {r['offset']:g}° | {r['variant']} | {r['planner']} | "
            f"{format_rate(r['recognition_rate'], r['recognition_rate_ci'])} | "
            f"{r['mean_views']:.2f} | {format_rate(r['confident_error_pct_of_trials'], r['confident_error_pct_of_trials_ci'])} | "
            f"{r['ece']:.3f} | {r['mean_exit_prob']:.3f} | {r['trials']} |")


HEADER = ("| grid / test offset | recipe or approach | planner | rate % [95 % CI] | views | confident errors % [95 % CI] "
          "| ECE | exit P | trials |\n|---|---|---|---:|---:|---:|---:|---:|---:|")


def figure(rows: list[dict], path: Path) -> Path:
    """Confident errors against the offset: the recipes with both planners
    (left), every variant with the planner it ran first (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    variants = list(dict.fromkeys(r["variant"] for r in rows))
    colour = {v: plt.get_cmap("tab20")(i % 20) for i, v in enumerate(variants)}
    first = {v: next(r["planner"] for r in rows if r["variant"] == v) for v in variants}
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.6), sharey=True)
    panels = ([(v, p) for v in variants if v.startswith("recipe ") for p in dict.fromkeys(
                  r["planner"] for r in rows if r["variant"] == v)],
              [(v, first[v]) for v in variants])
    for ax, keys, title in zip(axes, panels, ("recipes: default planner and random", "every variant, its first planner")):
        for variant, planner in keys:
            sel = sorted((r for r in rows if r["variant"] == variant and r["planner"] == planner),
                         key=lambda r: r["offset"])
            rnd = planner == "random"
            y = [r["confident_error_pct_of_trials"] for r in sel]
            ci = [r["confident_error_pct_of_trials_ci"] for r in sel]  # 95 % Wilson: asymmetric bars
            ax.errorbar([r["offset"] for r in sel], y,
                        yerr=[[v - lo for v, (lo, _) in zip(y, ci)], [hi - v for v, (_, hi) in zip(y, ci)]],
                        marker="s" if rnd else "o",
                        linestyle="--" if rnd else "-", color=colour[variant], capsize=3,
                        label=f"{variant}, {planner}")
        ax.set_xlabel("test views' offset from the nearest training view (degrees)")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    axes[0].set_ylabel("confident errors (% of trials; bars: 95 % interval)")
    fig.suptitle("Real turntable photos: trials that stopped sure and wrong")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def bench_options(ap: argparse.ArgumentParser, quick: dict) -> argparse.ArgumentParser:
    """Add the options every photo benchmark script shares (``--photos``,
    ``--trials``, ``--samples``, ``--components``, ``--quick`` = the script's
    ``quick`` values) to ``ap``; returns ``ap``."""
    ap.add_argument("--photos", type=Path, default=PHOTOS, help="folder of objM__I.png turntable photos")
    ap.add_argument("--trials", type=int, default=30, help="trials per object")
    ap.add_argument("--samples", type=int, default=100, help="augmented samples per training image")
    ap.add_argument("--components", type=int, default=20, help="eigenvectors K")
    ap.add_argument("--quick", action="store_true", help="the CI form: " + ", ".join(f"{k} {v}" for k, v in quick.items()))
    return ap


def bench_args(args: argparse.Namespace, quick: dict) -> argparse.Namespace:
    """Parsed arguments of a photo benchmark script with ``--quick`` applied
    and ``--out`` made."""
    if args.quick:
        for k, v in quick.items():
            setattr(args, k, v)
    args.out.mkdir(parents=True, exist_ok=True)
    return args


def build_parser() -> argparse.ArgumentParser:
    """The command line of this script (the docs tests parse the docs' commands with it)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("out/photo-bench"))
    ap.add_argument("--grids", type=int, nargs="+", default=[20, 30, 40], help="grid steps in degrees")
    ap.add_argument("--recipes", nargs="+", default=list(RECIPES), choices=list(RECIPES))
    ap.add_argument("--approaches", action="store_true", help="also the other approaches (APPROACHES)")
    ap.add_argument("--approach", nargs="+", choices=list(APPROACHES), metavar="NAME", default=None,
                    help="only these approaches (names as in the table), besides --recipes")
    ap.add_argument("--objects", type=int, default=None, help="the first N objects (default all)")
    return bench_options(ap, QUICK)


def main(argv=None) -> int:
    args = bench_args(build_parser().parse_args(argv), QUICK)
    t0 = time.perf_counter()
    print(HEADER, flush=True)
    with open(args.out / "photo_bench.log", "w") as log:
        rows = run(args.out, photos=args.photos, grids=args.grids, recipes=args.recipes,
                   approaches=args.approach or args.approaches,
                   trials=args.trials, objects=args.objects, samples=args.samples, components=args.components, log=log)
    seconds = time.perf_counter() - t0
    md = "\n".join([HEADER, *map(_line, rows)])
    (args.out / "photo_bench.md").write_text(md + "\n")
    (args.out / "photo_bench.json").write_text(json.dumps(
        {"photos": str(args.photos), "rows": rows, "seconds": seconds,
         "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}}, indent=2))
    fig = figure(rows, args.out / "photo_bench_confident_errors.png")
    print(f"photo benchmark in {seconds:.0f} s; wrote {args.out / 'photo_bench.md'}, {args.out / 'photo_bench.json'}, {fig}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
