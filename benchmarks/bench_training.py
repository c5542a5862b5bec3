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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/bench/training.json")
    ap.add_argument("--positions", default="32,7", help="positions per camera, e.g. 32,7")
    ap.add_argument("--objects", type=int, default=8)
    ap.add_argument("--poses", type=int, default=4)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--kind", default="DB2", choices=["DB1", "DB2"])
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
    args = ap.parse_args(argv)
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

    passthrough = [a for a in (argv if argv is not None else sys.argv[1:])]
    cut = []  # drop --out / --likelihoods / --occluded-jitter and their values: set per child
    skip = False
    for a in passthrough:
        if skip and not a.startswith("--"):
            continue
        skip = a in ("--out", "--likelihoods", "--occluded-jitter")
        if not skip:
            cut.append(a)
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


if __name__ == "__main__":
    sys.exit(main())
