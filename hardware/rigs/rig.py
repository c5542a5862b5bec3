"""The ``Rig`` interface every camera rig implements (synthetic, dataset, hardware).

A *configuration* is one position index per camera, ``(v1, v2, ...)``.  The flat
configuration index used by the planners is row-major over the cameras
(camera 1 slowest): ``a = index_from_config(config, rig.positions)``, so the
thesis's 32 x 7 grid has ``a = 7 * v1 + v2``.  The mapping is written once,
in :class:`jaxrecog.kernels.config_grid.ConfigGrid`; :func:`index_from_config`
and :func:`config_from_index` are its functional form for rig code (plain
integer arithmetic: Python ints, NumPy arrays and traced JAX arrays alike).

This module is the whole interface between the recognition core and the rigs:
:class:`Rig` and :class:`Capture`, and the pool the trial driver captures
through (:class:`RigPool`, :class:`CaptureJob`, :class:`SceneSpec`; the pools
themselves are in :mod:`.rig_pool`).  It is the one hardware module the core
imports at module level (``docs/architecture.md``, Layers).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol, Sequence, runtime_checkable

import numpy as np

from ...kernels.config_grid import ConfigGrid

__all__ = ["Capture", "CaptureJob", "Rig", "RigError", "RigPool", "SceneSpec", "SeededCaptures", "WorkerPool",
           "config_from_index", "index_from_config"]


class RigError(RuntimeError):
    """A rig could not do what was asked (device fault, bad configuration, ...)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Capture:
    """What one :meth:`Rig.capture` returns: the images and what the rig knows
    about them.

    Not a sequence on purpose: code written for the old ``list of images``
    return fails loudly (``capture()[0]`` is a ``TypeError``) instead of
    silently taking the wrong thing.

    Attributes:
        images: ``uint8 [n_cameras, H, W]``, camera 1 first.
        occluded: true occluded fraction of the object per camera where the rig
            knows it (rendered scenes); ``()`` where it does not (stored or real
            images) -- empty rather than NaN, so records compare equal.
    """

    images: np.ndarray
    occluded: tuple[float, ...]

    def __post_init__(self):
        images = np.asarray(self.images)
        if images.ndim != 3:
            raise RigError(f"a capture holds one 2-D image per camera, got an array of shape {images.shape}")
        occluded = tuple(float(x) for x in self.occluded)
        if len(occluded) not in (0, images.shape[0]):
            raise RigError(f"a capture of {images.shape[0]} image(s) has {len(occluded)} occluded fraction(s)")
        object.__setattr__(self, "images", images)
        object.__setattr__(self, "occluded", occluded)

    @classmethod
    def of(cls, images: Sequence[np.ndarray], occluded: Sequence[float] = ()) -> "Capture":
        """From a list of per-camera images (``occluded`` empty = unknown)."""
        return cls(np.stack([np.asarray(im) for im in images]), tuple(occluded))


class SeededCaptures:
    """Mixin for rigs whose captures draw from ``self._rng`` (noise, shifts,
    the choice among several stored images)."""

    _rng: np.random.Generator

    def reseed(self, seed) -> None:
        """Restart the random stream of the captures from ``seed`` (an int or a
        sequence of ints): campaigns reseed per (trial, step) so a trial's
        images do not depend on which trials ran before it or beside it."""
        self._rng = np.random.default_rng(seed)

    def close(self) -> None:
        """Nothing to release (real rigs close their devices)."""


@runtime_checkable
class Rig(Protocol):
    """Move cameras, capture one 8-bit gray image per camera.

    Everything the trial driver (:mod:`jaxrecog.driver`) uses is declared here;
    it reads no other attribute of a rig.
    """

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

    def reseed(self, seed: Any) -> None:
        """Restart the random stream of the captures (noise, the choice among
        stored images) from ``seed``, an int or a sequence of ints; a no-op for
        a rig whose captures draw nothing."""
        ...

    def move(self, configuration: Sequence[int]) -> None:
        """Move every camera to its position index in ``configuration``."""
        ...

    def capture(self) -> Capture:
        """One ``uint8`` image of ``image_shape`` per camera, with what the rig
        knows about them (:class:`Capture`)."""
        ...

    def close(self) -> None:
        """Release the devices (idempotent)."""
        ...


def index_from_config(configuration, positions: Sequence[int]):
    """Per-camera position indices -> flat configuration index (row-major,
    camera 1 slowest): ``ConfigGrid(positions).index(configuration)``
    (:mod:`jaxrecog.kernels.config_grid`).

    Python ints and NumPy integers are range-checked (``ValueError``) and give
    an ``int``; a traced JAX array ``[n]`` gives a traced scalar (no check)."""
    return ConfigGrid(positions).index(configuration)


def config_from_index(a, positions: Sequence[int]):
    """Flat configuration index -> per-camera position indices (row-major), the
    inverse of :func:`index_from_config`: ``ConfigGrid(positions).configuration(a)``.

    An ``int`` gives a tuple of ints (``ValueError`` outside ``0 .. A-1``); a
    traced JAX scalar gives a tuple of traced scalars."""
    return ConfigGrid(positions).configuration(a)


# ---- rig pools: what the trial driver captures through (implementations: .rig_pool) ----


@dataclasses.dataclass(frozen=True)
class SceneSpec:
    """What a rig must show before a capture: :meth:`Rig.reset`'s arguments.
    ``yaw_offset`` None = on the training grid (``reset`` is called without it,
    as every rig allows)."""

    object: int
    pose: int
    occluders: Any = None
    yaw_offset: float | None = None


@dataclasses.dataclass(frozen=True)
class CaptureJob:
    """One capture of one rig of the pool.

    Attributes:
        rig: index of the rig in the pool (``0 <= rig < n_rigs``).
        scene: set the rig up for this scene first (``reset``), or ``None`` to
            keep the scene it shows.
        seed: the rig's ``reseed`` value for this capture.
        config: the configuration to ``move`` to before capturing.
    """

    rig: int
    scene: SceneSpec | None
    seed: Any
    config: tuple[int, ...]


@runtime_checkable
class RigPool(Protocol):
    """``n_rigs`` identical rigs that capture a batch of jobs at once."""

    @property
    def n_rigs(self) -> int: ...

    @property
    def positions(self) -> tuple[int, ...]: ...

    @property
    def image_shape(self) -> tuple[int, int]: ...

    def capture_batch(self, jobs: Sequence[CaptureJob]) -> list[Capture]:
        """The captures of ``jobs``, in their order; the jobs of one rig run in
        their order (several slots may share a rig)."""
        ...

    def close(self) -> None: ...


class WorkerPool:
    """What the rig pools that own workers share (worker processes,
    :class:`~jaxrecog.hardware.rigs.rig_pool.ProcessRigs`; Ray actors,
    :class:`jaxrecog.ray_rigs.RayRigs`): ``self._finalizer`` (a
    ``weakref.finalize``) stops the workers, at ``close()`` or when the pool
    is collected; a closed pool refuses work; a pool is a context manager."""

    _finalizer: Any

    @property
    def closed(self) -> bool:
        return not self._finalizer.alive

    def _check_open(self) -> None:
        if self.closed:
            raise RigError("the rig pool is closed")

    def close(self) -> None:
        """Stop the workers (idempotent)."""
        self._finalizer()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
