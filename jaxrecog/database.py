"""The image database users work with: load, write, inspect.

The format (columns, rules, the in-memory :class:`ImageDatabase`, reading and
writing) is defined once, in :mod:`jaxrecog.dbformat`, and
re-exported here.  :func:`load_database` validates the whole folder and
reports *every* problem at once, each with its manifest row number (row 1 is
the first line after the header); nothing is written into the folder (the
command line's ``--problems-out FILE`` writes a long list where the user says).  Any number of cameras,
positions, objects and poses is accepted; class ``c = object * n_poses +
pose``.  One image file may serve several rows (turntable views:
:func:`notes` counts them).
"""

from __future__ import annotations

import os

from .dbformat import (
    COLUMNS,
    SPLITS,
    DatabaseError,
    ImageDatabase,
    NonGrayImageWarning,
    read_folder,
    shared_files,
)
from .dbformat import write_folder as write_database

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


def load_database(folder: str | os.PathLike) -> ImageDatabase:
    """Load and validate an image database folder
    (:func:`jaxrecog.dbformat.read_folder`: header, indices, splits,
    exact duplicate rows, two ``train`` images of one view, missing or
    unreadable files, image sizes; colour images become gray with a
    :class:`NonGrayImageWarning`).

    Raises:
        DatabaseError: listing every problem, each with its row number.
    """
    return read_folder(folder)


def notes(db: ImageDatabase) -> list[str]:
    """Lines worth telling a user about a valid database (``jaxrecog inspect``):
    image files shared by several rows (turntable views)."""
    n = shared_files(db.paths)
    if not n:
        return []
    return [f"  {n} image file(s) are used by more than one row (turntable views: one photo "
            f"serves several (pose, position) rows)"]
