"""Training: image database -> eigenspaces -> augmented samples -> likelihoods.

:func:`train_model` is the public entry.  For every camera position it builds
the eigenspace of the clean training images (:mod:`jaxrecog.eigenspace`), then
streams the augmented samples of every (class, level) through
:class:`~jaxrecog.sensor_model.GaussianAccumulator` in batches — the samples
are never all held — and fits the chosen likelihood family from their moments
(``Likelihood.fit``; default the thesis's diagonal Gaussian).

The per-position fitting and its speed are :mod:`jaxrecog.train_position`'s.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .augment import AugmentParams, levels_for, occluder_bank
from .counts import CountsMismatchError, check_counts
from .database import ImageDatabase, load_database
from .view_interpolation import INTERPOLATIONS, interpolated_views, view_neighbours
from .eigenspace import choose_n_components, position_eigenspace
from .kernels import Likelihood, likelihood_class
from .sensor_model import CameraModel, SensorModel
from .train_position import fit_position, stack_arrays, stack_positions

__all__ = ["train_model", "TrainingInfo", "add_objects", "AddObjectsError", "added_calibration_features",
           "train_image_fingerprints"]


@dataclasses.dataclass(frozen=True)
class TrainingInfo:
    """What :func:`train_model` did: parameters, sizes, provenance, time."""

    params: dict
    manifest_sha256: str
    seconds: float

    def to_dict(self) -> dict:
        return {"params": self.params, "manifest_sha256": self.manifest_sha256,
                "seconds": self.seconds}


def _check_rank(family, options: dict, K: int) -> None:
    """A low-rank covariance (``rank`` R in ``1..K-1``) needs K >= 2: on a
    database too small for that (one or two training images per position give
    K = 1) say what to train instead, before any sample is drawn."""
    if "rank" not in family.fit_options:
        return
    rank = options.get("rank")
    name = family.name or family.kind
    if K < 2:
        raise ValueError(f"likelihood {name} needs K >= 2 components for its rank (1..K-1), and K = 1 is all this "
                         f"database's training images hold: train with --recipe thesis or --likelihood "
                         f"{'view-mixture' if family.view_components else 'gaussian-full'}, or add training images")
    if rank is not None and not 1 <= int(rank) < K:
        raise ValueError(f"likelihood {name}: rank must be in 1..K-1 = 1..{K - 1}, got {rank}: give --rank "
                         f"1..{K - 1} or more --components")


def train_model(
    database: ImageDatabase | str | os.PathLike,
    *,
    kind: str = "DB1",
    n_components: int | float = 20,
    samples_per_image: int = 100,
    covariance: str = "diag",
    likelihood: str | None = None,
    likelihood_options: dict | None = None,
    seed: int = 0,
    progress: Callable[[int, int], None] | None = None,
    augment: AugmentParams | None = None,
    var_floor: float = 1e-6,
    batch_size: int = 256,
    view_jitter: bool = False,
    interpolate: int = 0,
    interpolation: str = "linear",
    components_at_most: bool = False,
    return_info: bool = False,
) -> SensorModel | tuple[SensorModel, TrainingInfo]:
    """Train the sensor model of a database (thesis ch. 4, §7.1).

    Args:
        database: an :class:`ImageDatabase` or a folder to load.
        kind: ``"DB1"`` (noise + shifts, one level) or ``"DB2"`` (adds occlusion
            levels 5..25 %).
        n_components: K (``int``) or the energy fraction to capture (``float``
            in (0, 1]); one K for all positions, see
            :func:`~jaxrecog.eigenspace.choose_n_components`.
        samples_per_image: augmented samples per training image and level.
        covariance: the likelihood kind when ``likelihood`` is not given
            (its older name: ``"diag"``, the default, or ``"full"``).
        likelihood: a registered likelihood kind or name
            (:data:`jaxrecog.kernels.LIKELIHOODS`, e.g. ``"gaussian-diag"``,
            ``"student-t"``, ``"gaussian-lowrank"``) that can be fitted from
            sample moments; overrides ``covariance``.
        likelihood_options: the family's fit options (its ``fit_options``,
            e.g. ``{"rank": 4}``, ``{"nu": "auto"}``).  A family that asks for
            held-out samples (``holdout_fraction``) gets every
            ``round(1 / fraction)``-th sample of each (class, level) held out
            of its moments.
        seed: everything random derives from it.
        progress: called as ``progress(done, total)`` after each position.
        augment: augmentation settings (``samples_per_image`` overrides its field),
            including the capture transforms (``max_rotation``, ``max_scale``,
            ``blur_sigma``, ``gain_amplitude``, ``gain_cells``; off by default),
            all recorded in the info's ``params["augment"]``.
        var_floor: variance floor relative to the mean training-image variance
            per component, ``floor_v = var_floor * sum(λ_v) / (K * C)``.
        batch_size: samples projected per matmul.
        view_jitter: also use the database's ``jitter`` rows: images taken
            near a training view (off the training grid), each labelled with
            the (camera, position, object, pose) of that view.  Each is an
            extra *base image* of its view's class: it gets its own
            ``samples_per_image`` augmented samples per level, drawn exactly
            as the training image's (same augmentation, and with
            ``shared_draws`` the same draws ``j``), which are *added* to the
            training image's: a view with ``J`` jitter images contributes
            ``(1 + J) * samples_per_image`` samples per level to its
            class's moments, and the training image's own samples are those
            of a run without jitter.  The eigenspace stays that of the
            training images.  The info records ``params["view_jitter"]``
            (mode ``"added"``, or ``"components"`` for a family with one
            component per rendered view; the jitter images used and the views that
            have any).  A database without ``jitter`` rows is a
            ``ValueError``.
        interpolate: ``n > 0`` adds ``2 n`` components per view to a
            ``view_components`` family: the training image blended with each
            neighbouring position's training image of the same class
            (:func:`~jaxrecog.view_interpolation.interpolated_views`), ``n``
            points per side out to halfway: the appearance manifold between
            training views (Murase & Nayar's parametric eigenspace).  Needs
            no new images; combines with ``view_jitter``.  The info records
            ``params["interpolate"]`` (``n``, the interpolation and the
            neighbours found).
        interpolation: ``"linear"`` (cross-fade) or ``"flow"`` (optical-flow
            morph), :mod:`jaxrecog.view_interpolation`.
        components_at_most: an ``int`` ``n_components`` is an upper bound:
            K is ``min(n_components, smallest eigenspace rank)`` instead of a
            :class:`~jaxrecog.eigenspace.ComponentsError` when the database
            has too few training images per position (the info's
            ``params["K"]`` says the K used).
        return_info: also return a :class:`TrainingInfo`.

    Returns:
        The :class:`SensorModel` (float32 arrays), and the info if asked.
    """
    t0 = time.perf_counter()
    lik_kind = covariance if likelihood is None else likelihood
    try:
        family = likelihood_class(lik_kind)
    except ValueError as e:
        raise ValueError(f"likelihood / covariance: {e}") from None
    if family.fit.__func__ is Likelihood.fit.__func__:
        raise ValueError(f"likelihood {lik_kind!r} cannot be trained from sample moments (no fit)")
    options = dict(likelihood_options or {})
    unknown = sorted(set(options) - set(family.fit_options))
    if unknown:
        takes = ", ".join(family.fit_options) or "none"
        raise ValueError(f"likelihood {lik_kind!r} has no option {', '.join(map(repr, unknown))} (it takes: {takes})")
    options = family.with_defaults(**options)   # what the model file records
    holdout = float(family.holdout_fraction(**options))
    levels = levels_for(kind)
    params = dataclasses.replace(augment or AugmentParams(), samples_per_image=samples_per_image)
    db = database if isinstance(database, ImageDatabase) else load_database(database)
    H, W = db.image_shape
    C = db.n_classes
    n_interp = int(interpolate)
    if n_interp < 0:
        raise ValueError(f"interpolate must be >= 0, got {interpolate}")
    if interpolation not in INTERPOLATIONS:
        raise ValueError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}, got {interpolation!r}")
    if n_interp and not family.view_components:
        raise ValueError(f"interpolate: the interpolated views are mixture components; likelihood "
                         f"{family.name or family.kind!r} has none (use view-mixture or view-mixture-lowrank)")
    if family.view_components and not (view_jitter or n_interp):
        raise ValueError(f"likelihood {family.name or family.kind!r} takes one component per rendered view: "
                         f"train with view jitter (view_jitter=True, `jaxrecog train --view-jitter`) on a "
                         f"database with 'jitter' rows, or with interpolated views (interpolate=N)")
    jitter = real_jitter = _jitter_images(db) if view_jitter else None
    neighbours = None
    if n_interp:
        neighbours = [view_neighbours(db.train_images(i)) for i in range(db.n_cameras)]
        jitter = _merge_views(jitter, {(i, v): x for i in range(db.n_cameras) for v, x in
                                       enumerate(interpolated_views(db.train_images(i), neighbours[i], n_interp,
                                                                    interpolation))})
    if family.view_components:
        missing = [(i, v) for i in range(db.n_cameras) for v in range(db.positions[i]) if (i, v) not in jitter]
        if missing:
            raise ValueError(f"likelihood {family.name or family.kind!r}: (camera, position) {missing[0]} and "
                             f"{len(missing) - 1} more have no jitter images; every view needs them")

    # eigenspaces of every position (clean images), then one K for all
    train = [db.train_images(i) for i in range(db.n_cameras)]        # [V, C, H, W] each
    spaces = [[position_eigenspace(t[v]) for v in range(t.shape[0])] for t in train]
    K = choose_n_components([s.eigenvalues for cam in spaces for s in cam], n_components, at_most=components_at_most)
    _check_rank(family, options, K)
    bank = occluder_bank(levels, (H, W), params, seed)

    total = sum(len(s) for s in spaces)
    done = 0
    cameras = []
    for i, cam_spaces in enumerate(spaces):
        eigen, liks = [], []
        for v, space in enumerate(cam_spaces):
            mean, basis, lam = space.truncate(K)
            images, labels = train[i][v], None
            if jitter is not None and (i, v) in jitter:
                extra, extra_cls = jitter[i, v]
                images = np.concatenate([images, extra])
                labels = np.concatenate([np.arange(C), extra_cls])
            liks.append(fit_position(
                images, mean, basis, lam, levels, params, bank, seed, i, v, labels=labels, n_classes=C,
                family=family, var_floor=var_floor, batch_size=batch_size, options=options, holdout=holdout,
            ))
            eigen.append((mean, basis, lam))
            done += 1
            if progress is not None:
                progress(done, total)
        cameras.append(CameraModel(*(stack_arrays(*x) for x in zip(*eigen)), likelihood=stack_positions(liks)))
    model = SensorModel(
        cameras=tuple(cameras),
        n_objects=db.n_objects,
        n_poses=db.n_poses,
        levels=tuple(float(x) for x in levels),
        image_shape=(H, W),
    )
    if not return_info:
        return model
    info = TrainingInfo(
        params={
            "kind": kind,
            "n_components": n_components,
            "K": K,
            "samples_per_image": samples_per_image,
            "covariance": family.kind,
            "likelihood": family.kind,
            "likelihood_options": options,
            "seed": seed,
            "var_floor": var_floor,
            "augment": {k: (list(x) if isinstance(x, tuple) else x)
                        for k, x in dataclasses.asdict(params).items()},
            "positions": list(db.positions),
            "n_objects": db.n_objects,
            "n_poses": db.n_poses,
            "image_shape": [H, W],
            "train_image_sha256": train_image_fingerprints(db),
            **({} if neighbours is None else {"interpolate": {
                "points_per_side": n_interp,
                "interpolation": interpolation,
                "neighbours": [[list(map(int, nb)) for nb in cam] for cam in neighbours],
            }}),
            **({} if not view_jitter else {"view_jitter": {
                "mode": "components" if family.view_components else "added",
                "images": int(sum(len(x[1]) for x in real_jitter.values())),
                "views": int(sum(len(np.unique(x[1])) for x in real_jitter.values())),
                "positions": len(real_jitter),
            }}),
        },
        manifest_sha256=db.manifest_sha256,
        seconds=time.perf_counter() - t0,
    )
    return model, info


#: hex digits kept of each training image's sha256 (:func:`train_image_fingerprints`)
_FINGERPRINT_HEX = 16


def train_image_fingerprints(db: ImageDatabase) -> list[list[str]]:
    """Per object of ``db``, the sha256 (first 16 hex digits) of each of its
    ``train`` images, in manifest order: what the model file records
    (``training["train_image_sha256"]``) so that :func:`add_objects` can tell
    an object the model already has (identical training images)."""
    rows = db.rows("train")
    out: list[list[str]] = [[] for _ in range(db.n_objects)]
    for r in rows:
        out[int(db.object[r])].append(hashlib.sha256(np.ascontiguousarray(db.images[r]).tobytes())
                                      .hexdigest()[:_FINGERPRINT_HEX])
    return out


class AddObjectsError(ValueError):
    """A database whose objects cannot be added to a model (one line naming why)."""


def add_objects(
    model: SensorModel,
    database: ImageDatabase | str | os.PathLike,
    training: dict,
    *,
    progress: Callable[[int, int], None] | None = None,
    batch_size: int = 256,
    return_info: bool = False,
) -> SensorModel | tuple[SensorModel, TrainingInfo]:
    """Add the objects of ``database`` to a trained ``model`` without
    retraining its classes (``jaxrecog train --add NEW_DB --to MODEL``).

    The model's eigenspaces stay as they are: the new objects' augmented
    images are projected into each position's existing eigenspace (its
    basis was built from the old objects' training images only), and only the
    new classes' likelihood components are fitted, exactly as
    :func:`train_model` fits a class (same augmentation, samples, seed,
    likelihood family and options, variance floor, view jitter, and
    interpolated views toward the neighbouring positions the model recorded),
    all read from ``training`` (the model file's ``training`` metadata).
    The old classes' arrays are copied bit for bit; a family's parameters
    shared by all classes (the Student-t's ``nu``) stay the model's.  A
    calibrated model's variance factors are applied to the new classes too, so
    the result is calibrated as the model was; recalibrating on the new
    objects' ``calib`` views is the caller's choice
    (:func:`~jaxrecog.calibration.calibrate_model`, as ``train --add`` does).

    Object ``m`` of ``database`` becomes object ``M_old + m`` of the result
    (classes ``(M_old + m) * n_poses + pose``).

    Raises:
        AddObjectsError: one line: another number of cameras, other positions,
            poses or image size than the model; an object whose training image
            is identical to one of the model's (the model file records the
            sha256 of every training image, ``train_image_fingerprints``;
            a model written before that records none and is not checked); a
            model whose metadata lacks the training parameters; a view-jitter
            model and a database without ``jitter`` rows (or with another
            number of them per view).
    """
    t0 = time.perf_counter()
    db = database if isinstance(database, ImageDatabase) else load_database(database)
    where = f"database {db._where()}"
    train = training.get("params") if isinstance(training.get("params"), dict) else training
    need = ("kind", "K", "samples_per_image", "seed", "var_floor", "augment", "likelihood")
    lacking = [k for k in need if k not in train]
    if lacking:
        raise AddObjectsError(f"the model's metadata records no training parameter {lacking[0]!r}: objects cannot be "
                              f"added to it the way it was trained (retrain it with jaxrecog train)")
    if db.n_cameras != model.n_cameras:
        raise AddObjectsError(f"{where} has {db.n_cameras} camera(s), the model {model.n_cameras}: "
                              f"new objects need the model's cameras")
    try:
        check_counts(model, db, other_name=where, only=("positions", "poses", "image"))
    except CountsMismatchError as e:
        raise AddObjectsError(f"{e} (new objects need the model's cameras, positions, poses and image size)") from None
    known = {h: m for m, hs in enumerate(train.get("train_image_sha256") or ()) for h in hs}
    if known:
        for r in db.rows("train"):
            h = hashlib.sha256(np.ascontiguousarray(db.images[r]).tobytes()).hexdigest()[:_FINGERPRINT_HEX]
            if h in known:
                raise AddObjectsError(
                    f"object {db.object[r]} of {where} is already in the model: its train image {db.paths[r]} "
                    f"(camera {db.camera[r]} position {db.position[r]} pose {db.pose[r]}) is identical to a "
                    f"training image of the model's object {known[h]}")

    family = type(model.cameras[0].likelihood)
    options = family.with_defaults(**dict(train.get("likelihood_options") or {}))
    holdout = float(family.holdout_fraction(**options))
    kind, K, seed = str(train["kind"]), int(train["K"]), int(train["seed"])
    levels = levels_for(kind)
    if tuple(float(x) for x in levels) != tuple(model.levels) or K != model.n_components:
        raise AddObjectsError(f"the model's metadata (kind {kind}, K {K}) does not match its arrays "
                              f"(levels {model.levels}, K {model.n_components})")
    aug = {k: tuple(x) if isinstance(x, list) else x for k, x in dict(train["augment"]).items()}
    params = dataclasses.replace(AugmentParams(**aug), samples_per_image=int(train["samples_per_image"]))
    H, W = db.image_shape
    C_old, C = model.n_classes, db.n_classes
    ip = train.get("interpolate") or {}
    n_interp = int(ip.get("points_per_side", 0))
    try:
        jitter = _jitter_images(db) if train.get("view_jitter") else None
    except ValueError as e:
        raise AddObjectsError(f"{where}: the model was trained with view jitter; {e}") from None
    new_train = [db.train_images(i) for i in range(db.n_cameras)]        # [V, C, H, W] each
    if n_interp:
        neighbours = [[tuple(int(x) for x in pair) for pair in cam] for cam in ip["neighbours"]]
        jitter = _merge_views(jitter, {(i, v): x for i in range(db.n_cameras) for v, x in enumerate(
            interpolated_views(new_train[i], neighbours[i], n_interp, str(ip.get("interpolation", "linear"))))})
    if family.view_components:
        missing = [(i, v) for i in range(db.n_cameras) for v in range(db.positions[i]) if (i, v) not in jitter]
        if missing:
            raise AddObjectsError(f"{where}: (camera, position) {missing[0]} and {len(missing) - 1} more have no "
                                  f"jitter images; the model's mixture needs them at every view")
    bank = occluder_bank(levels, (H, W), params, seed)
    # the floor of train_model, var_floor * sum(λ) / (K * C), with the model's own C
    var_floor = float(train["var_floor"]) * C / C_old
    total, done = sum(model.positions), 0
    cameras = []
    for i, cam in enumerate(model.cameras):
        liks = []
        eigen = [np.asarray(x, np.float64) for x in (cam.mean_image, cam.basis, cam.eigenvalues)]
        for v in range(cam.n_positions):
            mean, basis, lam = (x[v] for x in eigen)
            images, labels = new_train[i][v], None
            if jitter is not None and (i, v) in jitter:
                extra, extra_cls = jitter[i, v]
                images = np.concatenate([images, extra])
                labels = np.concatenate([np.arange(C), extra_cls])
            try:
                liks.append(fit_position(
                    images, mean, basis, lam, levels, params, bank, seed, i, v, labels=labels, n_classes=C,
                    family=family, var_floor=var_floor, batch_size=batch_size, options=options, holdout=holdout))
            except ValueError as e:
                raise AddObjectsError(f"{where}: {e}") from None
            done += 1
            if progress is not None:
                progress(done, total)
        new = stack_positions(liks)
        if cam.calibration is not None:   # the new classes on the old ones' footing
            new = jax.vmap(lambda lik, s: lik.scaled(s))(new, jnp.asarray(cam.calibration, new.dtype))
        cameras.append(dataclasses.replace(cam, likelihood=_append_classes(cam.likelihood, new, where)))
    out = SensorModel(cameras=tuple(cameras), n_objects=model.n_objects + db.n_objects, n_poses=model.n_poses,
                      levels=model.levels, image_shape=model.image_shape, stability=model.stability)
    if not return_info:
        return out
    seconds = time.perf_counter() - t0
    fingerprints = train.get("train_image_sha256")
    info = TrainingInfo(
        params={**train, "n_objects": out.n_objects,
                **({} if fingerprints is None else {"train_image_sha256": [*fingerprints,
                                                                           *train_image_fingerprints(db)]}),
                "added": [*train.get("added", []), {
                    "objects": [model.n_objects, out.n_objects - 1], "manifest_sha256": db.manifest_sha256,
                    "seconds": seconds}]},
        manifest_sha256=db.manifest_sha256,
        seconds=seconds,
    )
    return out, info


def added_calibration_features(model: SensorModel, database: ImageDatabase, split: str = "calib"):
    """The ``split`` views of the objects :func:`add_objects` added from
    ``database`` (the model's last ``database.n_objects`` objects), projected
    with ``model`` and labelled with their classes in the model:
    :class:`~jaxrecog.calibration.CalibrationFeatures` for
    :func:`~jaxrecog.calibration.calibrate_model`."""
    from .calibration import CalibrationFeatures, features_from_database

    first = model.n_objects - database.n_objects
    if first < 0:
        raise AddObjectsError(f"the model has {model.n_objects} objects, fewer than the database's {database.n_objects}")
    view = SensorModel(model.cameras, database.n_objects, model.n_poses, model.levels, model.image_shape)
    feats = features_from_database(view, database, split)
    return CalibrationFeatures(tuple(f._replace(cls=f.cls + first * model.n_poses) for f in feats.cameras))


def _append_classes(old: Likelihood, new: Likelihood, where: str) -> Likelihood:
    """``old`` with the classes of ``new`` after its own: every field with a
    class axis ``C`` concatenated along it (``old``'s values bit for bit), every
    field without one (shared by the classes) ``old``'s."""
    arrays = {}
    for f, spec in type(old).field_shapes.items():
        a = np.asarray(getattr(old, f))
        if "C" not in spec.split():
            arrays[f] = a
            continue
        b = np.asarray(getattr(new, f), a.dtype)
        ax = spec.split().index("C")
        if a.shape[:ax] + a.shape[ax + 1:] != b.shape[:ax] + b.shape[ax + 1:]:
            raise AddObjectsError(f"{where}: the new classes' {f} has shape {b.shape[:ax] + b.shape[ax + 1:]} "
                                  f"without the class axis, the model's {a.shape[:ax] + a.shape[ax + 1:]} (another "
                                  f"number of view-jitter images per view than the model was trained with?)")
        arrays[f] = np.concatenate([a, b], axis=ax)
    return type(old).from_arrays({f: jnp.asarray(x) for f, x in arrays.items()})


def _jitter_images(db: ImageDatabase) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """The ``jitter`` rows of ``db`` by (camera, position): their images
    ``uint8 [J, H, W]`` and the class of the training view each is labelled
    with ``int [J]``, in manifest order."""
    rows = np.flatnonzero(np.asarray(db.split) == "jitter")
    if rows.size == 0:
        raise ValueError("view_jitter: the database has no 'jitter' rows (images near a training view, "
                         "labelled with that view's camera, position, object and pose)")
    cls = db.class_index
    out: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    for i, v in sorted(set(zip(db.camera[rows].tolist(), db.position[rows].tolist()))):
        sel = rows[(db.camera[rows] == i) & (db.position[rows] == v)]
        out[i, v] = (db.images[sel], cls[sel].astype(np.int64))
    return out


def _merge_views(a, b):
    """Jitter images by (camera, position) from two sources, ``a`` (may be ``None``) first."""
    if a is None:
        return b
    return {key: tuple(np.concatenate([a[key][j], b[key][j]]) for j in range(2)) if key in a else b[key]
            for key in sorted(set(a) | set(b))}
