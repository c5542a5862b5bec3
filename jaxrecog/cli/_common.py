"""What several subcommands share: the two error kinds, table printing, the
synthetic rig of the layout options, and the model report."""

from __future__ import annotations

from typing import Any, Sequence, SupportsInt

import jax.random as jr
import numpy as np

from ..hardware import SyntheticRig, default_objects
from ..hardware.geometry.positions import CameraTable, default_table
from ..modelfile import load_model, load_model_meta
from ..recipes import recipe_from_meta

__all__ = ["CLIError", "UsageError", "fmt_cfg", "format_table", "key", "model_doc", "model_positions", "model_report",
           "print_table", "synthetic_rig", "synthetic_rig_factory"]


class CLIError(Exception):
    """A runtime failure with a message for the user (exit code 1)."""


class UsageError(Exception):
    """A bad argument found after parsing (exit code 2)."""


def key(seed: int):
    return jr.PRNGKey(int(seed))


def model_positions(model) -> tuple[int, ...]:
    return tuple(int(c.basis.shape[0]) for c in model.cameras)


def fmt_cfg(cfg: Sequence[SupportsInt]) -> str:  # ints or NumPy integers
    return ",".join(str(int(v)) for v in cfg)


def format_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """The rows under the headers, right-aligned columns, a rule under the headers."""
    cells = [[str(h) for h in headers]] + [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, widths)) for r in cells]
    return "\n".join([lines[0], "  ".join("-" * w for w in widths), *lines[1:]])


def print_table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    print(format_table(headers, rows))


def _table(cameras: int, stride: int) -> CameraTable:
    t = default_table()
    if cameras == 1:
        t = t.single_camera(0)
    return CameraTable(t.workspace, tuple(v[::stride] for v in t.views))


def synthetic_rig(args, **kw) -> SyntheticRig:
    """The synthetic rig of the layout options (``--cameras/--stride/--objects/--poses``)."""
    return synthetic_rig_factory(args, **kw)()


def synthetic_rig_factory(args, **kw):
    """A picklable callable that builds :func:`synthetic_rig`'s rig (for Ray tasks)."""
    import functools

    if isinstance(args.objects, str):  # "random:N" (_options.object_choice)
        from ..hardware.render.random_objects import parse_objects, random_objects

        _, n = parse_objects(args.objects)
        objs = random_objects(n, seed=getattr(args, "object_seed", 0))
    else:
        objs = default_objects()
        if args.objects > len(objs):
            raise UsageError(f"--objects {args.objects}: the synthetic scene has {len(objs)} objects")
        objs = objs[: args.objects]
    return functools.partial(SyntheticRig, _table(args.cameras, args.stride), objects=objs, n_poses=args.poses, **kw)


def _calibration_lines(model) -> list[str]:
    """Each calibrated camera's variance factors ``[V, L]``, per position: one
    row per occlusion level (one row when every level has the same factors)."""
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


def _augment_line(aug: dict) -> str:
    """The training augmentation of a model file, one line (older files lack the
    capture transforms: they were off)."""
    parts = [f"{k} {aug[k]}" for k in ("noise_sigma", "brightness_sigma", "max_shift") if k in aug]
    blur = aug.get("blur_sigma") or (0.0, 0.0)
    capture = [
        f"rotation +-{aug.get('max_rotation', 0.0):g} deg",
        f"scale +-{aug.get('max_scale', 0.0):g}",
        f"blur sigma {float(blur[0]):g}..{float(blur[1]):g} px",
        f"gain +-{aug.get('gain_amplitude', 0.0):g} ({aug.get('gain_cells', 3)}x{aug.get('gain_cells', 3)} grid)",
    ]
    on = (aug.get("max_rotation", 0) or aug.get("max_scale", 0) or float(blur[1]) > 0
          or aug.get("gain_amplitude", 0))
    gray = aug.get("occluder_gray") or (0.0, 0.0)
    occluders = (f"; occluders gray {float(gray[0]):g}..{float(gray[1]):g}" if float(gray[1]) > 0 else "")
    return ", ".join(parts) + "; capture " + (", ".join(capture) if on else "off") + occluders


def model_doc(path, model=None) -> dict:
    """What ``inspect --json`` reports of a model file (the ``model`` object
    of :data:`jaxrecog.cli._json.SCHEMAS` ``["inspect"]``)."""
    model = load_model(str(path)) if model is None else model
    meta = load_model_meta(path)
    recipe = recipe_from_meta(meta)
    H, W = model.image_shape
    per_camera = [{"camera": i, **stats,
                   "variance_factors": None if cam.calibration is None else np.asarray(cam.calibration, dtype=float)}
                  for i, (cam, stats) in enumerate(zip(model.cameras, model.camera_stats()))]
    training = meta.get("training")
    return {"cameras": model.n_cameras, "positions": list(model_positions(model)), "objects": model.n_objects,
            "poses": model.n_poses, "classes": model.n_classes, "image_shape": [int(H), int(W)],
            "components": model.n_components, "levels": [float(x) for x in model.levels],
            "likelihood": model.covariance, "per_camera": per_camera,
            "recipe": {**recipe.to_dict(), "recorded": "recipe" in meta},
            "training": training if isinstance(training, dict) else None}


def model_report(path, model=None) -> str:
    """What ``inspect`` (and ``demo``) prints for a model file: its summary, how
    it was trained and, when calibrated, the variance factors per camera and position."""
    model = load_model(str(path)) if model is None else model
    lines = [f"model file {path}", model.summary()]
    meta = load_model_meta(path)
    recipe = recipe_from_meta(meta)
    lines.append(f"  recipe: {recipe.name} (version {recipe.version})"
                 + ("" if "recipe" in meta else ", a file written before recipes")
                 + ": " + ", ".join(recipe.describe()))
    train = meta.get("training") or {}
    if isinstance(train.get("params"), dict):  # TrainingInfo.to_dict() (campaigns.prepare) nests them
        train = train["params"]
    if train:
        keys = ("kind", "K", "samples_per_image", "covariance", "seed")
        lines.append("  training: " + ", ".join(f"{k} {train[k]}" for k in keys if k in train))
        aug = train.get("augment")
        if isinstance(aug, dict):
            lines.append("  augmentation: " + _augment_line(aug))
        vj = train.get("view_jitter")
        if isinstance(vj, dict):
            how = ("one mixture component each" if vj.get("mode") == "components"
                   else f"{vj.get('mode')} to the training images' samples")
            lines.append(f"  view jitter: {vj.get('images')} jitter image(s) of {vj.get('views')} view(s), {how}")
        ip = train.get("interpolate")
        if isinstance(ip, dict):
            lines += interpolation_lines(ip)
    return "\n".join(lines + _calibration_lines(model))


def interpolation_lines(ip: dict) -> list[str]:
    """What ``inspect`` says of a model's interpolated views (training's
    ``params["interpolate"]``): how many of each camera's position sides
    found a neighbouring view to interpolate towards, and, where some did
    not, what that means and what to do."""
    cams = ip.get("neighbours", [])
    found = [sum(x >= 0 for pair in cam for x in pair) for cam in cams]
    total = [2 * len(cam) for cam in cams]
    per = ", ".join(f"camera {i} {f} of {t}" for i, (f, t) in enumerate(zip(found, total)))
    lines = [f"  interpolated views: {ip.get('points_per_side')} per side of each training position, towards "
             f"its neighbouring views ({per} sides have one)"]
    if any(f < t for f, t in zip(found, total)):
        lines.append("    a side without a neighbour gets no views between the positions: test views there are "
                     "explained by the training view alone (less sure); a camera with one position, or positions "
                     "that do not follow each other in order, have none -- add positions in between, or "
                     "number them along the path")
    return lines
