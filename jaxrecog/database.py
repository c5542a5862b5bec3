"""The image database: a folder of 8-bit gray PNGs plus ``manifest.csv``.

The format (columns, rules, reading and writing) is defined once, in
:mod:`jaxrecog.hardware.dbformat`; this module holds the in-memory
:class:`ImageDatabase` users work with.  :func:`load_database` validates the
whole folder and reports *every* problem at once, each with its manifest row
number (row 1 is the first line after the header); a long list is also
written to ``manifest-errors.txt`` next to the manifest.  Any number of
cameras, positions, objects and poses is accepted; class
``c = object * n_poses + pose``.  One image file may serve several rows
(turntable views: :func:`notes` counts them).
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from pathlib import Path
from typing import Sequence

import numpy as np

from .hardware.dbformat import (
    COLUMNS,
    INT_COLUMNS,
    SPLITS,
    DatabaseError,
    ManifestRow,
    NonGrayImageWarning,
    check_rows,
    database_error,
    manifest_text,
    read_folder,
    shared_files,
    write_image,
)

__all__ = [
    "COLUMNS",
    "SPLITS",
    "DatabaseError",
    "NonGrayImageWarning",
    "ImageDatabase",
    "load_database",
    "notes",
    "write_database",
]


@dataclasses.dataclass(frozen=True, eq=False)
class ImageDatabase:
    """A validated image database held in memory.

    Attributes:
        images: ``uint8 [N, H, W]``, row ``n`` of the manifest.
        camera, position, object, pose: ``int64 [N]``.
        split: ``str [N]``, one of :data:`SPLITS`.
        paths: image paths relative to ``root``.
        root: the folder (``None`` for an in-memory database).
        manifest_sha256: hex digest of the manifest text (for model provenance).
    """

    images: np.ndarray
    camera: np.ndarray
    position: np.ndarray
    object: np.ndarray
    pose: np.ndarray
    split: np.ndarray
    paths: tuple[str, ...]
    root: Path | None
    manifest_sha256: str

    # ---- sizes -------------------------------------------------------------
    @property
    def n_rows(self) -> int:
        return int(self.images.shape[0])

    @property
    def image_shape(self) -> tuple[int, int]:
        return (int(self.images.shape[1]), int(self.images.shape[2]))

    @property
    def n_cameras(self) -> int:
        return int(self.camera.max()) + 1

    @property
    def positions(self) -> tuple[int, ...]:
        """Number of positions of each camera (largest index + 1)."""
        return tuple(
            int(self.position[self.camera == i].max()) + 1 if np.any(self.camera == i) else 0
            for i in range(self.n_cameras)
        )

    @property
    def n_objects(self) -> int:
        return int(self.object.max()) + 1

    @property
    def n_poses(self) -> int:
        return int(self.pose.max()) + 1

    @property
    def n_classes(self) -> int:
        return self.n_objects * self.n_poses

    @property
    def class_index(self) -> np.ndarray:
        """``c = object * n_poses + pose`` per row, ``int64 [N]``."""
        return self.object * self.n_poses + self.pose

    def rows(self, split: str) -> np.ndarray:
        """Row indices of one split."""
        return np.flatnonzero(self.split == split)

    def train_images(self, camera: int) -> np.ndarray:
        """The training images of one camera as ``uint8 [V, C, H, W]``.

        Every (position, class) of the camera must have exactly one ``train``
        image; otherwise a :class:`DatabaseError` lists the missing ones.
        """
        if not 0 <= camera < self.n_cameras:
            raise ValueError(f"camera {camera} not in database (cameras 0..{self.n_cameras - 1})")
        n_pos, n_cls = self.positions[camera], self.n_classes
        sel = np.flatnonzero((self.split == "train") & (self.camera == camera))
        slots = np.full((n_pos, n_cls), -1, dtype=np.int64)
        slots[self.position[sel], self.class_index[sel]] = sel
        missing = np.argwhere(slots < 0)
        if missing.size:
            probs = [
                f"camera {camera} position {v}: no train image of object {c // self.n_poses} "
                f"pose {c % self.n_poses}"
                for v, c in missing
            ]
            raise database_error(self._where(), probs, folder=self.root)
        return self.images[slots]

    def _where(self) -> str:
        return str(self.root) if self.root is not None else "<in memory>"

    # ---- construction ------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        images: np.ndarray,
        camera: Sequence[int],
        position: Sequence[int],
        object: Sequence[int],
        pose: Sequence[int],
        split: Sequence[str],
        paths: Sequence[str] | None = None,
        root: Path | None = None,
    ) -> "ImageDatabase":
        """An in-memory database (e.g. generated); checks the same invariants as
        :func:`load_database` except file access."""
        images = np.asarray(images)
        if images.dtype != np.uint8 or images.ndim != 3:
            raise ValueError(f"images must be uint8 [N, H, W], got {images.dtype} {images.shape}")
        n = images.shape[0]
        cols = {k: np.asarray(v, dtype=np.int64) for k, v in
                zip(INT_COLUMNS, (camera, position, object, pose))}
        split_arr = np.asarray(split, dtype=np.str_)
        if paths is None:
            paths = [
                f"cam{c}/pos{v:03d}/obj{m}_pose{p}_{s}_{i}.png"
                for i, (c, v, m, p, s) in enumerate(zip(*cols.values(), split_arr))
            ]
        if any(len(a) != n for a in (*cols.values(), split_arr, paths)):
            raise ValueError("images, index columns, split and paths must have the same length")
        if n == 0:
            raise ValueError("an image database needs at least one row")
        rows = [ManifestRow(p, *(int(cols[k][i]) for k in INT_COLUMNS), str(split_arr[i]))
                for i, p in enumerate(paths)]
        problems = check_rows(list(enumerate(rows, start=1)))
        if problems:
            raise DatabaseError("<in memory>", problems)
        text = manifest_text(rows)
        return cls(
            images=images,
            camera=cols["camera"],
            position=cols["position"],
            object=cols["object"],
            pose=cols["pose"],
            split=split_arr,
            paths=tuple(paths),
            root=root,
            manifest_sha256=hashlib.sha256(text.encode()).hexdigest(),
        )


def load_database(folder: str | os.PathLike) -> ImageDatabase:
    """Load and validate an image database folder
    (:func:`jaxrecog.hardware.dbformat.read_folder`: header, indices, splits,
    exact duplicate rows, two ``train`` images of one view, missing or
    unreadable files, image sizes; colour images become gray with a
    :class:`NonGrayImageWarning`).

    Raises:
        DatabaseError: listing every problem, each with its row number.
    """
    root = Path(folder)
    return ImageDatabase(**read_folder(root)._asdict(), root=root)


def notes(db: ImageDatabase) -> list[str]:
    """Lines worth telling a user about a valid database (``jaxrecog inspect``):
    image files shared by several rows (turntable views)."""
    n = shared_files(db.paths)
    if not n:
        return []
    return [f"  {n} image file(s) are used by more than one row (turntable views: one photo "
            f"serves several (pose, position) rows)"]


def write_database(folder: str | os.PathLike, db: ImageDatabase) -> Path:
    """Write ``db`` as PNG files plus ``manifest.csv`` under ``folder``."""
    root = Path(folder)
    for path, img in zip(db.paths, db.images):
        f = root / path
        f.parent.mkdir(parents=True, exist_ok=True)
        write_image(f, img)
    rows = zip(db.paths, db.camera, db.position, db.object, db.pose, db.split)
    (root / "manifest.csv").write_text(manifest_text(list(rows)))
    return root
