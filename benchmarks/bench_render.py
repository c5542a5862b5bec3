"""Render throughput of the synthetic rig and time to render the training database.

Targets: <= 5 ms a frame, the whole 1248-image database <= 15 s on
2 cores.  Writes JSON (default out/bench/render.json).

    python benchmarks/bench_render.py [--repeats 3] [--out out/bench/render.json]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from jaxrecog.hardware import Noise, SyntheticRig, random_occluders, render_database


def _frames(rig: SyntheticRig, occluded: bool, rng) -> float:
    """Seconds per camera image over every configuration column, all objects."""
    n = 0
    t = time.perf_counter()
    for m in range(rig.n_objects):
        rig.reset(m, m % rig.n_poses, random_occluders(rng, rig.table, radius=rig.radius) if occluded else None)
        for v in range(rig.positions[0]):
            rig.move((v,) + tuple(v % k for k in rig.positions[1:]))
            n += len(rig.capture().images)
    return (time.perf_counter() - t) / n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="out/bench/render.json")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    result: dict = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count()}
    t = time.perf_counter()
    rig = SyntheticRig(noise=Noise(brightness=0.05, pixel=2.0, max_shift=2), seed=0)
    result["setup_s"] = time.perf_counter() - t
    rng = np.random.default_rng(0)
    for label, occ in (("clean", False), ("occluded", True)):
        times = [_frames(rig, occ, rng) for _ in range(args.repeats)]
        result[f"frame_ms_{label}"] = {"min": 1e3 * min(times), "median": 1e3 * statistics.median(times)}
        result[f"fps_{label}"] = 1.0 / min(times)
    rig.close()
    db_times = []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            manifest = render_database(tmp)  # includes building the rig and writing PNGs
            db_times.append(time.perf_counter() - t)
            n_images = sum(1 for _ in open(manifest)) - 1
    result["database"] = {"images": n_images, "min_s": min(db_times), "median_s": statistics.median(db_times)}
    result["targets"] = {"frame_ms": 5.0, "database_s": 15.0}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
