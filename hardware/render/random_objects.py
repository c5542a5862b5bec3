"""Many objects for the synthetic rig: pybullet_data's procedurally generated meshes.

``pybullet_data/random_urdfs/000`` .. ``999`` each hold ``NNN.urdf`` (one
link, mass 0.1, a coloured visual) and ``NNN.obj`` (a blob of 2..30 convex
pieces, 100..400 vertices, about 6 x 6 x 6 units; the URDF scales it by
0.015).  :func:`random_objects` draws ``n`` of them (a seeded permutation of
the 1000 folders, so ``random_objects(3)`` is the prefix of
``random_objects(50)``) and makes each an :class:`~.scene.ObjectSpec` with one
gray ``"mesh"`` part, the same gray for all, so they differ by shape only.

Each mesh is scaled uniformly so that it fits the bounding radius of the
thesis objects (:func:`~.scene.object_radius` of :func:`~.scene.default_objects`)
about the object centre in every resting orientation of
:data:`RESTING_ROTATIONS` (rotations about x by 0, 90, 180, 270 degrees): the
zoom rule (``Intrinsics.fov``) then frames them as it frames the thesis objects.
"""

from __future__ import annotations

import math
import os
from typing import Sequence

import numpy as np

from .scene import CENTRE_HEIGHT, ObjectSpec, Part, mesh_bounds, default_objects, object_radius, require_pybullet

__all__ = ["N_RANDOM", "RESTING_ROTATIONS", "random_mesh", "random_objects", "rested", "parse_objects"]

#: Folders ``random_urdfs/000`` .. ``999`` of pybullet_data.
N_RANDOM = 1000

#: Resting orientations of the turntable poses (xyz Euler, radians): the
#: object turned about the horizontal x axis by 0, 90, 180 and 270 degrees,
#: then set down on the table.  Not yaw rotations: on a turntable a yaw is
#: just another turntable angle.
RESTING_ROTATIONS: tuple[tuple[float, float, float], ...] = tuple((k * math.pi / 2, 0.0, 0.0) for k in range(4))

GRAY = (0.7, 0.7, 0.7, 1.0)


def random_mesh(k: int) -> str:
    """The mesh of folder ``k``, relative to the pybullet_data folder."""
    if not 0 <= int(k) < N_RANDOM:
        raise ValueError(f"random object {k} is out of range 0..{N_RANDOM - 1}")
    return f"random_urdfs/{int(k):03d}/{int(k):03d}.obj"


def _fit_scale(lo: np.ndarray, hi: np.ndarray, radius: float) -> float:
    """The largest uniform scale at which the mesh's bounding box, set down
    bottom-centred on the table in every orientation of RESTING_ROTATIONS,
    stays within ``radius`` of the object centre (0, 0, CENTRE_HEIGHT)."""
    w = hi - lo
    dims = [(w[0], w[1], w[2]), (w[0], w[2], w[1])]  # about x: 0/180 and 90/270 degrees

    def reach(s: float) -> float:
        out = 0.0
        for a, b, h in dims:
            lateral = (s * a) ** 2 / 4 + (s * b) ** 2 / 4
            out = max(out, lateral + CENTRE_HEIGHT ** 2, lateral + (s * h - CENTRE_HEIGHT) ** 2)
        return math.sqrt(out)

    if reach(0.0) >= radius:
        raise ValueError(f"radius {radius:.3f} m does not reach the table top from the object centre")
    lo_s, hi_s = 0.0, 1.0
    while reach(hi_s) < radius:  # reach grows with s
        hi_s *= 2.0
    for _ in range(60):
        mid = 0.5 * (lo_s + hi_s)
        lo_s, hi_s = (mid, hi_s) if reach(mid) < radius else (lo_s, mid)
    return lo_s


def random_objects(n: int, seed: int = 0, *, radius: float | None = None,
                   rgba: tuple[float, float, float, float] = GRAY, data_path: str | None = None) -> tuple[ObjectSpec, ...]:
    """``n`` objects drawn from pybullet_data's ``random_urdfs`` (module doc).

    Args:
        n: 1 .. 1000 objects.
        seed: which ones: the first ``n`` of a permutation of 0..999 seeded by
            ``seed`` (deterministic; a smaller ``n`` gives a prefix).
        radius: bounding radius to fit (default: the thesis objects', ~0.15 m).
        rgba: the colour of every object (gray).

    Returns:
        ``ObjectSpec`` named ``"random-NNN"`` (its folder) with one mesh part.
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= int(n) <= N_RANDOM:
        raise ValueError(f"random objects: need 1..{N_RANDOM}, got {n!r}")
    if data_path is None:
        _, pybullet_data = require_pybullet()
        data_path = pybullet_data.getDataPath()
    if radius is None:
        radius = object_radius(default_objects(), data_path)
    folders = np.random.default_rng(seed).permutation(N_RANDOM)[: int(n)]
    out = []
    for k in folders.tolist():
        mesh = random_mesh(k)
        path = os.path.join(data_path, mesh)
        if not os.path.exists(path):
            raise FileNotFoundError(f"mesh {mesh!r} is not in pybullet_data ({data_path})")
        lo, hi = mesh_bounds(path)
        s = _fit_scale(lo, hi, float(radius))
        out.append(ObjectSpec(f"random-{k:03d}", (Part("mesh", (s, s, s), (0.0, 0.0, 0.0), rgba=rgba, mesh=mesh),)))
    return tuple(out)


def rested(obj: ObjectSpec, rotation: Sequence[float]) -> ObjectSpec:
    """``obj`` turned by ``rotation`` (xyz Euler) and set down on the table
    (each mesh part re-placed bottom-centred; one-part objects only, as
    :func:`random_objects` makes)."""
    if len(obj.parts) != 1:
        raise ValueError(f"rested() turns one-part objects; {obj.name} has {len(obj.parts)} parts")
    (part,) = obj.parts
    if any(part.rotation):
        raise ValueError(f"rested() expects an unrotated part; {obj.name} has rotation {part.rotation}")
    rot = tuple(float(r) for r in rotation)
    deg = "/".join(f"{math.degrees(r):g}" for r in rot)
    return ObjectSpec(f"{obj.name}@{deg}", (Part(part.shape, part.size, part.position, rotation=rot, rgba=part.rgba,
                                                  mesh=part.mesh),))


def parse_objects(text: str | int) -> tuple[str, int]:
    """``--objects`` of ``jaxrecog render``: ``N`` (the first N of the 8 thesis
    objects) -> ``("thesis", N)``; ``random:N`` -> ``("random", N)``.
    Raises ``ValueError`` with a message for the user."""
    s = str(text).strip()
    if s.lower().startswith("random:"):
        body = s[len("random:"):].strip()
        try:
            n = int(body)
        except ValueError:
            raise ValueError(f"expected random:N with N an integer in 1..{N_RANDOM}, got {s!r}") from None
        if not 1 <= n <= N_RANDOM:
            raise ValueError(f"random:N: pybullet_data has {N_RANDOM} random objects, so N must lie in "
                             f"1..{N_RANDOM}, got {n}")
        return "random", n
    try:
        n = int(s)
    except ValueError:
        raise ValueError(f"expected a positive integer (the first N thesis objects) or random:N, got {s!r}") from None
    if n < 1:
        raise ValueError(f"expected a positive integer (the first N thesis objects) or random:N, got {s!r}")
    return "thesis", n
