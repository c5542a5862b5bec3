"""The ``Rig`` interface every camera rig implements (synthetic, dataset, hardware).

A *configuration* is one position index per camera, ``(v1, v2, ...)``.  The flat
configuration index used by the planners is row-major over the cameras
(camera 1 slowest): ``a = np.ravel_multi_index(config, rig.positions)``, so the
thesis's 32 x 7 grid has ``a = 7 * v1 + v2``.
"""

from __future__ import annotations

from typing import Protocol, Sequence, runtime_checkable

import numpy as np

__all__ = ["Rig", "RigError", "SeededCaptures", "config_from_index", "index_from_config"]


class RigError(RuntimeError):
    """A rig could not do what was asked (device fault, bad configuration, ...)."""


class SeededCaptures:
    """Mixin for rigs whose captures draw from ``self._rng`` (noise, shifts,
    the choice among several stored images)."""

    _rng: np.random.Generator

    def reseed(self, seed) -> None:
        """Restart the random stream of the captures from ``seed`` (an int or a
        sequence of ints): campaigns reseed per (trial, step) so a trial's
        images do not depend on which trials ran before it or beside it."""
        self._rng = np.random.default_rng(seed)


@runtime_checkable
class Rig(Protocol):
    """Move cameras, capture one 8-bit gray image per camera."""

    @property
    def positions(self) -> tuple[int, ...]:
        """Number of discrete positions of each camera, e.g. ``(32, 7)``."""
        ...

    @property
    def image_shape(self) -> tuple[int, int]:
        """(height, width) of every captured image, e.g. ``(120, 160)``."""
        ...

    def reset(self, object: int, pose: int, occluders: object | None = None) -> None:
        """Place ``object`` in ``pose`` on the turn-table; ``occluders`` is rig-specific
        (``None`` = clean scene)."""
        ...

    def move(self, configuration: Sequence[int]) -> None:
        """Move every camera to its position index in ``configuration``."""
        ...

    def capture(self) -> list[np.ndarray]:
        """One ``uint8`` image of ``image_shape`` per camera, camera 1 first."""
        ...


def config_from_index(a: int, positions: Sequence[int]) -> tuple[int, ...]:
    """Flat configuration index -> per-camera position indices (row-major)."""
    return tuple(int(i) for i in np.unravel_index(int(a), tuple(positions)))


def index_from_config(configuration: Sequence[int], positions: Sequence[int]) -> int:
    """Per-camera position indices -> flat configuration index (row-major)."""
    return int(np.ravel_multi_index(tuple(int(v) for v in configuration), tuple(positions)))
