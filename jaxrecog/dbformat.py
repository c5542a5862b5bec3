"""The image-database format: a folder of 8-bit gray images plus ``manifest.csv``.

``manifest.csv`` has exactly the columns :data:`COLUMNS`
(``path,camera,position,object,pose,split``; 0-based integers; split one of
:data:`SPLITS`), see ``docs/architecture.md``.  This leaf module (NumPy,
OpenCV, imported when an image is read or written, and the standard library
only; of this package it imports only :mod:`.problems`, :mod:`._files` and :mod:`._imagesize`) is the one
definition of the format and of the in-memory :class:`ImageDatabase`: the
renderer (:mod:`jaxrecog.hardware.render.render_db`) writes it, :func:`read_folder` reads and validates it for the dataset rig and
for :func:`jaxrecog.load_database`, :func:`write_folder` writes an
:class:`ImageDatabase`.

Rules (:func:`check_rows`): indices are non-negative integers below
:data:`MAX_INDEX` that form dense ranges (cameras ``0..n-1``, each camera's
positions ``0..V-1``, objects ``0..M-1``, poses ``0..N-1``: a gap, e.g. one
mistyped position 999999, names its row and is found before any array is
sized by the counts); a row may not repeat another row exactly; one
(camera, position, object, pose) has at most one ``train`` image.  One image
file may serve several rows that differ in camera, position, object, pose or
split: on a turntable one photo is the view of (pose p, position v) and of
(pose p', position v').  Every problem is reported at once, each with its
manifest row number (row 1 is the first line after the header); the
message shows the first :data:`~jaxrecog.problems.SHOWN` and the count, the
exception's ``problems`` hold them all (``jaxrecog --debug`` prints them,
``--problems-out FILE`` writes them).  Reading never writes into the folder.
The manifest is checked first, in time and memory linear in its rows; image
pixels are kept only when it is clean.
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
from typing import NamedTuple, Sequence

import numpy as np

from ._files import check_output_folder, read_bytes, write_text
from ._imagesize import MAX_IMAGE_PIXELS, image_size
from .problems import SHOWN, one_line, problem_message

__all__ = [
    "COLUMNS",
    "SPLITS",
    "INT_COLUMNS",
    "MAX_INDEX",
    "DatabaseError",
    "NonGrayImageWarning",
    "ManifestRow",
    "ImageDatabase",
    "database_error",
    "check_rows",
    "manifest_text",
    "parse_manifest",
    "read_gray",
    "read_folder",
    "shared_files",
    "write_folder",
    "write_image",
    "write_manifest",
]

COLUMNS = ("path", "camera", "position", "object", "pose", "split")
SPLITS = ("train", "test", "calib", "jitter")  # jitter: extra views near a training view (train --view-jitter)
INT_COLUMNS = ("camera", "position", "object", "pose")
MAX_INDEX = 2**20  # indices must be below this (a typo like 1e9 is not a position)


class DatabaseError(ValueError):
    """The image database is invalid; ``problems`` lists every problem found
    (``full_list``: a file that holds them all, ``None``: none was written)."""

    def __init__(self, where: str, problems: Sequence[str], full_list: str | os.PathLike | None = None):
        self.problems = list(problems)
        self.full_list = full_list
        super().__init__(problem_message(f"invalid image database {where}", self.problems, full_list=full_list))


class NonGrayImageWarning(UserWarning):
    """A colour (or gray+alpha) image was converted to 8-bit gray while loading."""


class ManifestRow(NamedTuple):
    """One manifest line after parsing."""

    path: str
    camera: int
    position: int
    object: int
    pose: int
    split: str


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
        need = n_pos * n_cls
        have = np.unique(self.position[sel] * n_cls + self.class_index[sel]).size
        if have < need and need > _MAX_LISTED + sel.size:
            # sparse views (dense indices, few of their combinations): name the
            # first ones without sizing an array by the counts' product
            present = set((self.position[sel] * n_cls + self.class_index[sel]).tolist())
            first = []
            for k in range(need):
                if k not in present:
                    first.append(k)
                    if len(first) == _MAX_LISTED:
                        break
            probs = [f"camera {camera} position {k // n_cls}: no train image of object {k % n_cls // self.n_poses} "
                     f"pose {k % self.n_poses}" for k in first]
            probs.append(f"camera {camera}: {need - have - len(first)} more of its {n_pos} positions x {n_cls} "
                         f"classes have no train image")
            raise database_error(self._where(), probs)
        slots = np.full((n_pos, n_cls), -1, dtype=np.int64)
        slots[self.position[sel], self.class_index[sel]] = sel
        missing = np.argwhere(slots < 0)
        if missing.size:
            probs = [
                f"camera {camera} position {v}: no train image of object {c // self.n_poses} "
                f"pose {c % self.n_poses}"
                for v, c in missing
            ]
            raise database_error(self._where(), probs)
        return self.images[slots]

    def _where(self) -> str:
        return str(self.root) if self.root is not None else "<in memory>"

    # ---- construction ------------------------------------------------------
    @classmethod
    def from_arrays(
        cls,
        images: np.ndarray,
        camera: Sequence[int] | np.ndarray,
        position: Sequence[int] | np.ndarray,
        object: Sequence[int] | np.ndarray,
        pose: Sequence[int] | np.ndarray,
        split: Sequence[str] | np.ndarray,
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


#: the most missing views :meth:`ImageDatabase.train_images` lists one by one
#: when the views are sparse (their count is then said in one more line)
_MAX_LISTED = 1000


def database_error(where: str | os.PathLike, problems: Sequence[str]) -> DatabaseError:
    """A :class:`DatabaseError` for ``problems`` found in ``where``.  Nothing is
    written anywhere: the message shows the count and the first
    :data:`~.problems.SHOWN`, the exception keeps the whole list (the command
    line's ``--debug`` prints it, ``--problems-out FILE`` writes it)."""
    return DatabaseError(str(where), problems)


def _dense_problems(first_rows: dict[str, dict[int, int]]) -> list[str]:
    """One problem per gap in the indices of each group: ``first_rows`` maps a
    group name (``"object"``, ``"camera 0 position"``) to ``{index: first row
    using it}``.  Sorting the distinct indices only: linear in the rows, never
    in the largest index."""
    problems = []
    for name, first in first_rows.items():
        expected = 0
        for v in sorted(first):
            if v != expected:
                gap = f"{expected}" if v == expected + 1 else f"{expected}..{v - 1}"
                problems.append(f"row {first[v]}: {name} {v} leaves a gap (no row has {name} {gap}; "
                                f"indices count 0, 1, 2, ... without gaps)")
            expected = v + 1
    return problems


def check_rows(rows: Sequence[tuple[int, ManifestRow]]) -> list[str]:
    """Value checks of parsed rows ``(row number, row)``: negative or too large
    indices, gaps in the dense ranges the indices form (cameras, each
    camera's positions, objects, poses; one problem per gap, naming the first
    row past it), unknown split, rows that repeat another exactly, two
    ``train`` images of one (camera, position, object, pose).  A path shared
    by rows that differ otherwise (turntable views) is not a problem.  Time
    and memory are linear in the rows, whatever the indices' values."""
    problems: list[str] = []
    seen_row: dict[ManifestRow, int] = {}
    seen_train: dict[tuple, int] = {}
    first: dict[str, dict[int, int]] = {"camera": {}, "object": {}, "pose": {}}
    positions: dict[int, dict[int, int]] = {}
    for r, row in rows:
        in_range = True
        for name in INT_COLUMNS:
            val = getattr(row, name)
            if val < 0:
                problems.append(f"row {r}: {name} = {val} is negative")
                in_range = False
            elif val >= MAX_INDEX:
                problems.append(f"row {r}: {name} = {one_line(val, 40)} is too large (must be < {MAX_INDEX})")
                in_range = False
        if in_range:
            for name in ("camera", "object", "pose"):
                first[name].setdefault(getattr(row, name), r)
            positions.setdefault(row.camera, {}).setdefault(row.position, r)
        if row.split not in SPLITS:
            problems.append(f"row {r}: split '{one_line(row.split, 60)}' is not one of {', '.join(SPLITS)}")
        if row in seen_row:
            problems.append(f"row {r}: duplicate of row {seen_row[row]} (same path '{one_line(row.path, 120)}', "
                            f"camera, position, object, pose and split)")
        else:
            seen_row[row] = r
        key = (row.camera, row.position, row.object, row.pose)
        if row.split == "train":
            if key in seen_train:
                problems.append(
                    f"row {r}: duplicate train entry camera {row.camera} position {row.position} "
                    f"object {row.object} pose {row.pose} (first at row {seen_train[key]})"
                )
            else:
                seen_train[key] = r
    first.update({f"camera {c} position": positions[c] for c in sorted(positions)})
    return problems + _dense_problems(first)


def shared_files(paths: Sequence[str]) -> int:
    """How many distinct image files are used by more than one row."""
    return sum(1 for n in Counter(paths).values() if n > 1)


def manifest_text(rows: Sequence[Sequence]) -> str:
    """The manifest for ``rows`` (each ``(path, camera, position, object, pose, split)``)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for p, *idx, s in rows:
        w.writerow([p, *(int(x) for x in idx), s])
    return buf.getvalue()


def write_manifest(folder, rows: Sequence[Sequence]):
    """Write ``folder/manifest.csv`` for ``rows`` (each ``(path, camera,
    position, object, pose, split)``), sorted by split (in :data:`SPLITS`
    order), camera, position, object, pose and path: the order of the
    rendered databases, whatever order their images were made in.  Returns
    the manifest's path."""
    ordered = sorted(rows, key=lambda r: (SPLITS.index(r[5]), r[1], r[2], r[3], r[4], r[0]))
    manifest = Path(folder) / "manifest.csv"
    return write_text(manifest, manifest_text(ordered), "manifest")


def parse_manifest(raw: bytes, where: str) -> tuple[list[tuple[int, ManifestRow]], list[str]]:
    """Parse the bytes of ``manifest.csv``: ``(numbered rows, problems)``.

    Header problems (unknown, repeated, missing columns) and per-row syntax
    problems (field count, non-integer index, empty or escaping path) are
    listed; the value checks are :func:`check_rows`.  A manifest that cannot
    be read at all (not UTF-8, no header, missing columns, broken CSV) raises
    :class:`DatabaseError` at once.
    """
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise DatabaseError(where, [f"manifest.csv is not UTF-8 text ({e.reason} at byte {e.start})"]) from None
    problems: list[str] = []
    numbered: list[tuple[int, ManifestRow]] = []
    n_rows = 0  # lines read after the header, for the row number of a CSV error
    try:
        reader = csv.reader(io.StringIO(text, newline=""))
        header = next(reader, None)
        if header is None:
            raise DatabaseError(where, ["manifest.csv is empty (no header)"])
        header = [h.strip() for h in header]
        for h in header:
            if h not in COLUMNS:
                problems.append(f"header: unknown column '{one_line(h, 60)}'")
        for h, k in Counter(header).items():
            if k > 1:
                problems.append(f"header: column '{h}' appears {k} times")
        missing = [c for c in COLUMNS if c not in header]
        if missing:
            problems.append(f"header: missing column(s) {', '.join(missing)}")
            raise DatabaseError(where, problems)
        col = {h: header.index(h) for h in COLUMNS}
        for r, fields in enumerate(reader, start=1):
            n_rows = r
            if not fields or all(not f.strip() for f in fields):
                continue
            if len(fields) != len(header):
                problems.append(f"row {r}: {len(fields)} fields, header has {len(header)}")
                continue
            bad = False
            vals = []
            for name in INT_COLUMNS:
                s = fields[col[name]].strip()
                try:
                    vals.append(int(s))
                except ValueError:
                    problems.append(f"row {r}: {name} '{one_line(s, 40)}' is not an integer")
                    bad = True
            path = fields[col["path"]].strip()
            if not path:
                problems.append(f"row {r}: empty path")
                bad = True
            elif (os.path.isabs(path) or ".." in Path(path).parts or "\\" in path
                  or not all(ch.isprintable() for ch in path)):
                problems.append(f"row {r}: path '{one_line(path, 120)}' must be relative, inside the "
                                f"folder, with '/' separators and printable characters")
                bad = True
            if not bad:
                numbered.append((r, ManifestRow(path, *vals, fields[col["split"]].strip())))
    except csv.Error as e:
        problems.append(f"row {n_rows + 1}: broken CSV ({one_line(e, 80)})")
    if not numbered and not problems:
        problems.append("manifest.csv has no rows")
    return numbered, problems


#: The most bytes the images of one database may take in memory (16 GiB).
MAX_DATABASE_BYTES = 1 << 34
#: The largest manifest.csv read (1 GiB: some 20 million rows).
MAX_MANIFEST_BYTES = 1 << 30


def read_gray(file: Path, name: str | None = None) -> tuple[np.ndarray | None, str | None, bool]:
    """Read one image as uint8 gray: ``(image, problem, converted_from_colour)``;
    a problem names the file as ``name`` (default: its file name).  An image
    whose header declares more than :data:`MAX_IMAGE_PIXELS` pixels is a
    problem found before it is decoded (a 20000 x 20000 PNG of a few kB would
    take 1.2 GB)."""
    import cv2

    name = one_line(file.name if name is None else name, 120)
    try:
        found = file.is_file()
    except (OSError, ValueError):  # a name too long for the file system
        found = False
    if not found:
        return None, f"missing file '{name}'", False
    try:
        size = image_size(file)
    except OSError as e:
        return None, f"cannot read image '{name}' ({e.strerror or e})", False
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        return None, (f"image '{name}' is {size[0]}x{size[1]} pixels by its header, more than the "
                      f"{MAX_IMAGE_PIXELS} an image may have (not decoded)"), False
    img = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
    if img is None:
        return None, f"cannot read image '{name}' (not an image file?)", False
    if img.dtype != np.uint8:
        return None, f"image '{name}' is {img.dtype}, expected 8-bit", False
    if img.ndim == 2:
        return img, None, False
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), None, True
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY), None, True
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0], None, False
    return None, f"image '{name}' has unsupported shape {img.shape}", False


def write_image(path: Path, image: np.ndarray) -> None:
    """Write one image file (format from the suffix); :class:`OSError` if OpenCV cannot."""
    import cv2

    if not cv2.imwrite(str(path), image):
        raise OSError(f"could not write image '{path}'")


def _row_key(msg: str) -> tuple[int, str]:
    if msg.startswith("row "):
        try:
            return (int(msg.split(":")[0].split()[1]), msg)
        except ValueError:
            pass
    return (0, msg)


def read_folder(folder: str | os.PathLike) -> "ImageDatabase":
    """Read and validate a database folder (see the module doc for the rules).

    Also checked: every file exists and is an 8-bit image, and all images have
    the same size (the most common size is the reference).  Colour images are
    converted to gray with a :class:`NonGrayImageWarning`.  A file shared by
    several rows is read once.

    Raises:
        DatabaseError: listing every problem, each with its row number.
    """
    root = Path(folder)
    manifest = root / "manifest.csv"
    if not manifest.is_file():
        raise DatabaseError(str(root), [f"no manifest.csv in '{root}'"])
    try:  # the size checked before reading, the read capped
        raw = read_bytes(manifest, "manifest.csv", MAX_MANIFEST_BYTES)
    except OSError as e:
        raise DatabaseError(str(root), [str(e)]) from None
    numbered, problems = parse_manifest(raw, str(root))
    problems += check_rows(numbered)
    # the pixels are kept only for a clean manifest: a broken one is checked
    # file by file (exists, decodes, its size) in the memory of one image
    keep = not problems

    first_row: dict[str, int] = {}  # path -> the first row index (into `numbered`) reading it
    shapes: list[tuple[int, ...] | None] = []
    out: np.ndarray | None = None
    colour_rows: list[int] = []
    file_problems: dict[int, str] = {}  # row index -> the problem of its file
    colour_set: set[int] = set()  # row indices whose file was in colour
    for i, (r, row) in enumerate(numbered):
        j = first_row.setdefault(row.path, i)
        if j != i:  # a file shared by several rows is read once
            shapes.append(shapes[j])
            if shapes[j] is None:
                problems.append(f"row {r}: {file_problems[j]}")
            elif j in colour_set:
                colour_rows.append(r)
            if out is not None and shapes[j] == out.shape[1:]:
                out[i] = out[j]
            continue
        img, problem, converted = read_gray(root / row.path, row.path)
        if problem:
            problems.append(f"row {r}: {problem}")
            file_problems[i] = problem
            shapes.append(None)
            continue
        shapes.append(img.shape)
        if converted:
            colour_rows.append(r)
            colour_set.add(i)
        if keep and out is None:
            need = len(numbered) * img.size
            try:
                if need > MAX_DATABASE_BYTES:
                    raise MemoryError
                out = np.empty((len(numbered), *img.shape), np.uint8)
            except MemoryError:
                problems.append(f"row {r}: {len(numbered)} images of {img.shape[0]}x{img.shape[1]} (this row's "
                                f"size) would take {need / 2**30:.1f} GiB, more than the "
                                f"{MAX_DATABASE_BYTES / 2**30:.0f} GiB a database may")
                keep = False
        if out is not None and img.shape == out.shape[1:]:
            out[i] = img

    counts = Counter(sh for sh in shapes if sh is not None)
    if counts:
        ref = counts.most_common(1)[0][0]
        for (r, row), sh in zip(numbered, shapes):
            if sh is not None and sh != ref:
                problems.append(
                    f"row {r}: image '{one_line(row.path, 120)}' is {sh[0]}x{sh[1]}, "
                    f"the others are {ref[0]}x{ref[1]}"
                )
    problems.sort(key=_row_key)
    if problems:
        raise database_error(root, problems)
    if colour_rows:
        shown = ", ".join(str(r) for r in colour_rows[:SHOWN]) + (" ..." if len(colour_rows) > SHOWN else "")
        warnings.warn(
            f"{root}: {len(colour_rows)} colour image(s) converted to gray (rows {shown})",
            NonGrayImageWarning,
            stacklevel=3,
        )
    rows = [row for _, row in numbered]
    assert out is not None  # a clean manifest has rows, each with an image of one size
    return ImageDatabase(
        images=out,
        camera=np.array([p.camera for p in rows], dtype=np.int64),
        position=np.array([p.position for p in rows], dtype=np.int64),
        object=np.array([p.object for p in rows], dtype=np.int64),
        pose=np.array([p.pose for p in rows], dtype=np.int64),
        split=np.array([p.split for p in rows], dtype=str),
        paths=tuple(p.path for p in rows),
        root=root,
        manifest_sha256=hashlib.sha256(raw).hexdigest(),
    )


def write_folder(folder: str | os.PathLike, db: ImageDatabase) -> Path:
    """Write ``db`` as PNG files plus ``manifest.csv`` under ``folder`` (made
    with its parents if missing; never through a file:
    :func:`jaxrecog._files.check_output_folder`)."""
    root = check_output_folder(folder, "database folder")
    for path, img in zip(db.paths, db.images):
        f = root / path
        f.parent.mkdir(parents=True, exist_ok=True)
        write_image(f, img)
    rows = zip(db.paths, db.camera, db.position, db.object, db.pose, db.split)
    write_text(root / "manifest.csv", manifest_text(list(rows)), "manifest")
    return root
