"""Render the training image database of the synthetic rig (thesis ch. 7).

The thesis took 32 images per camera position (8 objects x 4 poses) at 32
positions of camera 1 and 7 of camera 2: 1248 images.  :func:`render_database`
writes them as the folder + ``manifest.csv`` format of ``docs/architecture.md``
(columns ``path,camera,position,object,pose,split``), clean renders as the
``train`` split and, optionally, perturbed renders (noise, pixel offsets,
cardboard occluders) as the ``test`` split and held-out views near the
training views (object yaw, camera offset, lighting, noise:
:class:`~.synthetic.Perturb`) as the ``calib`` split, for calibrating the
sensor model's confidence (:mod:`jaxrecog.calibration`).
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ...dbformat import COLUMNS, write_image, write_manifest
from .occluders import random_occluders
from ..geometry.positions import CameraTable
from .scene import ObjectSpec
from .synthetic import Noise, Perturb, SyntheticRig

__all__ = ["MANIFEST_COLUMNS", "render_database", "alternating_offsets", "image_sink", "contact_sheet", "jitter_offsets", "lookalike_distances"]

MANIFEST_COLUMNS = COLUMNS  # the format lives in jaxrecog.dbformat


def render_database(
    out_dir: str | os.PathLike,
    table: CameraTable | None = None,
    objects: Sequence[ObjectSpec] | None = None,
    poses: int = 4,
    *,
    rig: SyntheticRig | None = None,
    test_per_view: int = 0,
    test_noise: Noise = Noise(brightness=0.05, pixel=2.0, max_shift=2),
    test_occluders: bool = False,
    seed: int = 0,
    progress: Callable[[int], object] | None = None,
    calib_per_view: int = 0,
    calib_perturb: Perturb = Perturb(),
    calib_occluders: bool | Callable[[np.random.Generator, int, int], object] = False,
    train: bool = True,
    jitter_per_view: int = 0,
    jitter_yaw_deg: float = 10.0,
    blocks=None,
) -> Path | None:
    """Render every (camera, position, object, pose) and write the database.

    Args:
        out_dir: folder to write (created; existing files of the same names are replaced).
        table, objects, poses: scene of a new :class:`SyntheticRig` (ignored when ``rig`` is given).
        rig: render with this rig instead (its table, objects and poses).
        test_per_view: perturbed ``test`` images per (camera, position, object, pose); 0 = none.
        test_noise: perturbations of the test images.
        test_occluders: give each (object, pose) of the test split a random
            cardboard layout (:func:`~.occluders.random_occluders`).
        seed: seeds the test perturbations and layouts.
        progress: called with the number of images just written (e.g. ``tqdm.update``).
        calib_per_view: held-out ``calib`` images per (camera, position, object, pose); 0 = none.
        calib_perturb: their perturbations (seeded by ``seed``, independent of the test split's).
        calib_occluders: ``True``: give each (object, pose) of the calib split a
            random layout; a callable ``(rng, camera, position) -> layout | None``:
            a layout per calib image (e.g. a board in front of that view).
        train: write the ``train`` split (``False``: e.g. a calib-only folder).
        jitter_per_view: clean renders *near* each training view, written as
            the ``jitter`` split and labelled with that view (for
            ``train_model(view_jitter=True)``): the object turned
            ``±jitter_yaw_deg * k / ceil(N / 2)`` degrees, k = 1 .. ceil(N / 2),
            alternating signs (N = 4, 10°: +5, -5, +10, -10).  These are the
            neighbouring views of a turn-table the training grid leaves out.
        jitter_yaw_deg: the largest of those turns (> 0).
        blocks: render only some (object, pose) blocks, elsewhere (a Ray
            task, :mod:`jaxrecog.ray_render`): at the start of each block,
            ``blocks.start(object, pose, rig, generators)`` says whether to
            render it (it may set the random generators' states first); every
            image goes to ``blocks.write(manifest_row, image)`` instead of a
            file, and no folder or manifest is written (returns ``None``).

    Returns:
        The path of ``manifest.csv``.  Train images: ``n_objects * poses`` per
        position, ``sum(positions)`` positions (1248 for the defaults).
    """
    if test_per_view < 0:
        raise ValueError(f"test_per_view must be >= 0, got {test_per_view}")
    if calib_per_view < 0:
        raise ValueError(f"calib_per_view must be >= 0, got {calib_per_view}")
    offsets = jitter_offsets(jitter_per_view, jitter_yaw_deg)
    own = rig is None
    if own:
        rig = SyntheticRig(table, objects=objects, n_poses=poses, seed=seed)
    out = Path(out_dir)
    rows: list[tuple] = []
    try:
        rng = np.random.default_rng(seed)
        calib_rng = np.random.default_rng([seed, 0xCA1])
        splits = [s for s, n in (("train", train), ("test", test_per_view), ("calib", calib_per_view),
                                 ("jitter", jitter_per_view)) if n]
        for i, n_pos in enumerate(rig.positions if blocks is None else ()):
            for v in range(n_pos):
                for s in splits:
                    (out / s / f"c{i}" / f"v{v:02d}").mkdir(parents=True, exist_ok=True)

        emit = image_sink(out, rows, blocks)

        def views(split, m, p, per_view, render, index=None):
            """Write ``per_view`` images ``render(camera, position, j)`` of
            every view of object ``m`` in pose ``p`` as ``split`` (file
            ``m{m}_p{p}_{j}.png``; ``index`` fixes j for one image per view)."""
            for i, n_pos in enumerate(rig.positions):
                for v in range(n_pos):
                    for j in range(per_view):
                        rel = f"{split}/c{i}/v{v:02d}/m{m}_p{p}_{j if index is None else index}.png"
                        emit(rel, render(i, v, j), i, v, m, p, split)
                if progress is not None:
                    progress(n_pos * per_view)

        for m in range(rig.n_objects):
            for p in range(rig.n_poses):
                if blocks is not None and not blocks.start(m, p, rig, (rng, calib_rng, rig._rng)):
                    continue
                rig.reset(m, p)
                for i, n_pos in enumerate(rig.positions if train else ()):
                    for v in range(n_pos):
                        img, _ = rig.render_clean(i, v)
                        emit(f"train/c{i}/v{v:02d}/m{m}_p{p}.png", img, i, v, m, p, "train")
                    if progress is not None:
                        progress(n_pos)
                if test_per_view:
                    layout = random_occluders(rng, rig.table, radius=rig.radius) if test_occluders else None
                    rig.reset(m, p, layout)
                    views("test", m, p, test_per_view, lambda i, v, j: rig.render_noisy(i, v, test_noise)[0])
                    rig.reset(m, p)
                if calib_per_view:
                    per_view = callable(calib_occluders)
                    layout = random_occluders(calib_rng, rig.table, radius=rig.radius) \
                        if calib_occluders is True else None
                    rig.reset(m, p, layout)

                    def calib(i, v, j):
                        if per_view:
                            rig.reset(m, p, calib_occluders(calib_rng, i, v))
                        return rig.render_perturbed(i, v, calib_perturb, calib_rng)[0]

                    views("calib", m, p, calib_per_view, calib)
                    rig.reset(m, p)
                for j, yaw in enumerate(offsets):
                    rig.reset(m, p, yaw_offset_deg=yaw)
                    views("jitter", m, p, 1, lambda i, v, _: rig.render_clean(i, v)[0], index=j)
                if offsets:
                    rig.reset(m, p)
    finally:
        if own:
            rig.close()
    return None if blocks is not None else write_manifest(out, rows)


def image_sink(out: Path, rows: list, blocks=None) -> Callable[..., None]:
    """``emit(rel_path, image, camera, position, object, pose, split)``: the
    image to ``out / rel_path`` (or to ``blocks.write(row, image)``: a Ray
    task's share, :mod:`jaxrecog.ray_render`) and its manifest row to ``rows``."""

    def emit(rel: str, img: np.ndarray, *row) -> None:
        if blocks is None:
            write_image(out / rel, img)
        else:
            blocks.write((rel, *row), img)
        rows.append((rel, *row))

    return emit


def jitter_offsets(n: int, max_deg: float) -> tuple[float, ...]:
    """The object turns (degrees) of the ``n`` jitter renders of a view:
    ``±max_deg * k / ceil(n / 2)``, k = 1 .. ceil(n / 2), alternating signs,
    the first ``n`` of them (:func:`render_database`)."""
    if isinstance(n, bool) or not isinstance(n, int) or n < 0:
        raise ValueError(f"jitter_per_view must be an integer >= 0, got {n!r}")
    if n and not (0 < max_deg < 180):
        raise ValueError(f"jitter_yaw_deg must be in (0, 180) degrees, got {max_deg!r}")
    return alternating_offsets(n, max_deg)


def alternating_offsets(n: int, max_deg: float) -> tuple[float, ...]:
    """``±max_deg * k / ceil(n / 2)``, k = 1 .. ceil(n / 2), alternating signs,
    the first ``n`` (no checks): the jitter views of the thesis rig
    (:func:`jitter_offsets`) and of the turn-table."""
    half = max(1, math.ceil(n / 2))
    return tuple((1 if j % 2 == 0 else -1) * max_deg * (j // 2 + 1) / half for j in range(n))


def contact_sheet(rig: SyntheticRig, views: Sequence[tuple[int, int]], gap: int = 2) -> np.ndarray:
    """Clean renders of every object (rows) in every pose, for each ``(camera,
    position)`` in ``views`` (column blocks), tiled into one ``uint8`` image."""
    H, W = rig.image_shape
    cols = len(views) * rig.n_poses
    sheet = np.full(((H + gap) * rig.n_objects - gap, (W + gap) * cols + gap * 3 * (len(views) - 1) - gap), 255, np.uint8)
    for m in range(rig.n_objects):
        for p in range(rig.n_poses):
            rig.reset(m, p)
            for b, (i, v) in enumerate(views):
                img, _ = rig.render_clean(i, v)
                c = b * rig.n_poses + p
                x0 = c * (W + gap) + b * 3 * gap
                y0 = m * (H + gap)
                sheet[y0 : y0 + H, x0 : x0 + W] = img
    return sheet


def lookalike_distances(rig: SyntheticRig, a: int, b: int) -> np.ndarray:
    """Distance between objects ``a`` and ``b`` per pose and position.

    ``d = || y_a / ||y_a|| - y_b / ||y_b|| ||`` on the clean images (the
    unit-energy scaling of eq. 4.1), so 0 means identical and sqrt(2) is the
    largest possible.

    Returns:
        ``float [n_poses, sum(positions)]``, positions of camera 0 first.
    """
    out = np.zeros((rig.n_poses, sum(rig.positions)))
    for p in range(rig.n_poses):
        imgs = []
        for m in (a, b):
            rig.reset(m, p)
            y = np.stack(
                [rig.render_clean(i, v)[0].ravel() for i, n in enumerate(rig.positions) for v in range(n)]
            ).astype(np.float64)
            imgs.append(y / np.linalg.norm(y, axis=1, keepdims=True))
        out[p] = np.linalg.norm(imgs[0] - imgs[1], axis=1)
    return out
