"""Held-out features for calibration (:mod:`jaxrecog.calibration`): the
``calib`` views of an image database projected with the model (eq. 4.1-4.11,
checked and normalised a position at a time), a held-out part of a test split,
and the checks on features given directly."""

from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np

from .counts import CountsMismatchError, check_counts
from .database import ImageDatabase, load_database
from .features import check_image
from .sensor_model import CameraModel, SensorModel

__all__ = ["CalibrationError", "CameraFeatures", "CalibrationFeatures", "features_from_database",
           "holdout_calibration", "checked_features"]


class CalibrationError(ValueError):
    """Calibration data that cannot be used (no images, wrong sizes, bad labels)."""


class CameraFeatures(NamedTuple):
    """Held-out features of one camera.

    Attributes:
        g: ``float [N, K]`` eigenspace features (eq. 4.1-4.11).
        position: ``int [N]`` position index of each feature.
        cls: ``int [N]`` true class ``c = object · n_poses + pose``.
    """

    g: np.ndarray
    position: np.ndarray
    cls: np.ndarray


class CalibrationFeatures(NamedTuple):
    """Held-out features of every camera of a model (one entry per camera)."""

    cameras: tuple[CameraFeatures, ...]


def features_from_database(model: SensorModel, database: ImageDatabase | str | os.PathLike,
                           split: str = "calib") -> CalibrationFeatures:
    """Project the ``split`` rows of an image database with ``model`` (eq. 4.1-4.11).

    Raises:
        CalibrationError: no rows of that split, or sizes that do not match the model.
        jaxrecog.features.ImageError: a bad image (named by its path).
    """
    db = database if isinstance(database, ImageDatabase) else load_database(database)
    rows = db.rows(split)
    if rows.size == 0:
        raise CalibrationError(
            f"database {db._where()}: no '{split}' rows to calibrate on (render a calib split, "
            f"or hold out part of the test split with holdout_calibration)"
        )
    try:  # a calibration split may cover fewer positions (each row is checked below)
        check_counts(model, db, other_name=f"database {db._where()}", only=("objects", "poses", "image"))
    except CountsMismatchError as e:
        raise CalibrationError(str(e)) from None
    cams = []
    for i, cam in enumerate(model.cameras):
        sel = rows[db.camera[rows] == i]
        if np.any(db.position[sel] >= cam.n_positions):
            bad = sel[db.position[sel] >= cam.n_positions][0]
            raise CalibrationError(f"{db.paths[bad]}: camera {i} position {db.position[bad]} "
                                   f"not in the model ({cam.n_positions} positions)")
        g = _project_rows(cam, db, sel, model.image_shape)
        cams.append(CameraFeatures(g, db.position[sel].copy(), db.class_index[sel].copy()))
    extra = rows[db.camera[rows] >= model.n_cameras]
    if extra.size:
        raise CalibrationError(f"{db.paths[extra[0]]}: camera {db.camera[extra[0]]} not in the model "
                               f"({model.n_cameras} cameras)")
    return CalibrationFeatures(tuple(cams))


def _project_rows(cam: CameraModel, db: ImageDatabase, sel: np.ndarray, image_shape) -> np.ndarray:
    """``g = basis[v]ᵀ (y / ||y|| - mean[v])`` (eq. 4.1-4.11) of the rows ``sel``
    of ``db`` taken by ``cam``, float64 ``[len(sel), K]``: every image checked
    (:func:`~jaxrecog.features.check_image`; the first bad one, in row order,
    raises), then one product per position.  ``||y||²`` of 8-bit pixels is a
    sum of integers below 2^53, exact in any order."""
    images = db.images[sel]
    flat = images.reshape(len(sel), -1)
    bad = np.flatnonzero(flat.min(axis=1, initial=255) == flat.max(axis=1, initial=0)) \
        if images.dtype == np.uint8 and images.shape[1:] == tuple(image_shape) else range(len(sel))
    for j in bad:   # all black or constant (or not 8-bit): check_image names what is wrong
        check_image(images[j], image_shape, name=db.paths[sel[j]])
    mean = np.asarray(cam.mean_image, np.float64)
    basis = np.asarray(cam.basis, np.float64)
    g = np.zeros((len(sel), cam.n_components))
    pos = db.position[sel]
    for v in np.unique(pos):
        at = np.flatnonzero(pos == v)
        y = flat[at].astype(np.float64)
        norm = np.sqrt(np.einsum("nd,nd->n", y, y))
        for j, row in zip(at, y / norm[:, None] - mean[v]):
            g[j] = row @ basis[v]      # one row at a time: the same products as projecting each image alone
    return g


def holdout_calibration(database: ImageDatabase, fraction: float, *, seed: int = 0,
                        source: str = "test") -> ImageDatabase:
    """A copy of ``database`` with a seeded ``fraction`` of its ``source`` rows
    relabelled ``calib`` (held out from evaluation).

    The ``train`` split cannot be the source: the model needs exactly one train
    image per (camera, position, class).
    """
    if source == "train":
        raise CalibrationError("the train split cannot be held out: training needs exactly one "
                               "train image per (camera, position, object, pose); use source='test'")
    if not 0.0 < fraction < 1.0:
        raise CalibrationError(f"fraction must be in (0, 1), got {fraction}")
    rows = database.rows(source)
    if rows.size == 0:
        raise CalibrationError(f"database {database._where()}: no '{source}' rows to hold out")
    rng = np.random.default_rng(seed)
    take = rng.choice(rows, size=max(1, int(round(fraction * rows.size))), replace=False)
    split = database.split.astype(object).copy()
    split[take] = "calib"
    return ImageDatabase.from_arrays(database.images, database.camera, database.position,
                                     database.object, database.pose, split.astype(str),
                                     paths=database.paths, root=database.root)


def checked_features(model: SensorModel, calib, split: str) -> CalibrationFeatures:
    """``calib`` (a database or its folder: its ``split`` rows projected; or
    features) as checked float64 / int64 :class:`CalibrationFeatures` for ``model``.

    Raises:
        CalibrationError: sizes, positions or classes that do not fit the model, NaN, no features.
        TypeError: anything else.
    """
    if isinstance(calib, CalibrationFeatures):
        feats = calib
    elif isinstance(calib, (ImageDatabase, str, os.PathLike)):
        return features_from_database(model, calib, split)
    elif isinstance(calib, (tuple, list)) and all(isinstance(c, CameraFeatures) for c in calib):
        feats = CalibrationFeatures(tuple(calib))
    else:
        raise TypeError(f"calibration data must be an ImageDatabase, a folder or CalibrationFeatures, "
                        f"got {type(calib).__name__}")
    if len(feats.cameras) != model.n_cameras:
        raise CalibrationError(f"calibration features for {len(feats.cameras)} camera(s), the model "
                               f"has {model.n_cameras}")
    out = []
    for i, (f, cam) in enumerate(zip(feats.cameras, model.cameras)):
        g = np.asarray(f.g, np.float64)
        pos = np.asarray(f.position)
        cls = np.asarray(f.cls)
        if g.ndim != 2 or g.shape[1] != cam.n_components or pos.shape != (g.shape[0],) \
                or cls.shape != (g.shape[0],):
            raise CalibrationError(f"camera {i}: features {g.shape}, positions {pos.shape}, classes "
                                   f"{cls.shape}; expected [N, {cam.n_components}], [N], [N]")
        if not np.all(np.isfinite(g)):
            raise CalibrationError(f"camera {i}: calibration features contain NaN or inf")
        if pos.size and (pos.min() < 0 or pos.max() >= cam.n_positions):
            raise CalibrationError(f"camera {i}: positions must be in 0..{cam.n_positions - 1}")
        if cls.size and (cls.min() < 0 or cls.max() >= model.n_classes):
            raise CalibrationError(f"camera {i}: classes must be in 0..{model.n_classes - 1}")
        out.append(CameraFeatures(g, pos.astype(np.int64), cls.astype(np.int64)))
    if sum(f.g.shape[0] for f in out) == 0:
        raise CalibrationError("no calibration features")
    return CalibrationFeatures(tuple(out))
