"""Render the synthetic rig's image database (thesis ch. 7: 32 images at each of
32 + 7 positions = 1248 train images) into the folder + manifest.csv format.

    python scripts/render_database.py out/db --test-per-view 2 --test-occluders \
        --contact-sheet out/contact_sheet.png --lookalike-table
"""

from __future__ import annotations

import argparse
import sys
import time

import cv2
import numpy as np
from tqdm import tqdm

from jaxrecog.hardware import Noise, SyntheticRig, contact_sheet, lookalike_distances, render_database


def _lookalike_report(rig: SyntheticRig, pairs=((4, 5), (6, 7))) -> str:
    lines = []
    labels = [f"{i}:{v}" for i, n in enumerate(rig.positions) for v in range(n)]
    for a, b in pairs:
        d = lookalike_distances(rig, a, b)
        lines.append(f"objects {a}/{b} (thesis {a + 1}/{b + 1}): ||y_a/|y_a| - y_b/|y_b|||, nonzero entries (camera:position=d)")
        for p in range(rig.n_poses):
            hits = ", ".join(f"{labels[k]}={d[p, k]:.3f}" for k in np.flatnonzero(d[p] > 1e-3))
            lines.append(f"  pose {p}: {hits or '-'}   (all other {int((d[p] <= 1e-3).sum())} positions: max {d[p][d[p] <= 1e-3].max(initial=0):.4f})")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", help="folder to write the database into")
    ap.add_argument("--test-per-view", type=int, default=0, help="perturbed test images per (camera, position, object, pose)")
    ap.add_argument("--test-occluders", action="store_true", help="random cardboard occluders in the test split")
    ap.add_argument("--brightness", type=float, default=0.05, help="test split: std of the brightness gain")
    ap.add_argument("--pixel-noise", type=float, default=2.0, help="test split: std of per-pixel noise (gray levels)")
    ap.add_argument("--max-shift", type=int, default=2, help="test split: largest random pixel offset")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--contact-sheet", metavar="PNG", help="also write 8 objects x 4 poses from two positions")
    ap.add_argument("--sheet-views", default="0:9,1:3", help="camera:position pairs for the contact sheet")
    ap.add_argument("--lookalike-table", action="store_true", help="print the look-alike pairs' distance per position")
    args = ap.parse_args(argv)
    try:
        views = [tuple(int(x) for x in s.split(":")) for s in args.sheet_views.split(",")]
        if any(len(v) != 2 for v in views):
            raise ValueError
    except ValueError:
        ap.error(f"--sheet-views {args.sheet_views!r}: expected camera:position pairs such as 0:9,1:3")

    with SyntheticRig(seed=args.seed) as rig:
        if args.contact_sheet:      # check the views before minutes of rendering, not after
            for i, v in views:
                if not (0 <= i < len(rig.positions) and 0 <= v < rig.positions[i]):
                    ap.error(f"--sheet-views: camera {i} position {v} is not on the rig "
                             f"(positions per camera {tuple(rig.positions)})")
        n_train = sum(rig.positions) * rig.n_objects * rig.n_poses
        total = n_train * (1 + args.test_per_view)
        t0 = time.perf_counter()
        with tqdm(total=total, unit="img", desc="render") as bar:
            manifest = render_database(
                args.out,
                rig=rig,
                test_per_view=args.test_per_view,
                test_noise=Noise(args.brightness, args.pixel_noise, args.max_shift),
                test_occluders=args.test_occluders,
                seed=args.seed,
                progress=bar.update,
            )
        print(f"wrote {total} images and {manifest} in {time.perf_counter() - t0:.1f} s")
        if args.contact_sheet:
            sheet = contact_sheet(rig, views)
            if not cv2.imwrite(args.contact_sheet, sheet):
                print(f"could not write {args.contact_sheet}", file=sys.stderr)
                return 1
            print(f"contact sheet (rows: objects 0-7; columns: poses 0-3 at {views}): {args.contact_sheet}")
        if args.lookalike_table:
            print(_lookalike_report(rig))
    return 0


if __name__ == "__main__":
    sys.exit(main())
