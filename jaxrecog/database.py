"""The image database: a folder of 8-bit gray PNGs plus ``manifest.csv``.

``manifest.csv`` has exactly the columns ``path,camera,position,object,pose,split``
(0-based integers; split ``train``, ``test`` or ``calib``), see
``docs/architecture.md``.  :func:`load_database` validates the whole folder and
reports *every* problem at once, each with its manifest row number (row 1 is the
first line after the header).  Any number of cameras, positions, objects and
poses is accepted; class ``c = object * n_poses + pose``.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import os
import warnings
from collections import Counter
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

__all__ = [
    "COLUMNS",
    "SPLITS",
    "DatabaseError",
    "NonGrayImageWarning",
    "ImageDatabase",
    "load_database",
    "write_database",
]

COLUMNS = ("path", "camera", "position", "object", "pose", "split")
SPLITS = ("train", "test", "calib")
_INT_COLUMNS = ("camera", "position", "object", "pose")


class DatabaseError(ValueError):
    """The image database is invalid; ``problems`` lists every problem found."""

    def __init__(self, where: str, problems: Sequence[str]):
        self.problems = list(problems)
        head = f"invalid image database {where}: {len(self.problems)} problem(s)"
        super().__init__("\n  ".join([head, *self.problems]))


class NonGrayImageWarning(UserWarning):
    """A colour (or gray+alpha) image was converted to 8-bit gray while loading."""


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
            raise DatabaseError(self._where(), probs)
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
                zip(_INT_COLUMNS, (camera, position, object, pose))}
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
        problems = _check_rows(
            [(i + 1, (p, *(int(cols[k][i]) for k in _INT_COLUMNS), str(split_arr[i])))
             for i, p in enumerate(paths)]
        )
        if problems:
            raise DatabaseError("<in memory>", problems)
        text = _manifest_text(paths, cols, split_arr)
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


def _manifest_text(paths, cols, split) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for i, p in enumerate(paths):
        w.writerow([p, *(int(cols[k][i]) for k in _INT_COLUMNS), split[i]])
    return buf.getvalue()


def _check_rows(rows: list[tuple[int, tuple]]) -> list[str]:
    """Value checks shared by the loader and :meth:`ImageDatabase.from_arrays`:
    negative indices, unknown split, duplicate paths, duplicate train entries.
    ``rows`` holds (row number, (path, camera, position, object, pose, split))."""
    problems: list[str] = []
    seen_path: dict[str, int] = {}
    seen_train: dict[tuple, int] = {}
    for r, (path, cam, pos, obj, pose, split) in rows:
        for name, val in zip(_INT_COLUMNS, (cam, pos, obj, pose)):
            if val < 0:
                problems.append(f"row {r}: {name} = {val} is negative")
        if split not in SPLITS:
            problems.append(f"row {r}: split '{split}' is not one of {', '.join(SPLITS)}")
        if path in seen_path:
            problems.append(f"row {r}: duplicate of row {seen_path[path]} (same path '{path}')")
        else:
            seen_path[path] = r
        key = (cam, pos, obj, pose)
        if split == "train":
            if key in seen_train:
                problems.append(
                    f"row {r}: duplicate train entry camera {cam} position {pos} object {obj} "
                    f"pose {pose} (first at row {seen_train[key]})"
                )
            else:
                seen_train[key] = r
    return problems


def _read_gray(file: Path) -> tuple[np.ndarray | None, str | None, bool]:
    """Read one image as uint8 gray: (image, problem, converted_from_colour)."""
    img = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None, f"cannot read image '{file.name}' (not an image file?)", False
    if img.dtype != np.uint8:
        return None, f"image '{file.name}' is {img.dtype}, expected 8-bit", False
    if img.ndim == 2:
        return img, None, False
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), None, True
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY), None, True
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0], None, False
    return None, f"image '{file.name}' has unsupported shape {img.shape}", False


def load_database(folder: str | os.PathLike) -> ImageDatabase:
    """Load and validate an image database folder.

    Checks: ``manifest.csv`` exists; its header has exactly :data:`COLUMNS`
    (unknown and missing columns are reported); every row has integer,
    non-negative indices and a known split; no path appears twice and no
    (camera, position, object, pose) has two ``train`` images; every file
    exists and is an 8-bit image; all images have the same size (the most
    common size is taken as the reference).  Colour images are converted to
    gray with a :class:`NonGrayImageWarning`.

    Raises:
        DatabaseError: listing every problem, each with its row number.
    """
    root = Path(folder)
    manifest = root / "manifest.csv"
    if not manifest.is_file():
        raise DatabaseError(str(root), [f"no manifest.csv in '{root}'"])
    raw = manifest.read_bytes()
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise DatabaseError(str(root), [f"manifest.csv is not UTF-8 text ({e.reason})"]) from None
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None:
        raise DatabaseError(str(root), ["manifest.csv is empty (no header)"])
    header = [h.strip() for h in header]
    problems: list[str] = []
    for h in header:
        if h not in COLUMNS:
            problems.append(f"header: unknown column '{h}'")
    for h, k in Counter(header).items():
        if k > 1:
            problems.append(f"header: column '{h}' appears {k} times")
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        problems.append(f"header: missing column(s) {', '.join(missing)}")
        raise DatabaseError(str(root), problems)
    col = {h: header.index(h) for h in COLUMNS}

    parsed: list[tuple | None] = []
    for r, fields in enumerate(reader, start=1):
        if not fields or all(not f.strip() for f in fields):
            parsed.append(None)
            continue
        if len(fields) != len(header):
            problems.append(f"row {r}: {len(fields)} fields, header has {len(header)}")
            parsed.append(None)
            continue
        bad = False
        vals = []
        for name in _INT_COLUMNS:
            s = fields[col[name]].strip()
            try:
                vals.append(int(s))
            except ValueError:
                problems.append(f"row {r}: {name} '{s}' is not an integer")
                bad = True
        path = fields[col["path"]].strip()
        split = fields[col["split"]].strip()
        if not path:
            problems.append(f"row {r}: empty path")
            bad = True
        elif os.path.isabs(path) or ".." in Path(path).parts:
            problems.append(f"row {r}: path '{path}' must be relative and inside the folder")
            bad = True
        parsed.append(None if bad else (path, *vals, split))

    numbered = [(r, p) for r, p in enumerate(parsed, start=1) if p is not None]
    if not parsed:
        problems.append("manifest.csv has no rows")
    problems += _check_rows(numbered)

    images: list[np.ndarray | None] = []
    colour_rows: list[int] = []
    for r, p in numbered:
        img, problem, converted = _read_gray(root / p[0]) if (root / p[0]).is_file() else (
            None, f"missing file '{p[0]}'", False)
        if problem:
            problems.append(f"row {r}: {problem}")
        if converted:
            colour_rows.append(r)
        images.append(img)

    shapes = Counter(im.shape for im in images if im is not None)
    if shapes:
        ref = shapes.most_common(1)[0][0]
        for (r, p), im in zip(numbered, images):
            if im is not None and im.shape != ref:
                problems.append(
                    f"row {r}: image '{p[0]}' is {im.shape[0]}x{im.shape[1]}, "
                    f"the others are {ref[0]}x{ref[1]}"
                )
    problems.sort(key=_row_key)
    if problems:
        raise DatabaseError(str(root), problems)
    if colour_rows:
        shown = ", ".join(str(r) for r in colour_rows[:10]) + (" ..." if len(colour_rows) > 10 else "")
        warnings.warn(
            f"{root}: {len(colour_rows)} colour image(s) converted to gray (rows {shown})",
            NonGrayImageWarning,
            stacklevel=2,
        )
    rows = [p for _, p in numbered]
    return ImageDatabase(
        images=np.stack(images).astype(np.uint8, copy=False),
        camera=np.array([p[1] for p in rows], dtype=np.int64),
        position=np.array([p[2] for p in rows], dtype=np.int64),
        object=np.array([p[3] for p in rows], dtype=np.int64),
        pose=np.array([p[4] for p in rows], dtype=np.int64),
        split=np.array([p[5] for p in rows], dtype=str),
        paths=tuple(p[0] for p in rows),
        root=root,
        manifest_sha256=hashlib.sha256(raw).hexdigest(),
    )


def _row_key(msg: str) -> tuple[int, str]:
    if msg.startswith("row "):
        try:
            return (int(msg.split(":")[0].split()[1]), msg)
        except ValueError:
            pass
    return (0, msg)


def write_database(folder: str | os.PathLike, db: ImageDatabase) -> Path:
    """Write ``db`` as PNG files plus ``manifest.csv`` under ``folder``."""
    root = Path(folder)
    for path, img in zip(db.paths, db.images):
        f = root / path
        f.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(f), img):
            raise OSError(f"could not write image '{f}'")
    cols = {"camera": db.camera, "position": db.position, "object": db.object, "pose": db.pose}
    (root / "manifest.csv").write_text(_manifest_text(db.paths, cols, db.split))
    return root
