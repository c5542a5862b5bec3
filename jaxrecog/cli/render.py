"""``jaxrecog render``: the synthetic rig's image database."""

from __future__ import annotations

import functools
import json
import time
from pathlib import Path

from .._files import check_output_folder, write_text
from .._lock import folder_lock
from ..scene import CAPTURE_NOISE
from ..hardware import Noise, render_database
from .._progress import bar
from ._common import UsageError, synthetic_rig, synthetic_rig_factory
from ._options import cluster_option, nonneg, positive, table_options

NAME = "render"
ORDER = 10
HELP = "render the synthetic rig's image database"
DESCRIPTION = ("Render every (camera, position, object, pose) of the synthetic pybullet rig into an\n"
               "image database folder (PNG images + manifest.csv), the thesis's training set.\n\n"
               "--turntable --objects random:N renders a turntable set instead: N gray random_urdfs\n"
               "meshes, a camera circling each at --step degrees (training views), test views halfway\n"
               "between them, calib views a quarter step off, poses = resting orientations (turned\n"
               "about x by 0, 90, 180, 270 degrees); see hardware/render/turntable.py.")

#: Per-view counts when not given: the thesis rig renders the train split only;
#: a turntable set is meant for a campaign, so it has test and calib views.
_DEFAULT_COUNTS = {False: (0, 0), True: (2, 1)}


def add_arguments(p) -> None:
    p.add_argument("--out", required=True, metavar="FOLDER", help="database folder to write")
    table_options(p)
    p.add_argument("--test-per-view", type=nonneg, default=None,
                   help="also render this many perturbed 'test' images per view (for --rig dataset:); "
                        "default 0, with --turntable 2")
    p.add_argument("--test-occluders", "--occluders", dest="test_occluders", action="store_true",
                   help="cardboard occluders in the test images: a random layout per test (object, pose); "
                        "with --turntable a board in front of every test view (10..40 %% of the object hidden)")
    p.add_argument("--calib-per-view", type=nonneg, default=None,
                   help="held-out 'calib' images per view (small object yaw, camera offset, lighting and "
                        "noise perturbations), for `train --calibrate`; default 0, with --turntable 1")
    p.add_argument("--seed", type=int, default=0, help="seed of the test and calib perturbations")
    cluster_option(p, "render")
    g = p.add_argument_group("turntable set (--turntable)")
    g.add_argument("--turntable", action="store_true",
                   help="a turntable layout: camera(s) on a circle around the object, --step degrees apart "
                        "(--cameras 1 by default; 2 adds a camera at 60 degrees elevation); needs --objects random:N")
    g.add_argument("--step", type=positive, default=20, metavar="DEG",
                   help="turntable: degrees between training views (must divide 360)")
    g.add_argument("--jitter-per-view", type=nonneg, default=0, metavar="N",
                   help="turntable: N clean 'jitter' images within +-step/4 of each training view, labelled "
                        "with it (extra training samples for `train --view-jitter`)")
    g.add_argument("--object-seed", type=int, default=0,
                   help="which random objects --objects random:N draws (a seeded permutation of the 1000)")
    p.set_defaults(cameras=None)  # 2 on the thesis rig, 1 on a turntable


def run(args) -> int:
    """Render into ``--out`` (made with its parents if missing, never
    through a file), holding its lock: a second ``render --out`` of the same folder is
    refused with one line naming the first's PID."""
    existed = Path(args.out).exists()
    out = check_output_folder(args.out, "database folder")
    try:
        with folder_lock(out, what="jaxrecog render"):
            return _run(args)
    except BaseException:  # refused options (or a render that wrote nothing) leave no empty folder behind
        if not existed and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
        raise


def _run(args) -> int:
    t0 = time.perf_counter()
    turntable = bool(args.turntable)
    d_test, d_calib = _DEFAULT_COUNTS[turntable]
    test_per_view = d_test if args.test_per_view is None else args.test_per_view
    calib_per_view = d_calib if args.calib_per_view is None else args.calib_per_view
    if turntable:
        return _turntable(args, test_per_view, calib_per_view, t0)
    if args.jitter_per_view:
        raise UsageError("--jitter-per-view applies to --turntable sets only")
    args.cameras = 2 if args.cameras is None else args.cameras
    with synthetic_rig(args, seed=args.seed) as rig:
        n_train = sum(rig.positions) * rig.n_objects * rig.n_poses
        total = n_train * (1 + test_per_view + calib_per_view)
        with bar(total, "render", "img") as b:
            kw = dict(test_per_view=test_per_view, test_noise=Noise(*CAPTURE_NOISE), test_occluders=args.test_occluders,
                      seed=args.seed, calib_per_view=calib_per_view, progress=b.update)
            if args.cluster:
                from ..ray_render import render_database_on

                factory = synthetic_rig_factory(args, seed=args.seed)
                manifest = render_database_on(args.cluster, args.out, rig_factory=factory, **kw)
            else:
                manifest = render_database(args.out, rig=rig, **kw)
        layout = {"cameras": args.cameras, "stride": args.stride, "objects": args.objects,
                  "poses": args.poses, "positions": list(rig.positions)}
        if isinstance(args.objects, str):
            layout["object_seed"] = args.object_seed
            layout["names"] = [o.name for o in rig.scene.objects]
    write_text(Path(args.out) / "rig.json", json.dumps(layout, indent=2) + "\n", "rig layout")
    dt = time.perf_counter() - t0
    print(f"rendered {total} images (positions {tuple(layout['positions'])}, {args.objects} objects x "
          f"{args.poses} poses) in {dt:.1f} s ({total / max(dt, 1e-9):.0f} images/s) -> {manifest}")
    return 0


def _turntable(args, test_per_view: int, calib_per_view: int, t0: float) -> int:
    from ..hardware.render.random_objects import RESTING_ROTATIONS, parse_objects, random_objects
    from ..hardware.render.turntable import DISTANCE, ELEVATIONS, TURNTABLE_PERTURB, render_turntable

    if not isinstance(args.objects, str):
        raise UsageError("--turntable needs --objects random:N (the poses turn one-mesh objects over; "
                         "the thesis objects are built of several parts)")
    if args.stride != 1:
        raise UsageError("--stride thins the thesis table; a turntable set takes --step DEG")
    if 360 % args.step:
        raise UsageError(f"--step {args.step}: the degrees between training views must divide 360")
    if args.poses > len(RESTING_ROTATIONS):
        raise UsageError(f"--poses {args.poses}: a turntable set has at most {len(RESTING_ROTATIONS)} resting "
                         "orientations (turned about x by 0, 90, 180, 270 degrees)")
    cameras = 1 if args.cameras is None else args.cameras
    _, n = parse_objects(args.objects)
    objects = random_objects(n, seed=args.object_seed)
    n_pos = 360 // args.step
    per_view = 1 + args.jitter_per_view + test_per_view + calib_per_view
    total = cameras * n_pos * n * args.poses * per_view
    if args.cluster:
        from ..ray_render import render_turntable_on

        render_turntable = functools.partial(render_turntable_on, args.cluster)
    with bar(total, "render", "img") as b:
        manifest = render_turntable(args.out, objects, cameras=cameras, step_deg=args.step, poses=args.poses,
                                    test_per_view=test_per_view, calib_per_view=calib_per_view,
                                    jitter_per_view=args.jitter_per_view, occluders=args.test_occluders,
                                    seed=args.seed, progress=b.update)
    dt = time.perf_counter() - t0
    layout = {"turntable": True, "cameras": cameras, "objects": args.objects, "object_seed": args.object_seed,
              "names": [o.name for o in objects], "poses": args.poses,
              "pose_rotations_deg": [[round(x * 57.29577951308232, 6) for x in r] for r in RESTING_ROTATIONS[: args.poses]],
              "step_deg": args.step, "positions": [n_pos] * cameras, "elevations_deg": list(ELEVATIONS[:cameras]),
              "distance_m": DISTANCE,
              "offsets_deg": {"test": args.step / 2, "calib": args.step / 4, "jitter": args.step / 4},
              "per_view": {"test": test_per_view, "calib": calib_per_view, "jitter": args.jitter_per_view},
              "test_occluders": bool(args.test_occluders),
              "perturb": {"eye_offset": TURNTABLE_PERTURB.eye_offset, "light": TURNTABLE_PERTURB.light,
                          "noise": list(CAPTURE_NOISE)},
              "seed": args.seed, "seconds": round(dt, 1)}
    write_text(Path(args.out) / "rig.json", json.dumps(layout, indent=2) + "\n", "rig layout")
    print(f"rendered {total} turntable images ({n} objects x {args.poses} poses, {cameras} camera(s) x {n_pos} "
          f"positions; per view 1 train + {test_per_view} test + {calib_per_view} calib + {args.jitter_per_view} "
          f"jitter) in {dt:.1f} s ({total / max(dt, 1e-9):.0f} images/s) -> {manifest}")
    return 0
