"""``jaxrecog inspect``: summarise a model file or an image database."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .._files import check_output_folder
from .. import plots
from ..database import SPLITS, load_database, notes, shared_files
from ..modelfile import load_model
from ._common import CLIError, UsageError, model_doc, model_positions, model_report
from ._json import SCHEMA_VERSION, json_option, run_reporting
from ._options import nonneg

NAME = "inspect"
ORDER = 30
HELP = "summarise a model file or an image database"
DESCRIPTION = ("Print a summary of a model file (.npz; with a calibrated model, its variance factors\n"
               "per camera and position) or an image database folder; optionally draw its\n"
               "eigenimages (model) or occluder examples (database).")


def add_arguments(p) -> None:
    p.add_argument("path", metavar="PATH", help="model file or database folder")
    p.add_argument("--plot-dir", metavar="FOLDER",
                   help="write figures here: eigenimages (model) or occlusion examples (database)")
    p.add_argument("--camera", type=nonneg, default=0, help="camera of the eigenimage / example figure")
    p.add_argument("--position", type=nonneg, default=0, help="position of the eigenimage / example figure")
    json_option(p)


def _splits(db) -> dict[str, int]:
    split = np.asarray(db.split)
    return {s: int((split == s).sum()) for s in SPLITS if s != "jitter" or (split == s).any()}


def _database_doc(db) -> dict:
    H, W = db.image_shape
    return {"root": str(db.root), "images": int(db.n_rows), "image_shape": [int(H), int(W)],
            "cameras": int(db.n_cameras), "positions": [int(n) for n in db.positions], "objects": int(db.n_objects),
            "poses": int(db.n_poses), "splits": _splits(db), "shared_files": int(shared_files(db.paths))}


def _database_summary(db) -> str:
    H, W = db.image_shape
    return "\n".join([
        f"ImageDatabase {db.root}: {db.n_rows} images {H}x{W}",
        f"  cameras {db.n_cameras}, positions {db.positions}, {db.n_objects} objects x {db.n_poses} poses",
        "  splits: " + ", ".join(f"{k} {v}" for k, v in _splits(db).items()),
    ])


def _report(args) -> tuple[dict, str]:
    path = Path(args.path)
    written = []
    if args.plot_dir:  # before any work: a folder (made with its parents) that takes files
        check_output_folder(args.plot_dir, "--plot-dir folder")
    if not path.exists() and path.suffix != ".npz":
        raise CLIError(f"{path}: no such model file or database folder")
    summary = {"model": None, "database": None}
    if path.is_dir():
        db = load_database(path)
        summary["database"] = _database_doc(db)
        text = [_database_summary(db), *notes(db)]
        if args.plot_dir:
            rows = np.flatnonzero((np.asarray(db.camera) == args.camera) & (np.asarray(db.position) == args.position)
                                  & (np.asarray(db.split) == "train"))
            if rows.size == 0:
                raise UsageError(f"the database has no train image at camera {args.camera}, position {args.position}")
            written += plots.occlusion_examples(db.images[rows[0]], Path(args.plot_dir) / "occlusion_examples",
                                                title=f"DB2 occluders on camera {args.camera}, position {args.position}")
    else:
        model = load_model(str(path))
        summary["model"] = model_doc(path, model)
        text = [model_report(path, model)]
        if args.plot_dir:
            if args.camera >= len(model.cameras) or args.position >= model.cameras[args.camera].basis.shape[0]:
                raise UsageError(f"the model has no camera {args.camera} position {args.position} "
                                 f"(positions {model_positions(model)})")
            cam = model.cameras[args.camera]
            written += plots.eigenimages(np.asarray(cam.mean_image[args.position]), np.asarray(cam.basis[args.position]),
                                         model.image_shape, Path(args.plot_dir) / "eigenimages",
                                         eigenvalues=np.asarray(cam.eigenvalues[args.position]),
                                         title=f"Camera {args.camera}, position {args.position}")
    doc = {"command": NAME, "schema_version": SCHEMA_VERSION, "path": str(path),
           "kind": "database" if summary["database"] is not None else "model", **summary,
           "written": [str(p) for p in written]}
    return doc, "\n".join(text + [f"wrote {p}" for p in doc["written"]])


def run(args) -> int:
    return run_reporting(args, _report)
