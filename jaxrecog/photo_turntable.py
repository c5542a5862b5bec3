"""Image databases from real turntable photos (``data/turntable-photos``).

A turntable photo set holds, for each object, photos every ``photo_step``
degrees of turntable angle (COIL-20: 72 photos, every 5°).  It becomes an
image database of the project's format (one camera) by the mapping of
``data/turntable-photos/README.md``:

* **positions** are the angles of a sparse grid, ``angle(v) = grid · v``
  (``grid`` divides 360; 20° -> 18 positions);
* **poses** are turntable offsets ``offset(p) = 360 p / poses`` (4 poses:
  0/90/180/270);
* the photo of view (pose ``p``, position ``v``) is the one at angle
  ``offset(p) + angle(v)`` (mod 360).

Splits, every row labelled with its grid view ``(v, p)``:

``train``  the photo at ``offset(p) + angle(v)``;
``test``   ``offset(p) + angle(v) + test_offset`` (default ``grid / 2``:
           halfway to the next grid view, the honest test -- a real capture
           is never exactly at a training view);
``calib``  ``calib_offset`` (default 5°) off the grid, the sign alternating
           with ``v`` (held-out views for ``train --calibrate``);
``jitter`` ``jitter_per_view`` (0 or 1) photo ``calib_offset`` off on the
           *other* side (extra views for ``train --view-jitter``).

A photo may serve several rows: with poses 90° apart and a 20° grid, the
test photo of (p, v) is the training photo of (p + 1, v - 4).  What is
checked: no ``test`` photo is a ``calib`` or ``jitter`` photo of any view,
nor a ``train`` photo of its own position (whose eigenspace and classes
would then hold it): nothing at the position a test view is replayed at is
fitted or calibrated on it.
"""

from __future__ import annotations

import math
import os
import re
import shutil
from pathlib import Path
from typing import NamedTuple

from ._files import check_output_folder, write_text
from .dbformat import manifest_text

__all__ = ["PhotoSet", "scan_photos", "build_photo_database", "PHOTOS"]

#: The development photos shipped with the repository (64 x 64 COIL-20 objects 1-10).
PHOTOS = Path(__file__).resolve().parent.parent / "data" / "turntable-photos"

_NAME = re.compile(r"^obj(\d+)__(\d+)\.png$")


class PhotoSet(NamedTuple):
    """A folder of turntable photos: ``files[m][i]`` is object ``m`` (0-based)
    at angle ``step * i`` degrees."""

    folder: Path
    files: tuple[tuple[str, ...], ...]
    step: float

    @property
    def n_objects(self) -> int:
        return len(self.files)


def scan_photos(folder: str | os.PathLike = PHOTOS) -> PhotoSet:
    """The photos ``objM__I.png`` of ``folder`` (M 1-based, I the angle index).

    Raises:
        ValueError: no such files, object numbers with gaps, or objects whose
            angle indices are not the same dense range ``0..N-1``.
    """
    root = Path(folder)
    if not root.is_dir():
        raise ValueError(f"photo folder {root} not found")
    found: dict[int, dict[int, str]] = {}
    for name in sorted(os.listdir(root)):
        m = _NAME.match(name)
        if m:
            found.setdefault(int(m.group(1)), {})[int(m.group(2))] = name
    if not found:
        raise ValueError(f"photo folder {root}: no files named objM__I.png")
    objs = sorted(found)
    if objs != list(range(objs[0], objs[0] + len(objs))):
        raise ValueError(f"photo folder {root}: object numbers {objs} have gaps")
    n = len(found[objs[0]])
    for o in objs:
        if sorted(found[o]) != list(range(n)):
            raise ValueError(f"photo folder {root}: object {o} has angle indices other than 0..{n - 1}")
    if 360 % n:
        raise ValueError(f"photo folder {root}: {n} photos an object do not divide 360 degrees")
    return PhotoSet(root, tuple(tuple(found[o][i] for i in range(n)) for o in objs), 360.0 / n)


def _index(photos: PhotoSet, angle: float, what: str) -> int:
    k = angle / photos.step
    if not math.isclose(k, round(k), abs_tol=1e-9):
        raise ValueError(f"{what} {angle:g} degrees is not a multiple of the photos' {photos.step:g} degree step")
    return round(k) % round(360.0 / photos.step)


def build_photo_database(out_dir: str | os.PathLike, grid: float = 20.0, *, photos: PhotoSet | None = None,
                         poses: int = 4, objects: int | None = None, test_offset: float | None = None,
                         calib_offset: float = 5.0, jitter_per_view: int = 0) -> Path:
    """Write a one-camera turntable database (module doc) into ``out_dir``:
    the photos it uses are copied to ``out_dir/photos``; returns the path of
    its ``manifest.csv``.  ``objects``: the first N objects (default all)."""
    ps = photos if photos is not None else scan_photos()
    n_pos = round(360.0 / float(grid))
    if n_pos < 2 or not math.isclose(n_pos * float(grid), 360.0):
        raise ValueError(f"grid must divide 360 into at least 2 positions, got {grid}")
    if int(poses) < 1:
        raise ValueError(f"poses must be >= 1, got {poses}")
    if int(jitter_per_view) not in (0, 1):
        raise ValueError(f"jitter_per_view must be 0 or 1, got {jitter_per_view}")
    n_obj = ps.n_objects if objects is None else int(objects)
    if not 1 <= n_obj <= ps.n_objects:
        raise ValueError(f"objects must lie in 1..{ps.n_objects}, got {objects}")
    t_off = float(grid) / 2 if test_offset is None else float(test_offset)
    offsets = {"train": lambda v: 0.0, "test": lambda v: t_off,
               "calib": lambda v: calib_offset if v % 2 == 0 else -calib_offset,
               "jitter": lambda v: -calib_offset if v % 2 == 0 else calib_offset}
    counts = {"train": 1, "test": 1, "calib": 1, "jitter": int(jitter_per_view)}
    rows: list[tuple] = []
    used: dict[str, set[tuple[int, ...]]] = {s: set() for s in offsets}  # split -> {(object, photo, position)}
    for s, off in offsets.items():
        if not counts[s]:
            continue
        for m in range(n_obj):
            for p in range(int(poses)):
                for v in range(n_pos):
                    at = 360.0 * p / int(poses) + float(grid) * v + off(v)
                    k = _index(ps, at, f"{s} view angle")
                    used[s].add((m, k, v))
                    rows.append((f"photos/{ps.files[m][k]}", 0, v, m, p, s))
    test = {x[:2] for x in used["test"]}
    for s in ("calib", "jitter"):
        both = test & {x[:2] for x in used[s]}
        if both:
            m, k = min(both)
            raise ValueError(f"grid {grid:g}, test offset {t_off:g}: the test photo {ps.files[m][k]} is also a "
                             f"{s} photo; choose offsets that keep the test views apart")
    both = used["test"] & used["train"]
    if both:
        m, k, v = min(both)
        raise ValueError(f"grid {grid:g}, test offset {t_off:g}: the test photo {ps.files[m][k]} is a train "
                         f"photo of its own position {v}; choose offsets that keep the test views apart")
    out = check_output_folder(out_dir, "database folder")
    (out / "photos").mkdir(exist_ok=True)
    for m, k in sorted({x[:2] for x in set().union(*used.values())}):
        shutil.copyfile(ps.folder / ps.files[m][k], out / "photos" / ps.files[m][k])
    return write_text(out / "manifest.csv", manifest_text(rows), "manifest")
