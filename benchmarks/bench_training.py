"""Time DB2 training at the thesis's default sizes and write JSON.

Default: 2 cameras with 32 + 7 positions, 8 objects x 4 poses (32 training
images per position), 120 x 160 images, 6 occlusion levels, 100 samples per
image and level, K = 20, diagonal covariance.  The database is generated
(``make_database`` of ``tests/builders.py``) before the clock starts.  Reports wall time of
``train_model`` and the peak resident memory of the process
(``resource.getrusage``).  Targets: <= 60 s on 2 cores, <= 2 GB.

    python benchmarks/bench_training.py --out out/bench/training.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
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
    ap.add_argument("--covariance", default="diag", choices=["diag", "full"])
    args = ap.parse_args(argv)

    from builders import make_database
    from jaxrecog.train import train_model

    positions = tuple(int(x) for x in args.positions.split(","))
    t = time.perf_counter()
    db = make_database(positions=positions, n_objects=args.objects, n_poses=args.poses,
                       image_shape=(args.height, args.width))
    t_db = time.perf_counter() - t
    rss_before = _peak_rss_mb()
    t = time.perf_counter()
    model = train_model(db, kind=args.kind, n_components=args.components,
                        samples_per_image=args.samples, covariance=args.covariance, seed=0)
    for cam in model.cameras:
        cam.mu.block_until_ready()
    wall = time.perf_counter() - t
    n_levels = len(model.levels)
    n_images = sum(positions) * args.objects * args.poses
    result = {
        "benchmark": "training",
        "kind": args.kind,
        "covariance": args.covariance,
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
            "augmented_samples": n_images * n_levels * args.samples,
            "K": model.n_components,
        },
        "samples_per_s": n_images * n_levels * args.samples / wall,
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "targets": {"wall_s": 60.0, "peak_rss_mb": 2048.0},
    }
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
