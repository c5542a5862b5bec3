"""``jaxrecog render``: the synthetic rig's image database."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..experiments import CAPTURE_NOISE
from ..hardware import Noise, render_database
from .._progress import bar
from ._common import synthetic_rig
from ._options import nonneg, table_options

NAME = "render"
ORDER = 10
HELP = "render the synthetic rig's image database"
DESCRIPTION = ("Render every (camera, position, object, pose) of the synthetic pybullet rig into an\n"
               "image database folder (PNG images + manifest.csv), the thesis's training set.")


def add_arguments(p) -> None:
    p.add_argument("--out", required=True, metavar="FOLDER", help="database folder to write")
    table_options(p)
    p.add_argument("--test-per-view", type=nonneg, default=0,
                   help="also render this many perturbed 'test' images per view (for --rig dataset:)")
    p.add_argument("--test-occluders", action="store_true",
                   help="give each test (object, pose) a random cardboard occluder layout")
    p.add_argument("--calib-per-view", type=nonneg, default=0,
                   help="held-out 'calib' images per view (small object yaw, camera offset, lighting and "
                        "noise perturbations), for `train --calibrate`")
    p.add_argument("--seed", type=int, default=0, help="seed of the test and calib perturbations")


def run(args) -> int:
    t0 = time.perf_counter()
    with synthetic_rig(args, seed=args.seed) as rig:
        n_train = sum(rig.positions) * rig.n_objects * rig.n_poses
        total = n_train * (1 + args.test_per_view + args.calib_per_view)
        with bar(total, "render", "img") as b:
            manifest = render_database(args.out, rig=rig, test_per_view=args.test_per_view,
                                       test_noise=Noise(*CAPTURE_NOISE),
                                       test_occluders=args.test_occluders, seed=args.seed,
                                       calib_per_view=args.calib_per_view, progress=b.update)
        layout = {"cameras": args.cameras, "stride": args.stride, "objects": args.objects,
                  "poses": args.poses, "positions": list(rig.positions)}
    (Path(args.out) / "rig.json").write_text(json.dumps(layout, indent=2) + "\n")
    print(f"rendered {total} images (positions {tuple(layout['positions'])}, {args.objects} objects x "
          f"{args.poses} poses) in {time.perf_counter() - t0:.1f} s -> {manifest}")
    return 0
