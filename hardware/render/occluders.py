"""Cardboard occluders for the synthetic rig (thesis ch. 7.2: pieces of cardboard).

A layout is plain data (no pybullet): thin boxes ("boards") placed between a
camera and the object, each facing the camera position it was aimed at and
shifted sideways so that it covers part of the object's image.  The layout is
fixed for a trial; as the cameras move, the boards cover more, less or none of
the object, which is what the occlusion levels of the belief track
(thesis eq. 3.6-3.9).

Geometry of one board.  With the object centre ``o``, its bounding radius
``R``, the chosen camera eye ``e``, ``r = |e - o|`` and ``u = (e - o) / r``,
the board plane is perpendicular to ``u`` at distance ``s`` from ``o``
(``s > R``, so it never cuts the object).  Measured in the plane through
``o`` (scale ``k = (r - s) / r`` back to the board), the board is a
rectangle of half sizes ``(a, b) = R (U(size), U(size))`` whose centre sits
``rho R`` from the object's image centre, ``rho ~ U(offset)``, in a random
direction.  The defaults make the occluded fraction of the object, measured
from the segmentation mask, span about 0-30 % of the image from the position
aimed at (and mostly 0 from the others).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from ..geometry.positions import CameraTable

__all__ = ["Board", "OccluderLayout", "OCCLUDER_OFFSET", "OCCLUDER_SIZE", "random_occluders"]

#: Board half-sizes and offsets (units of the object radius) of the campaigns'
#: cardboard occluders (the thesis cases, the turntable's occluded test views):
#: chosen so that the first view of each camera loses roughly 10-40 % of the
#: object (measured from segmentation, see ``TrialResult.occluded_fraction``),
#: "comparable to the levels of the second training set" (thesis §7.2).
OCCLUDER_SIZE = (0.18, 0.38)
OCCLUDER_OFFSET = (0.2, 0.8)


@dataclasses.dataclass(frozen=True)
class Board:
    """One flat cardboard box (metres).

    ``half_extents`` = (half width, half thickness, half height) in the board
    frame, whose y axis (thickness) is ``quaternion`` applied to world y.
    ``aimed_at`` = (camera, position) the board was placed in front of.
    """

    centre: tuple[float, float, float]
    half_extents: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    gray: float
    aimed_at: tuple[int, int]


@dataclasses.dataclass(frozen=True)
class OccluderLayout:
    """The boards of one trial (hashable: the rig rebuilds bodies only when it changes)."""

    boards: tuple[Board, ...]

    def __len__(self) -> int:
        return len(self.boards)


def _quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    """Rotation matrix -> quaternion (x, y, z, w), pybullet's order."""
    t = np.trace(R)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k]) * 2
        q = [0.0, 0.0, 0.0]
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
        w = (R[k, j] - R[j, k]) / s
        x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return (x / n, y / n, z / n, w / n)


def random_occluders(
    rng: np.random.Generator,
    table: CameraTable,
    *,
    radius: float = 0.15,
    boards_per_camera: int = 1,
    cameras: Sequence[int] | None = None,
    size: tuple[float, float] = (0.12, 0.28),
    offset: tuple[float, float] = (0.2, 0.75),
    gap: tuple[float, float] = (0.02, 0.08),
    thickness: float = 0.003,
) -> OccluderLayout:
    """Draw a random cardboard layout for one trial.

    Args:
        rng: seeded NumPy generator (the only source of randomness).
        table: camera table; each board faces a random position of its camera.
        radius: bounding radius R of the objects (``SyntheticRig.radius``).
        boards_per_camera: boards placed in front of each camera.
        cameras: which cameras get boards (default all).
        size: range of the board half sizes, in units of R at the object's depth.
        offset: range of the board centre's distance from the object's image
            centre, in units of R.
        gap: range of the distance from the bounding sphere to the board plane (m).
        thickness: board thickness (m).

    Returns:
        An :class:`OccluderLayout`.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy Generator, got {type(rng).__name__}")
    if radius <= 0 or boards_per_camera < 0 or thickness <= 0:
        raise ValueError("radius and thickness must be > 0 and boards_per_camera >= 0")
    for name, (lo, hi) in (("size", size), ("offset", offset), ("gap", gap)):
        if not 0 <= lo <= hi:
            raise ValueError(f"{name} range must satisfy 0 <= low <= high, got {(lo, hi)}")
    cams = range(table.n_cameras) if cameras is None else cameras
    o = np.asarray(table.workspace.object_xyz, dtype=float)
    z = np.array([0.0, 0.0, 1.0])
    boards = []
    for i in cams:
        if not 0 <= i < table.n_cameras:
            raise ValueError(f"camera {i} is not in the table (0..{table.n_cameras - 1})")
        for _ in range(boards_per_camera):
            v = int(rng.integers(len(table.views[i])))
            e = np.asarray(table.views[i][v].eye, dtype=float)
            r = float(np.linalg.norm(e - o))
            u = (e - o) / r
            s = min(radius + rng.uniform(*gap), 0.6 * r)
            k = (r - s) / r
            x_b = np.cross(u, z)
            if np.linalg.norm(x_b) < 1e-6:
                x_b = np.array([1.0, 0.0, 0.0])
            x_b /= np.linalg.norm(x_b)
            z_b = np.cross(x_b, u)
            a, b = radius * rng.uniform(*size, size=2)
            rho, phi = radius * rng.uniform(*offset), rng.uniform(0.0, 2 * math.pi)
            centre = o + s * u + k * rho * (math.cos(phi) * x_b + math.sin(phi) * z_b)
            R = np.stack([x_b, u, z_b], axis=1)
            boards.append(
                Board(
                    centre=tuple(float(c) for c in centre),
                    half_extents=(float(k * a), thickness / 2, float(k * b)),
                    quaternion=_quaternion(R),
                    gray=float(rng.uniform(0.45, 0.75)),
                    aimed_at=(int(i), v),
                )
            )
    return OccluderLayout(tuple(boards))
