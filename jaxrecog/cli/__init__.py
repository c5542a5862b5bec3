"""jaxrecog: active multi-camera object recognition (render, train, plan, recognize, experiment).

Exit codes: 0 success, 2 usage error, 1 runtime failure (one line
"jaxrecog: error: ..."; run with --debug for the traceback).
Settings may come from a TOML file (--config FILE): one table per subcommand
with the long option names as keys; command-line options override the file.
Indices (objects, poses, positions) are 0-based everywhere.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import math
import subprocess
import sys
import time
import types
from pathlib import Path
from typing import Any, Sequence

from ..hardware.problems import problem_message

__all__ = ["main", "build_parser", "CLIError"]

PLANNERS = ("mi", "mi-class", "crlb", "crlb-det", "crlb-eig", "random", "fixed")


class CLIError(Exception):
    """A runtime failure with a message for the user (exit code 1)."""


class UsageError(Exception):
    """A bad argument found after parsing (exit code 2)."""


# --------------------------------------------------------------------------
# parser
# --------------------------------------------------------------------------

class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Raw descriptions; ``(default: X)`` after each help where a default means something."""

    def _get_help_string(self, action):
        text = action.help or ""
        d = action.default
        if "%(default)" in text or d is None or d is False or d is argparse.SUPPRESS or not action.option_strings:
            return text
        shown = " ".join(map(str, d)) if isinstance(d, (list, tuple)) else d
        return f"{text} (default: {shown})"


def _config_tuple(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(x) for x in str(text).replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected positions like '3,2' (one per camera), got {text!r}") from None
    if any(v < 0 for v in vals):
        raise argparse.ArgumentTypeError(f"positions must be >= 0, got {text!r}")
    return vals


def _int_at_least(low: int, what: str):
    """An argparse type: an integer >= ``low``, described as ``what`` in errors."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if v < low:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return v

    return parse


_positive = _int_at_least(1, "a positive integer")
_nonneg = _int_at_least(0, "an integer >= 0")


def _probability(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a probability, got {text!r}") from None
    if not 0.0 < v <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a probability in (0, 1], got {text!r}")
    return v


def _global_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    d = argparse.SUPPRESS if suppress else None
    parser.add_argument("--quiet", "-q", action="store_true", default=d if suppress else False,
                        help="no progress bars (they are also off when output is not a terminal)")
    parser.add_argument("--debug", action="store_true", default=d if suppress else False,
                        help="show the full traceback on errors")
    parser.add_argument("--config", metavar="FILE.TOML", default=d,
                        help="read option defaults from this TOML file ([global] and one table per subcommand)")


def _table_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("synthetic rig layout (must match the model's positions)")
    g.add_argument("--cameras", type=int, choices=(1, 2), default=2,
                   help="cameras of the thesis rig to use (1 = camera 1 only)")
    g.add_argument("--stride", type=_positive, default=1,
                   help="keep every STRIDE-th position of each camera (1 = the full 32 x 7 table)")
    g.add_argument("--objects", type=_positive, default=8, help="number of objects (the first N of the 8)")
    g.add_argument("--poses", type=_positive, default=4, help="poses per object (pose p at 360*p/POSES degrees)")


def _planner_size_options(p: argparse.ArgumentParser) -> None:
    """The planners' Monte Carlo size (``plan`` and ``recognize``)."""
    p.add_argument("--samples", type=_positive, default=1024, help="Monte Carlo samples of the planner")
    p.add_argument("--min-per-stratum", type=_positive, default=8,
                   help="at least this many samples per state (object, pose, levels): with an occlusion model "
                        "1024 samples alone give one draw per state, too few to see a sticker view")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="jaxrecog", description=__doc__, formatter_class=_Formatter)
    _global_options(parser, suppress=False)
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    def add(name: str, help: str, description: str) -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help, description=description, formatter_class=_Formatter)
        _global_options(p, suppress=True)
        return p

    # render ---------------------------------------------------------------
    p = add("render", "render the synthetic rig's image database",
            "Render every (camera, position, object, pose) of the synthetic pybullet rig into an\n"
            "image database folder (PNG images + manifest.csv), the thesis's training set.")
    p.add_argument("--out", required=True, metavar="FOLDER", help="database folder to write")
    _table_options(p)
    p.add_argument("--test-per-view", type=_nonneg, default=0,
                   help="also render this many perturbed 'test' images per view (for --rig dataset:)")
    p.add_argument("--test-occluders", action="store_true",
                   help="give each test (object, pose) a random cardboard occluder layout")
    p.add_argument("--calib-per-view", type=_nonneg, default=0,
                   help="held-out 'calib' images per view (small object yaw, camera offset, lighting and "
                        "noise perturbations), for `train --calibrate`")
    p.add_argument("--seed", type=int, default=0, help="seed of the test and calib perturbations")

    # train ----------------------------------------------------------------
    p = add("train", "train a sensor model (DB1/DB2) from an image database",
            "Train the eigenspace + Gaussian sensor model of an image database and write the\n"
            "model file (.npz).  DB1 = noise and shifts; DB2 adds occluders of 5..25 %.")
    p.add_argument("database", metavar="DATABASE", help="image database folder (with manifest.csv)")
    p.add_argument("--out", required=True, metavar="MODEL.NPZ", help="model file to write")
    p.add_argument("--kind", choices=("DB1", "DB2"), default="DB2", help="augmentation kind")
    p.add_argument("--components", type=float, default=20,
                   help="eigenvectors K per position (integer), or the energy fraction to keep (0..1)")
    p.add_argument("--samples", type=_positive, default=100,
                   help="augmented samples per training image and occlusion level")
    p.add_argument("--covariance", choices=("diag", "full"), default="diag", help="Gaussian covariance form")
    p.add_argument("--seed", type=int, default=0, help="seed of the augmentation")
    p.add_argument("--calibrate", action="store_true",
                   help="calibrate the model on the database's 'calib' split (jaxrecog.calibration)")

    # inspect --------------------------------------------------------------
    p = add("inspect", "summarise a model file or an image database",
            "Print a summary of a model file (.npz; with a calibrated model, its variance factors\n"
            "per camera and position) or an image database folder; optionally draw its\n"
            "eigenimages (model) or occluder examples (database).")
    p.add_argument("path", metavar="PATH", help="model file or database folder")
    p.add_argument("--plot-dir", metavar="FOLDER",
                   help="write figures here: eigenimages (model) or occlusion examples (database)")
    p.add_argument("--camera", type=_nonneg, default=0, help="camera of the eigenimage / example figure")
    p.add_argument("--position", type=_nonneg, default=0, help="position of the eigenimage / example figure")

    # plan -----------------------------------------------------------------
    p = add("plan", "score all camera configurations and print the best ones",
            "Score every configuration with a planner, for the uniform belief or for the belief\n"
            "after a set of images taken at --at; print the best and the top configurations.")
    p.add_argument("model", metavar="MODEL.NPZ", help="model file")
    p.add_argument("--planner", choices=PLANNERS, default="mi", help="scoring rule")
    p.add_argument("--images", nargs="+", metavar="PNG",
                   help="one gray image per camera, taken at --at (default: score the uniform belief)")
    p.add_argument("--at", type=_config_tuple, metavar="V1,V2",
                   help="configuration the --images were taken at (one position per camera)")
    _planner_size_options(p)
    p.add_argument("--top", type=_positive, default=10, help="how many configurations to list")
    p.add_argument("--plot", metavar="PNG", help="also write the scores as a heat map (PNG + SVG)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed")

    # recognize ------------------------------------------------------------
    p = add("recognize", "run one recognition trial on a rig",
            "Place an object, then take image sets and move the cameras where the planner says\n"
            "until the best (object, pose) reaches --threshold or --max-steps; print each step.")
    p.add_argument("model", metavar="MODEL.NPZ", help="model file")
    p.add_argument("--rig", default="synthetic", metavar="RIG",
                   help="'synthetic' (pybullet scene), 'dataset:FOLDER' (replay a database's test split) "
                        "or a rig TOML file (simulated or real hardware)")
    p.add_argument("--object", type=_nonneg, default=0, help="object to place (0-based)")
    p.add_argument("--pose", type=_nonneg, default=0, help="its pose (0-based)")
    p.add_argument("--start", type=_config_tuple, metavar="V1,V2",
                   help="initial configuration (default: random from --seed)")
    p.add_argument("--planner", choices=PLANNERS, default="mi", help="view planner")
    p.add_argument("--threshold", type=_probability, default=0.95, help="stop probability P_th")
    p.add_argument("--max-steps", type=_positive, default=7, help="largest number of image sets")
    _planner_size_options(p)
    p.add_argument("--occluders", action="store_true", help="synthetic rig: cardboard boards in front of the first views (as thesis case ii/iii)")
    p.add_argument("--noise", type=float, default=2.0, help="synthetic rig: per-pixel noise (gray levels)")
    p.add_argument("--plot", metavar="PNG", help="also plot the belief over objects per step")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed (start, planner, rig noise)")
    _table_options(p)

    # experiment -----------------------------------------------------------
    p = add("experiment", "run a thesis case, a TOML experiment or a campaign on an image database",
            "Run a recognition campaign as in thesis chapter 7 and write the tables (Markdown,\n"
            "JSON) and plots into --out.  CASE is a case name (i, ii, iii, single-clean,\n"
            "single-occluded) or a TOML file with 'case' and Settings fields; the case renders\n"
            "and trains its own database and models (cached in --workdir).\n\n"
            "With --rig dataset:FOLDER --model MODEL.NPZ (and no CASE) the campaign replays the\n"
            "test split of an image database instead: every object of the model, --trials per\n"
            "object with a random pose and start, any number of cameras and positions (the\n"
            "model's).  A TOML file may give 'rig' and 'model' in place of 'case'.")
    p.add_argument("case", metavar="CASE", nargs="?",
                   help="thesis case name or experiment TOML file (leave out with --rig dataset:FOLDER)")
    p.add_argument("--out", default="out/experiment", metavar="FOLDER", help="where tables and plots go")
    p.add_argument("--workdir", metavar="FOLDER", help="cache of the rendered database and models, and the "
                   "finished trials (default: OUT/work)")
    p.add_argument("--rig", metavar="RIG",
                   help="'synthetic' (the thesis case's rendered rig; the default) or 'dataset:FOLDER' "
                        "(replay an image database's test split; needs --model)")
    p.add_argument("--model", metavar="MODEL.NPZ", help="trained model file for --rig dataset:FOLDER")
    p.add_argument("--planners", nargs="+", choices=PLANNERS, metavar="PLANNER",
                   help=f"planners to compare, from {', '.join(PLANNERS)} (default: the case's; "
                        "mi random on a dataset rig)")
    p.add_argument("--trials", type=_positive, help="trials per object (default: the case's)")
    p.add_argument("--samples", type=_positive, help="Monte Carlo samples of the planners")
    p.add_argument("--min-per-stratum", type=_positive, help="at least this many planner samples per state "
                   "(default 8)")
    p.add_argument("--batch", type=_positive, help="trials run in lockstep")
    p.add_argument("--seed", type=int, help="campaign seed")
    p.add_argument("--stride", type=_positive,
                   help="synthetic rig: keep every STRIDE-th position of each camera (8 = a 4 x 1 table "
                        "that renders and trains in seconds; default 1 = the thesis's 32 x 7)")
    p.add_argument("--quick", action="store_true", help="small models and fewer planner samples "
                   "(minutes, not hours)")
    p.add_argument("--trace", action="store_true", help="also run one traced trial and plot its belief "
                   "(thesis cases)")

    # bench ----------------------------------------------------------------
    p = add("bench", "run the benchmark scripts and merge their JSON",
            "Run every benchmarks/bench_*.py script (each with --out FILE.json), merge the\n"
            "results into one JSON file and print a summary table.")
    p.add_argument("--out", default="out/bench", metavar="FOLDER", help="folder of the JSON files")
    p.add_argument("--benchmarks", metavar="FOLDER",
                   help="folder of the scripts (default: benchmarks/ next to the package)")
    p.add_argument("--only", nargs="+", metavar="NAME", help="run only these (e.g. render training)")
    p.add_argument("--timeout", type=_positive, default=1800, help="seconds allowed per script")

    # demo -----------------------------------------------------------------
    p = add("demo", "what `make demo` runs: render, train, a short campaign, plots",
            "Render the synthetic database, train DB1 and DB2 (and print their summaries), run\n"
            "a short case (iii) campaign (occluded scenes, DB2 model) with the MI planners (class and\n"
            "state targets), print the table and write the plots.  --stride 8 makes it a smoke\n"
            "run of well under a minute (positions (4, 1), 160 images).")
    p.add_argument("--out", default="out/demo", metavar="FOLDER", help="output folder")
    p.add_argument("--trials", type=_positive, default=10, help="trials per object")
    p.add_argument("--planners", nargs="+", choices=PLANNERS, default=["mi-class", "mi"], metavar="PLANNER",
                   help=f"planners to run, from {', '.join(PLANNERS)}; the first also draws the trace "
                        "(default: mi-class mi, the class and the thesis's state target)")
    p.add_argument("--stride", type=_positive, default=1,
                   help="keep every STRIDE-th position of each camera (1 = the thesis's 32 x 7 table)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed")
    return parser


def _version() -> str:
    from .. import __version__

    return __version__


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------

def _require(module: str, what: str):
    """Import ``module`` lazily (keeps `--help` fast) or fail with one clear line, e.g. when an extra it needs is missing."""
    try:
        return importlib.import_module(module)
    except (ImportError, AttributeError) as e:
        raise CLIError(f"{what} needs {module}, which could not be imported ({type(e).__name__}: {e})") from e


def _recognizer_modules():
    planners = _require("jaxrecog.planners", "planning")
    recognizer = _require("jaxrecog.recognizer", "recognition")
    return planners, recognizer


def _load_model(path: str):
    from ..modelfile import load_model

    return load_model(path)


def _table(cameras: int, stride: int):
    from ..hardware.positions import CameraTable, default_table

    t = default_table()
    if cameras == 1:
        t = t.single_camera(0)
    return CameraTable(t.workspace, tuple(v[::stride] for v in t.views))


def _synthetic_rig(args, **kw):
    from ..hardware import SyntheticRig, default_objects

    objs = default_objects()
    if args.objects > len(objs):
        raise UsageError(f"--objects {args.objects}: the synthetic scene has {len(objs)} objects")
    return SyntheticRig(_table(args.cameras, args.stride), objects=objs[: args.objects],
                        n_poses=args.poses, **kw)


def _model_positions(model) -> tuple[int, ...]:
    return tuple(int(c.mu.shape[0]) for c in model.cameras)


def _fmt_cfg(cfg: Sequence[int]) -> str:
    return ",".join(str(int(v)) for v in cfg)


def _print_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    for j, r in enumerate(cells):
        print("  ".join(c.rjust(w) for c, w in zip(r, widths)))
        if j == 0:
            print("  ".join("-" * w for w in widths))


def _read_gray(path: str, shape: tuple[int, int]):
    import cv2
    import numpy as np

    if not Path(path).is_file():
        raise CLIError(f"image {path} not found")
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CLIError(f"image {path} cannot be read as an image")
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype != np.uint8:
        raise CLIError(f"image {path} is {img.dtype}, expected 8-bit gray")
    if tuple(img.shape) != tuple(shape):
        raise CLIError(f"image {path} is {img.shape[0]}x{img.shape[1]}, the model expects {shape[0]}x{shape[1]}")
    return img


def _key(seed: int):
    import jax.random as jr

    return jr.PRNGKey(int(seed))


# --------------------------------------------------------------------------
# subcommands
# --------------------------------------------------------------------------

def cmd_render(args) -> int:
    from ..hardware import Noise, render_database
    from ..progress import bar

    t0 = time.perf_counter()
    with _synthetic_rig(args, seed=args.seed) as rig:
        n_train = sum(rig.positions) * rig.n_objects * rig.n_poses
        total = n_train * (1 + args.test_per_view + args.calib_per_view)
        with bar(total, "render", "img") as b:
            manifest = render_database(args.out, rig=rig, test_per_view=args.test_per_view,
                                       test_noise=Noise(brightness=0.05, pixel=2.0, max_shift=2),
                                       test_occluders=args.test_occluders, seed=args.seed,
                                       calib_per_view=args.calib_per_view, progress=b.update)
        layout = {"cameras": args.cameras, "stride": args.stride, "objects": args.objects,
                  "poses": args.poses, "positions": list(rig.positions)}
    (Path(args.out) / "rig.json").write_text(json.dumps(layout, indent=2) + "\n")
    print(f"rendered {total} images (positions {tuple(layout['positions'])}, {args.objects} objects x "
          f"{args.poses} poses) in {time.perf_counter() - t0:.1f} s -> {manifest}")
    return 0


def cmd_train(args) -> int:
    from ..database import load_database
    from ..modelfile import save_model
    from ..progress import bar
    from ..train import train_model

    comps: int | float = args.components
    if float(comps).is_integer() and comps >= 1:
        comps = int(comps)
    elif not 0 < comps <= 1:
        raise UsageError(f"--components must be an integer >= 1 or a fraction in (0, 1], got {args.components}")
    calibrate = None
    if args.calibrate:
        from ..calibration import calibrate_model as calibrate
    db = load_database(args.database)
    with bar(sum(db.positions), f"train {args.kind}", "pos") as b:
        model, info = train_model(db, kind=args.kind, n_components=comps, samples_per_image=args.samples,
                                  covariance=args.covariance, seed=args.seed, progress=b.set,
                                  return_info=True)
    params = dict(info.params)
    calibration = None
    if calibrate is not None:
        model, cal = calibrate(model, db)
        params["calibrated"] = True
        calibration = cal.to_dict()
        print(cal.summary())
    path = save_model(args.out, model, training=params, manifest_sha256=info.manifest_sha256,
                      calibration=calibration)
    print(f"trained {args.kind} (K={params['K']}) in {info.seconds:.1f} s -> {path}")
    print(model.summary())
    return 0


def _database_summary(db) -> str:
    import numpy as np

    splits = {s: int((np.asarray(db.split) == s).sum()) for s in ("train", "test", "calib")}
    H, W = db.image_shape
    return "\n".join([
        f"ImageDatabase {db.root}: {db.n_rows} images {H}x{W}",
        f"  cameras {db.n_cameras}, positions {db.positions}, {db.n_objects} objects x {db.n_poses} poses",
        "  splits: " + ", ".join(f"{k} {v}" for k, v in splits.items()),
    ])


def _calibration_lines(model) -> list[str]:
    """Each calibrated camera's variance factors ``[V, L]``, per position: one
    row per occlusion level (one row when every level has the same factors)."""
    import numpy as np

    lines = []
    for i, cam in enumerate(model.cameras):
        if cam.calibration is None:
            continue
        f = np.asarray(cam.calibration, dtype=float)
        lines.append(f"  camera {i} variance factors, positions 0..{f.shape[0] - 1}:")
        if np.all(f == f[:, :1]):
            rows = [("all levels", f[:, 0])]
        else:
            rows = [(f"level {lv:.2f}", f[:, j]) for j, lv in enumerate(model.levels)]
        lines += [f"    {name}: " + " ".join(f"{x:.3g}" for x in r) for name, r in rows]
    return lines


def _model_report(path, model=None) -> str:
    """What ``inspect`` prints for a model file: its summary, how it was
    trained and, when calibrated, the variance factors per camera and position."""
    from ..modelfile import load_model_meta

    model = _load_model(str(path)) if model is None else model
    lines = [f"model file {path}", model.summary()]
    train = load_model_meta(path).get("training") or {}
    if isinstance(train.get("params"), dict):  # TrainingInfo.to_dict() (experiments.prepare) nests them
        train = train["params"]
    if train:
        keys = ("kind", "K", "samples_per_image", "covariance", "seed")
        lines.append("  training: " + ", ".join(f"{k} {train[k]}" for k in keys if k in train))
    return "\n".join(lines + _calibration_lines(model))


def cmd_inspect(args) -> int:
    import numpy as np

    from .. import plots

    path = Path(args.path)
    written = []
    if not path.exists() and path.suffix != ".npz":
        raise CLIError(f"{path}: no such model file or database folder")
    if path.is_dir():
        from ..database import load_database, notes

        db = load_database(path)
        print("\n".join([_database_summary(db), *notes(db)]))
        if args.plot_dir:
            rows = np.flatnonzero((np.asarray(db.camera) == args.camera) & (np.asarray(db.position) == args.position)
                                  & (np.asarray(db.split) == "train"))
            if rows.size == 0:
                raise UsageError(f"the database has no train image at camera {args.camera}, position {args.position}")
            written += plots.occlusion_examples(db.images[rows[0]], Path(args.plot_dir) / "occlusion_examples",
                                                title=f"DB2 occluders on camera {args.camera}, position {args.position}")
    else:
        model = _load_model(str(path))
        print(_model_report(path, model))
        if args.plot_dir:
            if args.camera >= len(model.cameras) or args.position >= model.cameras[args.camera].mu.shape[0]:
                raise UsageError(f"the model has no camera {args.camera} position {args.position} "
                                 f"(positions {_model_positions(model)})")
            cam = model.cameras[args.camera]
            written += plots.eigenimages(np.asarray(cam.mean_image[args.position]), np.asarray(cam.basis[args.position]),
                                         model.image_shape, Path(args.plot_dir) / "eigenimages",
                                         eigenvalues=np.asarray(cam.eigenvalues[args.position]),
                                         title=f"Camera {args.camera}, position {args.position}")
    for p in written:
        print(f"wrote {p}")
    return 0


def _scores_report(scores, positions, top: int) -> tuple[int, list]:
    import numpy as np

    s = np.asarray(scores, dtype=float)
    order = np.argsort(np.where(np.isfinite(s), -s, np.inf), kind="stable")[:top]
    rows = [(r + 1, _fmt_cfg(np.unravel_index(a, positions)), int(a), f"{s[a]:.4g}") for r, a in enumerate(order)]
    return int(order[0]), rows


def cmd_plan(args) -> int:
    import jax.random as jr
    import numpy as np

    P, R = _recognizer_modules()
    model = _load_model(args.model)
    positions = _model_positions(model)
    imgs = None
    if args.images:  # check everything before the (costly) planner tables
        if args.at is None:
            raise UsageError("--images needs --at V1,V2 (where they were taken)")
        if len(args.images) != len(positions) or len(args.at) != len(positions):
            raise UsageError(f"the model has {len(positions)} camera(s): give that many --images and --at positions")
        if any(v >= n for v, n in zip(args.at, positions)):
            raise UsageError(f"--at {_fmt_cfg(args.at)} is outside the model's positions {positions}")
        imgs = np.stack([_read_gray(p, model.image_shape) for p in args.images])
    elif args.at is not None:
        raise UsageError("--at is only used with --images")
    k_plan, k_score = jr.split(_key(args.seed))
    planner = P.make_planner(args.planner, model, key=k_plan, samples=args.samples,
                             min_per_stratum=args.min_per_stratum)
    rec = R.Recognizer(model, planner)
    if imgs is not None:
        state = rec.init(config=args.at)
        _, dec = rec.step(state, imgs, k_score, trace=True)
        scores = np.asarray(dec.trace.scores)
        print(f"after the images at {_fmt_cfg(args.at)}: best (object, pose) = ({int(dec.object)}, {int(dec.pose)}), "
              f"P = {float(dec.probability):.3f}")
        what = f"belief after images at ({_fmt_cfg(args.at)})"
    else:
        state = rec.init(config=(0,) * len(positions))
        scores = np.asarray(planner.scores(state.prior, k_score))
        what = "uniform belief"
    best, rows = _scores_report(scores, positions, args.top)
    cfg = np.unravel_index(best, positions)
    print(f"{args.planner} scores of {scores.size} configurations ({what}); best: ({_fmt_cfg(cfg)}) "
          f"index {best}, score {scores[best]:.4g}")
    _print_table(["rank", "config", "index", "score"], rows)
    if args.plot:
        from .. import plots

        for p in plots.score_heatmap(scores, positions, args.plot, chosen=cfg,
                                     title=f"{args.planner.upper()} scores, {what}",
                                     label=f"{args.planner} score (higher = better)"):
            print(f"wrote {p}")
    return 0


def _make_rig(args, model):
    """The rig of ``--rig`` and whether the CLI owns (closes) it."""
    spec = args.rig
    if spec == "synthetic":
        from ..hardware import Noise

        if args.objects != model.n_objects or args.poses != model.n_poses:
            args.objects, args.poses = model.n_objects, model.n_poses
        return _synthetic_rig(args, noise=Noise(brightness=0.03, pixel=args.noise, max_shift=1), seed=args.seed)
    if spec.startswith("dataset:"):
        from ..hardware import DatasetRig

        folder = spec[len("dataset:"):]
        if not folder:
            raise UsageError("--rig dataset:FOLDER needs a folder")
        return DatasetRig.from_folder(folder, seed=args.seed)
    if spec.endswith(".toml"):
        if not Path(spec).is_file():
            raise CLIError(f"rig file {spec} not found")
        from ..hardware import rig_from_config

        return rig_from_config(spec)
    raise UsageError(f"--rig {spec!r}: expected 'synthetic', 'dataset:FOLDER' or a .toml rig file")


def cmd_recognize(args) -> int:
    import jax.random as jr
    import numpy as np

    P, R = _recognizer_modules()
    model = _load_model(args.model)
    positions = _model_positions(model)
    if args.object >= model.n_objects or args.pose >= model.n_poses:
        raise UsageError(f"--object/--pose: the model has {model.n_objects} objects x {model.n_poses} poses")
    if args.start is not None and (len(args.start) != len(positions)
                                   or any(v >= n for v, n in zip(args.start, positions))):
        raise UsageError(f"--start {_fmt_cfg(args.start)} does not fit the model's positions {positions}")
    if args.occluders and args.rig != "synthetic":
        raise UsageError("--occluders works with --rig synthetic only")
    k_plan, k_init, k_run = jr.split(_key(args.seed), 3)
    rig = _make_rig(args, model)
    try:
        if tuple(rig.positions) != positions:
            raise CLIError(f"rig {args.rig} has positions {tuple(rig.positions)} but model {args.model} has "
                           f"{positions} (for the synthetic rig use the --cameras/--stride the database "
                           "was rendered with)")
        planner = P.make_planner(args.planner, model, key=k_plan, samples=args.samples,
                             min_per_stratum=args.min_per_stratum)
        rec = R.Recognizer(model, planner, p_threshold=args.threshold, max_steps=args.max_steps)
        state = rec.init(key=None if args.start is not None else k_init, config=args.start)
        occl = None
        if args.occluders:
            from ..experiments import occluder_factory  # the thesis-case boards (first views occluded)

            start = tuple(int(v) for v in np.asarray(state.config))
            occl = occluder_factory(rig)(np.random.default_rng(args.seed), start)
        rig.reset(args.object, args.pose, occl)
        probs = [np.full(model.n_objects, 1.0 / model.n_objects)]
        rows = []
        dec = None
        for n in range(args.max_steps):
            cfg = tuple(int(v) for v in np.asarray(state.config))
            rig.move(cfg)
            cap = rig.capture()
            state, dec = rec.step(state, cap.images, jr.fold_in(k_run, n), trace=True)
            probs.append(np.asarray(dec.trace.object_probs, dtype=float))
            occ = cap.occluded
            stop = bool(dec.stop)
            rows.append((n + 1, _fmt_cfg(cfg), int(dec.object), int(dec.pose), f"{float(dec.probability):.3f}",
                         " ".join(f"{100 * x:.0f}%" for x in occ) or "-",
                         "stop" if stop else _fmt_cfg(np.asarray(dec.next_config))))
            if stop:
                break
    finally:
        close = getattr(rig, "close", None)
        if close is not None:
            close()
    print(f"object {args.object}, pose {args.pose} on rig {args.rig}; planner {args.planner}, "
          f"P_th {args.threshold}")
    _print_table(["step", "config", "object", "pose", "P", "occluded", "next"], rows)
    ok = int(dec.object) == args.object and int(dec.pose) == args.pose
    print(f"result: object {int(dec.object)}, pose {int(dec.pose)} with P = {float(dec.probability):.3f} after "
          f"{len(rows)} step(s) -- {'correct' if ok else 'WRONG'}")
    if args.plot:
        from .. import plots

        for p in plots.belief_lines(np.stack(probs), args.plot, true_object=args.object,
                                    title=f"Belief per step: object {args.object + 1} (index {args.object}), "
                                          f"pose {args.pose}, {args.planner.upper()}"):
            print(f"wrote {p}")
    return 0


# -- experiments -------------------------------------------------------------

def _experiments():
    ex = _require("jaxrecog.experiments", "experiment")
    for name in ("CASES", "Settings", "run_case"):
        if not hasattr(ex, name):
            raise CLIError(f"jaxrecog.experiments has no {name} (this build is incomplete)")
    return ex


def _settings_fields(Settings) -> set[str]:
    if dataclasses.is_dataclass(Settings):
        return {f.name for f in dataclasses.fields(Settings)}
    import inspect

    return set(inspect.signature(Settings).parameters)


def _make_settings(ex, values: dict[str, Any], where: str):
    known = _settings_fields(ex.Settings)
    bad = sorted(set(values) - known)
    if bad:
        raise UsageError(problem_message(f"{where}: unknown setting(s) (known: {', '.join(sorted(known))})", bad))
    return ex.Settings(**values)


def _write_report(report, name: str, out: Path, thesis_key: str | None, title: str | None = None) -> list[Path]:
    """``case_NAME.md`` / ``.json`` and the ``campaign_NAME`` bars (PNG + SVG),
    with the thesis's numbers as markers for a thesis case on the full table."""
    from .. import plots
    from ..thesis import SINGLE_CAMERA, TABLES

    full_table = getattr(report.settings, "stride", 1) == 1  # a strided table is not the thesis's rig
    thesis_key = thesis_key if full_table else None

    out.mkdir(parents=True, exist_ok=True)
    written = []
    md = out / f"case_{name}.md"
    md.write_text(report.markdown())
    written.append(md)
    js = report.to_json()
    js_path = out / f"case_{name}.json"
    js_path.write_text(js if isinstance(js, str) else json.dumps(js, indent=2))
    written.append(js_path)
    rows = dict(report.rows)
    # "mi-class" and "crlb-det" are variants of the thesis's "mi" / "crlb" planners
    ref = {p: TABLES[(thesis_key, p.split("-")[0])] for p in rows
           if (thesis_key, p.split("-")[0]) in TABLES} if thesis_key else {}
    if full_table and name.startswith("single-") and name.split("-", 1)[1] in SINGLE_CAMERA:
        # the thesis gives only the average for the single camera (§7.3), MI planner
        rate, views, exitp = SINGLE_CAMERA[name.split("-", 1)[1]]
        n_obj = sum(r.label != "Average" for r in next(iter(rows.values())))
        avg = types.SimpleNamespace(rate=(math.nan,) * n_obj, views=(math.nan,) * n_obj,
                                    average=(rate, exitp, views))
        ref = {p: avg for p in rows if p.startswith("mi")}
    written += plots.campaign_bars(rows, out / f"campaign_{name}", thesis=ref,
                                   title=(title or f"Case ({name})")
                                         + ("" if full_table else f", every {report.settings.stride}th position")
                                         + f": {report.settings.trials_per_object} trials per object"
                                         + (", markers: thesis" if ref else ""))
    return written


def _trace_plot(ex, settings, out: Path, planner: str = "mi", obj: int = 5, prepared=None,
                case: str = "iii") -> list[Path]:
    import numpy as np

    from .. import plots
    from ..thesis import TABLE_7_8

    if not hasattr(ex, "run_trace"):
        raise CLIError("jaxrecog.experiments has no run_trace (this build is incomplete)")
    res = ex.run_trace(settings, object=obj, planner=planner, prepared=prepared, case=case)
    probs = np.asarray(res.object_probs, dtype=float)
    M = probs.shape[1]
    probs = np.vstack([np.full((1, M), 1.0 / M), probs])
    thesis_rig = getattr(settings, "stride", 1) == 1
    ref = np.asarray(TABLE_7_8) if thesis_rig and M == len(TABLE_7_8[0]) and obj == 5 and case == "iii" else None
    scene = "occluded" if ex.CASES[case].occluded else "clean"
    return list(plots.belief_lines(probs, out / "belief_trace", true_object=res.object, reference=ref,
                                   title=f"Belief per step: object {res.object + 1} (index {res.object}), "
                                         f"pose {res.pose}, {planner.upper()}, case {case} ({scene})"))


def _dataset_folder(rig: str) -> str:
    if not rig.startswith("dataset:"):
        raise UsageError(f"--rig {rig!r}: expected 'synthetic' or 'dataset:FOLDER'")
    folder = rig[len("dataset:"):]
    if not folder:
        raise UsageError("--rig dataset:FOLDER needs a folder")
    return folder


def cmd_experiment(args, file_settings: dict[str, Any] | None = None) -> int:
    ex = _experiments()
    values: dict[str, Any] = {}
    planners = args.planners
    name = args.case
    rig, model = args.rig, args.model
    if name is not None and (name.endswith(".toml") or Path(name).is_file()):
        from ..config import ConfigFileError, load_settings

        path = name
        try:
            data = load_settings_flat(path)
        except ConfigFileError as e:
            raise UsageError(str(e)) from None
        file_rig, file_model = data.pop("rig", None), data.pop("model", None)
        rig = rig if rig is not None else file_rig
        model = model if model is not None else file_model
        if "case" not in data and rig in (None, "synthetic"):
            raise UsageError(f"experiment file {path}: needs a 'case' key ({', '.join(ex.CASES)}) "
                             "or 'rig' = 'dataset:FOLDER' and 'model'")
        name = str(data.pop("case")) if "case" in data else None
        if planners is None and "planners" in data:
            planners = list(data.pop("planners"))
        data.pop("planners", None)
        values.update(data)
    dataset = rig is not None and str(rig) != "synthetic"
    if dataset:
        folder = _dataset_folder(str(rig))
        if name is not None:
            raise UsageError(f"--rig {rig} replays a database, not a thesis case: leave out the case ({name})")
        if not model:
            raise UsageError("--rig dataset:FOLDER needs --model MODEL.NPZ (a model file trained on the database)")
        if args.trace:
            raise UsageError("--trace works with the thesis cases (synthetic rig) only")
        if (args.stride or values.get("stride", 1)) != 1:
            raise UsageError("--stride selects positions of the synthetic rig; a database has its own positions")
    else:
        if model:
            raise UsageError("--model is used with --rig dataset:FOLDER only (a thesis case trains its own models)")
        if name is None:
            raise UsageError("give a CASE (" + ", ".join(ex.CASES) + ") or an experiment TOML file, "
                             "or --rig dataset:FOLDER --model MODEL.NPZ")
        if name not in ex.CASES:
            raise UsageError(f"unknown case {name!r}; choose {', '.join(ex.CASES)} or a TOML file")
    out = Path(args.out)
    over = {"trials_per_object": args.trials, "samples": args.samples,
            "min_per_stratum": args.min_per_stratum, "batch": args.batch, "seed": args.seed,
            "stride": args.stride}
    values.update({k: v for k, v in over.items() if v is not None})
    if args.quick:
        for k, v in _quick_settings(ex).items():
            values.setdefault(k, v)
    values.setdefault("workdir", args.workdir or str(out / "work"))
    if args.workdir:
        values["workdir"] = args.workdir
    settings = _make_settings(ex, values, args.case or "experiment")
    t0 = time.perf_counter()
    if dataset:
        report = ex.run_dataset(folder, model, settings, planners=planners, progress=_bars())
        print(report.markdown())
        written = _write_report(report, "dataset", out, None, title=f"Database {Path(folder).name}")
        print(f"campaign on {folder} in {time.perf_counter() - t0:.0f} s; wrote:")
    else:
        report = ex.run_case(name, settings, planners=planners, progress=_bars())
        print(report.markdown())
        written = _write_report(report, name, out, name if name in ("i", "ii", "iii") else None)
        if args.trace:
            written += _trace_plot(ex, settings, out, planner=(planners or ["mi"])[0], case=name)
        print(f"case {name} in {time.perf_counter() - t0:.0f} s; wrote:")
    for p in written:
        print(f"  {p}")
    return 0


def _bars() -> bool:
    from ..progress import enabled

    return enabled()


#: "Quick" runs (demo, ``experiment --quick``): fewer Monte Carlo and training
#: samples and a smaller eigenspace; the database is still the thesis's 32 x 7
#: (``--stride`` thins it).
QUICK = {"samples": 256, "min_per_stratum": 2, "samples_per_image": 30, "n_components": 12}


def _quick_settings(ex) -> dict[str, Any]:
    known = _settings_fields(ex.Settings)
    if "quick" in known:
        return {"quick": True}
    return {k: v for k, v in QUICK.items() if k in known}


def load_settings_flat(path: str) -> dict[str, Any]:
    """An experiment TOML: top-level keys (``case``, ``planners``, Settings
    fields); a ``[settings]`` table is merged in too."""
    from ..config import ConfigFileError, read_toml

    data = read_toml(path, "experiment file")
    inner = data.pop("settings", {})
    if not isinstance(inner, dict):
        raise ConfigFileError(f"experiment file {path}: 'settings' must be a table")
    data.update(inner)
    return data


def cmd_bench(args) -> int:
    from ..progress import bar

    folder = Path(args.benchmarks) if args.benchmarks else Path(__file__).resolve().parent.parent / "benchmarks"
    scripts = sorted(folder.glob("bench_*.py")) if folder.is_dir() else []
    if args.only:
        want = {n.removeprefix("bench_").removesuffix(".py") for n in args.only}
        scripts = [s for s in scripts if s.stem.removeprefix("bench_") in want]
    if not scripts:
        raise CLIError(f"no benchmark scripts (bench_*.py) found in {folder}"
                       + (f" matching {' '.join(args.only)}" if args.only else ""))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    merged: dict[str, Any] = {}
    rows = []
    with bar(len(scripts), "bench", "script") as b:
        for s in scripts:
            name = s.stem.removeprefix("bench_")
            target = out / f"{name}.json"
            t0 = time.perf_counter()
            try:
                proc = subprocess.run([sys.executable, str(s), "--out", str(target)], capture_output=True,
                                      text=True, timeout=args.timeout)
                rc = proc.returncode
                err = (proc.stderr.strip().splitlines() or [""])[-1]
            except subprocess.TimeoutExpired:
                rc, err = None, f"timed out after {args.timeout} s"
            wall = time.perf_counter() - t0
            if rc == 0 and target.is_file():
                try:
                    merged[name] = json.loads(target.read_text())
                    status = "ok"
                except ValueError:
                    merged[name] = {"error": "unreadable JSON"}
                    status = "bad JSON"
            else:
                merged[name] = {"error": err or f"exit code {rc}"}
                status = "failed" if rc is not None else "timeout"
            rows.append((name, status, f"{wall:.1f}", _headline(merged[name])))
            b.update(1)
    merged_path = out / "bench.json"
    merged_path.write_text(json.dumps(merged, indent=2) + "\n")
    _print_table(["benchmark", "status", "wall s", "numbers"], rows)
    print(f"wrote {merged_path}")
    failed = [r[0] for r in rows if r[1] != "ok"]
    if failed:
        raise CLIError(problem_message(f"benchmark(s) failed (see {merged_path})", failed))
    return 0


_NOT_HEADLINES = {"cpus", "seed", "repeats", "version", "format_version"}


def _headline(d: Any, limit: int = 4) -> str:
    """A few timing numbers of a benchmark's JSON: leaves named like a median,
    a rate or a wall time, at any depth (``mi.J=1.uniform/state.median_ms``);
    other top-level numbers when there are none."""
    if not isinstance(d, dict):
        return ""
    if "error" in d:
        return str(d["error"])[:60]
    timing = ("median_ms", "median", "wall_s", "seconds", "fps_clean", "trials_per_s", "peak_rss_mb")
    found: list[tuple[str, float]] = []

    def walk(node: Any, path: str) -> None:
        for k, v in node.items():
            key = f"{path}.{k}" if path else str(k)
            if isinstance(v, dict):
                walk(v, key)
            elif isinstance(v, list):
                for i, item in enumerate(v):
                    if isinstance(item, dict):
                        walk(item, f"{key}[{item.get('planner', i)}]")
            elif (k in timing or str(k).startswith("median")) and isinstance(v, (int, float)) and not isinstance(v, bool):
                found.append((key, float(v)))

    walk(d, "")
    if not found:
        found = [(k, v) for k, v in d.items()
                 if k not in _NOT_HEADLINES and isinstance(v, (int, float)) and not isinstance(v, bool)]
    return ", ".join(f"{k}={v:.4g}" for k, v in found[:limit])


def cmd_demo(args) -> int:
    ex = _experiments()
    out = Path(args.out)
    t0 = time.perf_counter()
    values = {"workdir": str(out / "work"), "trials_per_object": args.trials, "seed": args.seed,
              "stride": args.stride}
    values.update(_quick_settings(ex))
    settings = _make_settings(ex, values, "demo")
    prepared = ex.prepare(settings, progress=_bars(), databases=("DB1", "DB2"))
    print(f"database and DB1/DB2 models ready in {time.perf_counter() - t0:.0f} s ({settings.workdir})")
    for kind, path in sorted(prepared.models.items()):
        print(f"{kind} model:")
        print(_model_report(path))
    report = ex.run_case("iii", settings, planners=list(args.planners), progress=_bars(), prepared=prepared)
    print(report.markdown())
    written = _write_report(report, "iii", out, "iii")
    written += _trace_plot(ex, settings, out, planner=args.planners[0], prepared=prepared)
    written += _demo_model_plots(prepared, settings, out, args.seed)
    print(f"demo finished in {time.perf_counter() - t0:.0f} s; tables and plots:")
    for p in written:
        print(f"  {p}")
    return 0


def _find_model(prepared, kind: str = "DB2"):
    """The model of :func:`experiments.prepare` (``Prepared.models[kind]``)."""
    path = (getattr(prepared, "models", None) or {}).get(kind)
    return _load_model(str(path)) if path is not None else None


def _demo_model_plots(prepared, settings, out: Path, seed: int) -> list[Path]:
    import numpy as np

    from .. import plots

    written: list[Path] = []
    model = _find_model(prepared)
    if model is None:
        print("(no DB2 model found in the work folder: skipping the heat map and eigenimages)")
        return written
    P, R = _recognizer_modules()
    import jax.random as jr

    k1, k2 = jr.split(_key(seed))
    positions = _model_positions(model)
    planner = P.make_planner("mi", model, key=k1, samples=getattr(settings, "samples", 256) or 256,
                             min_per_stratum=getattr(settings, "min_per_stratum", 1))
    prior = R.Recognizer(model, planner).init(config=(0,) * len(positions)).prior
    scores = np.asarray(planner.scores(prior, k2))
    written += plots.score_heatmap(scores, positions, out / "mi_scores",
                                   title="MI of every configuration, uniform belief", label="MI (nats)")
    cam = model.cameras[0]
    written += plots.eigenimages(np.asarray(cam.mean_image[0]), np.asarray(cam.basis[0]), model.image_shape,
                                 out / "eigenimages", eigenvalues=np.asarray(cam.eigenvalues[0]),
                                 title="Camera 0, position 0")
    img = (np.asarray(cam.mean_image[0]).reshape(model.image_shape))
    img = np.clip(255 * (img - img.min()) / max(float(np.ptp(img)), 1e-12), 0, 255).astype(np.uint8)
    db_img = _first_train_image(Path(settings.workdir))
    written += plots.occlusion_examples(db_img if db_img is not None else img, out / "occlusion_examples",
                                        levels=tuple(x for x in model.levels if x > 0) or (0.05, 0.25))
    return written


def _first_train_image(workdir: Path):
    import cv2

    for m in sorted(workdir.rglob("manifest.csv")):
        for cand in sorted((m.parent / "train").rglob("*.png"))[:1]:
            img = cv2.imread(str(cand), cv2.IMREAD_GRAYSCALE)
            if img is not None:
                return img
    return None


COMMANDS = {
    "render": cmd_render,
    "train": cmd_train,
    "inspect": cmd_inspect,
    "plan": cmd_plan,
    "recognize": cmd_recognize,
    "experiment": cmd_experiment,
    "bench": cmd_bench,
    "demo": cmd_demo,
}


# --------------------------------------------------------------------------
# entry point
# --------------------------------------------------------------------------

def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


def _apply_config(parser: argparse.ArgumentParser, path: str) -> dict[str, Any]:
    """Set option defaults from the TOML file (command line still wins)."""
    from ..config import load_settings, section

    data = load_settings(path)
    known_global = {"quiet", "debug"}
    glob = section(data, "global", known_global, path)
    subs = _subparsers(parser)
    unknown = sorted(set(data) - set(subs) - {"global"})
    if unknown:
        from ..config import ConfigFileError

        raise ConfigFileError(problem_message(f"settings file {path}: unknown table(s) "
                                              f"(known: global, {', '.join(subs)})", unknown))
    for name, sp in subs.items():
        dests = {a.dest for a in sp._actions if a.option_strings and a.dest not in ("help", "config")}
        values = section(data, name, dests, path)
        if values:
            sp.set_defaults(**values)
    return glob


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    debug = "--debug" in argv
    try:
        pre = argparse.ArgumentParser(add_help=False)
        pre.add_argument("--config")
        pre.add_argument("--debug", action="store_true")
        known, _ = pre.parse_known_args(argv)
        glob: dict[str, Any] = {}
        if known.config:
            from ..config import ConfigFileError

            try:
                glob = _apply_config(parser, known.config)
            except ConfigFileError as e:
                parser.error(str(e))
        args = parser.parse_args(argv)
    except SystemExit as e:  # argparse: --help (0) or usage error (2)
        return int(e.code) if isinstance(e.code, int) else 2
    args.quiet = bool(getattr(args, "quiet", False) or glob.get("quiet", False))
    args.debug = bool(getattr(args, "debug", False) or glob.get("debug", False) or debug)
    from ..progress import set_quiet

    set_quiet(args.quiet)
    try:
        return int(COMMANDS[args.command](args) or 0)
    except UsageError as e:
        if args.debug:
            raise
        sub = _subparsers(parser)[args.command]
        sub.print_usage(sys.stderr)
        print(f"jaxrecog {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxrecog: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # noqa: BLE001 - the one place that turns failures into exit code 1
        if args.debug:
            for problem in getattr(e, "problems", None) or ():  # the full list, then the traceback
                print(problem, file=sys.stderr)
            raise
        # one line per line of the message: a list of problems stays readable
        msg = "\n  ".join(" ".join(line.split()) for line in str(e).splitlines() if line.strip()) \
            or type(e).__name__
        if not isinstance(e, (CLIError, OSError, ValueError)) and type(e).__name__ not in msg:
            msg = f"{type(e).__name__}: {msg}"
        print(f"jaxrecog: error: {msg}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
