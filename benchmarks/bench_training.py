"""Time DB2 training at the thesis's default sizes, per likelihood, and write JSON.

Default: 2 cameras with 32 + 7 positions, 8 objects x 4 poses (32 training
images per position), 120 x 160 images, 6 occlusion levels, 100 samples per
image and level, K = 20, every registered likelihood family
(``kernels.likelihood_names()``: the thesis's diagonal Gaussian, full,
low-rank, Student-t and the view mixtures).  The view mixtures train on
``--view-jitter`` (default 8) more images per training view, one component
each (rendered a fraction of a position off the view), so they see
``1 + 8`` times the samples.  The database is generated (``make_database`` of
``tests/builders.py``) before the clock starts.  Each family trains in its
own child process (``--likelihood NAME``), so each reports its own peak
resident memory (``resource.getrusage``) beside the wall time of
``train_model``; ``ratio_vs_diag`` is each wall time over the diagonal
Gaussian's in the same run.  Targets: <= 60 s on 2 cores, <= 2 GB.

    python benchmarks/bench_training.py --out out/bench/training.json
    python benchmarks/bench_training.py --likelihoods gaussian-diag gaussian-lowrank

Objects scaling: ``--scale-objects N ...`` trains (DB1, the
thesis's diagonal Gaussian) and calibrates (``calibrate_model`` on the calib
split, as the turntable case does) a turntable-shaped synthetic database of
each ``N`` objects: one camera, ``--positions`` 18 (20° steps), ``--poses`` 4,
one train and one calib view per (position, class), the calib view a
quarter position off the grid.  ``--scale-databases FOLDER ...`` does the same
on image database folders with a calib split (rendered turntable sets,
``jaxrecog render --turntable --objects random:N``).  Each size runs in its
own child process, the database generated or loaded before the clock starts;
each row has the wall and CPU seconds of training and calibration, the peak
resident memory, and ``per_class_vs_smallest``: each cost per class over the
smallest size's (1 = linear in the number of classes, above 1 = faster than
linear).

    python benchmarks/bench_training.py --scale-objects 10 50 200 --out out/bench/training_objects.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))  # test support (oracles, builders, compile counter) lives in tests/


def _peak_rss_mb() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / 1024.0 if sys.platform != "darwin" else r / 2**20


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/bench/training.json")
    ap.add_argument("--positions", help="positions per camera, e.g. 32,7 (default 32,7; scaling: 18)")
    ap.add_argument("--objects", type=int, default=8)
    ap.add_argument("--poses", type=int, default=4)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--kind", choices=["DB1", "DB2"], help="default DB2; scaling: DB1")
    ap.add_argument("--components", type=int, default=20)
    ap.add_argument("--view-jitter", type=int, default=8,
                    help="jitter images per training view for the families that need them (the view mixtures: "
                         "one component each); the other families train without (default 8, as the campaigns)")
    ap.add_argument("--occluded-jitter", nargs="+", choices=["sampled", "translated"],
                    default=["sampled", "translated"],
                    help="view mixtures: how their occluded jitter components are trained (one row each; "
                         "kernels/view_mixture.py)")
    ap.add_argument("--likelihood", help="train this one family in this process (what each child runs)")
    ap.add_argument("--likelihoods", nargs="+", help="families to compare (default: every registered one)")
    ap.add_argument("--scale-objects", type=int, nargs="+", metavar="N",
                    help="objects scaling: a turntable-shaped synthetic database of each N objects")
    ap.add_argument("--scale-databases", nargs="+", metavar="FOLDER",
                    help="objects scaling on these image database folders (each with a calib split)")
    ap.add_argument("--in-process", action="store_true",
                    help="scaling: every size in this process (quicker; peak memory is then the running maximum)")
    ap.add_argument("--no-calibrate", action="store_true", help="scaling: time training alone")
    ap.add_argument("--scale-one", help=argparse.SUPPRESS)   # a child of the scaling mode: synthetic:N or a folder
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    scaling = bool(args.scale_objects or args.scale_databases or args.scale_one)
    args.positions = args.positions or ("18" if scaling else "32,7")
    args.kind = args.kind or ("DB1" if scaling else "DB2")
    if scaling:
        return _scale(args, argv)
    if args.likelihood is None:
        return _compare(args, argv)

    from builders import make_database
    from jaxrecog.kernels import likelihood_class
    from jaxrecog.train import train_model

    positions = tuple(int(x) for x in args.positions.split(","))
    needs_jitter = likelihood_class(args.likelihood).view_components
    if needs_jitter and args.view_jitter < 1:
        print(f"bench_training: error: {args.likelihood} needs --view-jitter >= 1", file=sys.stderr)
        return 2
    view_jitter = args.view_jitter if needs_jitter else 0
    mode = args.occluded_jitter[0] if needs_jitter else None
    t = time.perf_counter()
    db = make_database(positions=positions, n_objects=args.objects, n_poses=args.poses,
                       image_shape=(args.height, args.width), n_jitter=view_jitter)
    t_db = time.perf_counter() - t
    rss_before = _peak_rss_mb()
    t = time.perf_counter()
    model = train_model(db, kind=args.kind, n_components=args.components,
                        samples_per_image=args.samples, likelihood=args.likelihood, seed=0,
                        view_jitter=bool(view_jitter),
                        likelihood_options={"occluded_jitter": mode} if mode else None)
    for cam in model.cameras:
        cam.mu.block_until_ready()
    wall = time.perf_counter() - t
    n_levels = len(model.levels)
    n_images = sum(positions) * args.objects * args.poses
    # samples per training image: every level of it and of its jitter images, or
    # (translated) of the jitter images at level 0 only
    per_image = args.samples * (n_levels * (1 + view_jitter) if mode != "translated" else n_levels + view_jitter)
    result = {
        "benchmark": "training",
        "kind": args.kind,
        "likelihood": args.likelihood,
        "occluded_jitter": mode,
        "wall_s": wall,
        "database_generation_s": t_db,
        "peak_rss_mb": _peak_rss_mb(),
        "peak_rss_mb_before_training": rss_before,
        "sizes": {
            "cameras": len(positions),
            "positions": list(positions),
            "training_images": n_images,
            "image_shape": [args.height, args.width],
            "levels": n_levels,
            "samples_per_image": args.samples,
            "view_jitter_images_per_view": view_jitter,
            "augmented_samples": n_images * per_image,
            "K": model.n_components,
        },
        "samples_per_s": n_images * per_image / wall,
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "targets": {"wall_s": 60.0, "peak_rss_mb": 2048.0},
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


def _without(argv, flags) -> list[str]:
    """The command line (``argv``, or ``sys.argv[1:]``) without ``flags`` and
    their values: what each child gets besides its own."""
    cut, skip = [], False
    for a in (argv if argv is not None else sys.argv[1:]):
        if skip and not a.startswith("--"):
            continue
        skip = a in flags
        if not skip:
            cut.append(a)
    return cut


def _compare(args, argv) -> int:
    """Each family in a child process (its own peak memory), one JSON with
    every row and the wall-time ratio against the diagonal Gaussian."""
    from jaxrecog.kernels import likelihood_names

    names = list(args.likelihoods or likelihood_names())
    unknown = sorted(set(names) - set(likelihood_names()))
    if unknown:
        print(f"bench_training: error: unknown likelihood(s) {', '.join(unknown)}; "
              f"choose from {', '.join(likelihood_names())}", file=sys.stderr)
        return 2
    from jaxrecog.kernels import likelihood_class

    cut = _without(argv, ("--out", "--likelihoods", "--occluded-jitter"))  # set per child
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            for mode in (args.occluded_jitter if likelihood_class(name).view_components else ["sampled"]):
                out = Path(tmp) / f"{name}-{mode}.json"
                subprocess.run([sys.executable, __file__, *cut, "--likelihood", name, "--occluded-jitter", mode,
                                "--out", str(out)], check=True, stdout=subprocess.DEVNULL)
                rows.append(json.loads(out.read_text()))
    base = next((r["wall_s"] for r in rows if r["likelihood"] == "gaussian-diag"), None)
    for r in rows:
        r["ratio_vs_diag"] = None if base is None else r["wall_s"] / base
        r["meets_targets"] = r["wall_s"] <= r["targets"]["wall_s"] and r["peak_rss_mb"] <= r["targets"]["peak_rss_mb"]
    result = {"benchmark": "training", "rows": rows}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    for r in rows:
        ratio = "" if r["ratio_vs_diag"] is None else f"  {r['ratio_vs_diag']:.2f}x diag"
        label = r["likelihood"] + (f" ({r['occluded_jitter']})" if r.get("occluded_jitter") else "")
        print(f"{label:33s} {r['wall_s']:7.1f} s  {r['peak_rss_mb']:7.0f} MB{ratio}")
    print(f"wrote {out}")
    return 0


# ---------------------------------------------------------------- objects scaling

#: the costs ``per_class_vs_smallest`` compares
_SCALED = ("train_wall_s", "train_cpu_s", "calibrate_wall_s", "calibrate_cpu_s", "total_wall_s", "total_cpu_s",
           "peak_rss_mb")


def _timed(f):
    """``(f(), wall seconds, CPU seconds of this process)``, JAX results ready."""
    import jax

    w, c = time.perf_counter(), time.process_time()
    out = jax.block_until_ready(f())
    return out, time.perf_counter() - w, time.process_time() - c


def _measure_objects(spec: str, args) -> dict:
    """Train and calibrate one database (``synthetic:N`` or a folder): one row."""
    from builders import make_database
    from jaxrecog.calibration import calibrate_model
    from jaxrecog.database import load_database
    from jaxrecog.train import train_model

    t = time.perf_counter()
    if spec.startswith("synthetic:"):
        positions = tuple(int(x) for x in args.positions.split(","))
        db = make_database(positions=positions, n_objects=int(spec.split(":", 1)[1]), n_poses=args.poses,
                           image_shape=(args.height, args.width), n_calib=1, view_offset=0.25)
    else:
        db = load_database(spec)
    t_db = time.perf_counter() - t
    rss_before = _peak_rss_mb()
    model, train_wall, train_cpu = _timed(lambda: train_model(
        db, kind=args.kind, n_components=args.components, samples_per_image=args.samples, seed=0))
    rss_trained = _peak_rss_mb()
    info, cal_wall, cal_cpu = None, None, None
    if not args.no_calibrate:
        (_, info), cal_wall, cal_cpu = _timed(lambda: calibrate_model(model, db))
    return {
        "database": spec, "objects": db.n_objects, "classes": db.n_classes,
        "train_wall_s": train_wall, "train_cpu_s": train_cpu,
        "calibrate_wall_s": cal_wall, "calibrate_cpu_s": cal_cpu,
        "total_wall_s": train_wall + (cal_wall or 0.0), "total_cpu_s": train_cpu + (cal_cpu or 0.0),
        "peak_rss_mb": _peak_rss_mb(), "peak_rss_mb_before_training": rss_before,
        "peak_rss_mb_after_training": rss_trained,
        "database_seconds": t_db,
        "sizes": {"positions": list(db.positions), "poses": db.n_poses, "image_shape": list(db.image_shape),
                  "train_images": int(db.rows("train").size), "calib_images": int(db.rows("calib").size),
                  "kind": args.kind, "K": model.n_components, "samples_per_image": args.samples,
                  "calibration_iterations_max": None if info is None else int(max(x.max() for x in info.iterations))},
    }


def _num(x: float | None, width: int) -> str:
    return f"{'-':>{width}s}" if x is None else f"{x:{width}.1f}"


def per_class_ratios(rows: list[dict]) -> None:
    """Set each row's ``per_class_vs_smallest``: every cost of :data:`_SCALED`
    per class over the smallest size's, ``(x / C) / (x_0 / C_0)`` (``None``
    where a cost was not measured)."""
    base = min(rows, key=lambda r: r["classes"])
    for r in rows:
        r["per_class_vs_smallest"] = {k: None if r[k] is None else (r[k] / r["classes"]) / (base[k] / base["classes"])
                                      for k in _SCALED}


def _scale(args, argv) -> int:
    """Every size (a child process each, or ``--in-process``), the ratios per
    class against the smallest, one JSON."""
    if args.scale_one:
        row = _measure_objects(args.scale_one, args)
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(row, indent=2) + "\n")
        return 0
    if any(n < 1 for n in args.scale_objects or ()):
        print("bench_training: error: --scale-objects needs sizes >= 1", file=sys.stderr)
        return 2
    specs = [f"synthetic:{n}" for n in args.scale_objects or ()] + list(args.scale_databases or ())
    cut = _without(argv, ("--out", "--scale-objects", "--scale-databases", "--in-process"))
    load = [os.getloadavg()[0]]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for j, spec in enumerate(specs):
            if args.in_process:
                rows.append(_measure_objects(spec, args))
                continue
            out = Path(tmp) / f"{j}.json"
            subprocess.run([sys.executable, __file__, *cut, "--scale-one", spec, "--out", str(out)], check=True,
                           stdout=subprocess.DEVNULL)
            rows.append(json.loads(out.read_text()))
    load.append(os.getloadavg()[0])
    per_class_ratios(rows)
    result = {"benchmark": "training-objects", "rows": rows, "in_process": args.in_process,
              "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS"), "load_average_1min": load,
              "cpu_count": os.cpu_count(), "platform": platform.platform()}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"{'objects':>7s} {'classes':>7s} {'train s (cpu)':>15s} {'calibrate s (cpu)':>18s} {'peak MB':>8s} "
          f"{'per class vs smallest: total (cpu)':>34s}")
    for r in rows:
        q = r["per_class_vs_smallest"]
        print(f"{r['objects']:7d} {r['classes']:7d} {r['train_wall_s']:7.1f} ({r['train_cpu_s']:5.1f}) "
              f"{_num(r['calibrate_wall_s'], 9)} ({_num(r['calibrate_cpu_s'], 5)}) {r['peak_rss_mb']:8.0f} "
              f"{q['total_wall_s']:27.2f} ({q['total_cpu_s']:.2f})")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
