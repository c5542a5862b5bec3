"""A rig that replays an image database (folder + ``manifest.csv``).

``move`` selects each camera's position, ``capture`` returns a stored image of
the current object and pose at those positions, from the chosen split
(``test`` by default).  Works with any number of cameras and positions, so a
campaign can run on a real image set exactly as on the rendered rig.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ...dbformat import read_folder
from .rig import Capture, RigError, SeededCaptures

__all__ = ["DatasetRig"]


class DatasetRig(SeededCaptures):
    """Replay one split of an image database through the ``Rig`` interface.

    Args:
        database: a :class:`~jaxrecog.dbformat.ImageDatabase` (or anything with the
            same ``images``, ``camera``, ``position``, ``object``, ``pose``,
            ``split`` arrays and ``positions``).
        split: which rows to replay (``"test"`` by default).
        seed: when several images exist for one (camera, position, object,
            pose), each capture picks one at random from this seed.
    """

    def __init__(self, database, *, split: str = "test", seed: int = 0):
        rows = np.flatnonzero(np.asarray(database.split) == split)
        if rows.size == 0:
            raise RigError(f"the database has no '{split}' rows to replay (give it some: rows with split "
                           f"'{split}' in its manifest, or `jaxrecog render --test-per-view N` for a rendered one)")
        self._db = database
        self._rng = np.random.default_rng(seed)
        self._index: dict[tuple[int, int, int, int], list[int]] = {}
        for r in rows:
            k = (int(database.camera[r]), int(database.position[r]), int(database.object[r]), int(database.pose[r]))
            self._index.setdefault(k, []).append(int(r))
        self._positions = tuple(int(p) for p in database.positions)
        self._shape = tuple(int(s) for s in database.images.shape[1:3])
        # the database's counts (all splits), for the one model-vs-rig check
        self._n_objects = int(np.max(database.object)) + 1
        self._n_poses = int(np.max(database.pose)) + 1
        self._scene: tuple[int, int] | None = None
        self._config: tuple[int, ...] | None = None

    @classmethod
    def from_folder(cls, folder, **kwargs) -> "DatasetRig":
        """Read and validate the folder (:func:`~jaxrecog.dbformat.read_folder`) and replay it."""
        return cls(read_folder(folder), **kwargs)

    @property
    def positions(self) -> tuple[int, ...]:
        return self._positions

    @property
    def image_shape(self) -> tuple[int, int]:
        return self._shape  # type: ignore[return-value]

    @property
    def n_objects(self) -> int:
        """Objects of the database (largest index + 1)."""
        return self._n_objects

    @property
    def n_poses(self) -> int:
        """Poses per object of the database (largest index + 1)."""
        return self._n_poses

    def reset(self, object: int, pose: int, occluders: object | None = None) -> None:
        if occluders is not None:
            raise RigError("a dataset rig replays stored images; it cannot add occluders")
        self._scene = (int(object), int(pose))

    def move(self, configuration: Sequence[int]) -> None:
        cfg = tuple(int(v) for v in configuration)
        if len(cfg) != len(self._positions) or any(not 0 <= v < n for v, n in zip(cfg, self._positions)):
            raise RigError(f"configuration {cfg} is outside the positions {self._positions}")
        self._config = cfg

    def capture(self) -> Capture:
        if self._scene is None or self._config is None:
            raise RigError("call reset() and move() before capture()")
        out = []
        for cam, v in enumerate(self._config):
            rows = self._index.get((cam, v) + self._scene)
            if not rows:
                raise RigError(
                    f"no stored image for camera {cam}, position {v}, object {self._scene[0]}, pose {self._scene[1]}"
                )
            out.append(np.array(self._db.images[rows[int(self._rng.integers(len(rows)))]], np.uint8))
        return Capture.of(out)  # a stored image's occluded fraction is unknown
