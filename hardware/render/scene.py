"""The rendered scene of the synthetic rig: turn-table, 8 objects, fixed lighting.

Everything lives in **one pybullet client in DIRECT mode** and is rendered by its
CPU TinyRenderer (headless).  Visual shapes are built once; a new pose only
moves bodies (``resetBasePositionAndOrientation``), a new object swaps the few
bodies made from those shapes (TinyRenderer transforms every body's triangles,
even off-screen ones), and occluder boards are toggled by parking them far
above every camera.  pybullet keeps the data of every body and visual shape
ever made on a client (about 7 kB a reset with four boards, ~3 kB without:
a long env run grew without bound), so after :data:`REBUILD_AFTER` bodies
the scene moves to a fresh client, at the next :meth:`Scene.set_object`,
with the same object, pose and boards: the images do not change.

Frames.  The *object frame* has its origin on the turn-table axis at the
turn-table top, z up; objects span about z = 0 .. 0.2 m, so their centre is
``CENTRE_HEIGHT`` = 0.10 m above the table top and coincides with the
workspace's ``object_xyz`` (the point every camera looks at, thesis ch. 6).
Pose ``p`` of ``N`` rotates the object by ``360° p / N`` about the vertical
axis through that point.

The objects (thesis fig. 7.1 has 8 real objects; these are stand-ins with the
same structure).  Index ``m`` is thesis object ``m + 1``:

0. duck (``duck.obj`` from ``pybullet_data``, its own texture)
1. bunny (``bunny.obj``), tan
2. mug (``objects/mug.obj``) with a dark logo patch beside the handle
3. toy robot: box torso, sphere head, one capsule arm, backpack, two legs
4. house: walls, gable roof, off-centre chimney, door, window, and a porch
   niche (two fins and an awning) on one wall
5. the same house with a dark **sticker** inside the porch niche
6. truck: cargo box with a side stripe, red cab, windscreen, four wheels, and
   a niche (fins and awning) on the rear doors
7. the same truck with a dark **sticker** inside the rear niche

The niches are as deep as they are wide and roofed, so a sticker is seen only
from cameras within 31° of its normal in azimuth and at low elevation:
objects 4/5 and 6/7 (thesis 5/6 and 7/8) render identically from every other
position.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import sys
from typing import Sequence

import numpy as np

__all__ = [
    "CENTRE_HEIGHT",
    "Part",
    "ObjectSpec",
    "Lighting",
    "Intrinsics",
    "Scene",
    "default_objects",
    "object_radius",
    "require_pybullet",
    "mesh_bounds",
]

CENTRE_HEIGHT = 0.10
_PARK = (0.0, 0.0, 1000.0)  # far above every camera: outside every view frustum
#: bodies made on one pybullet client before the scene rebuilds it (module doc)
REBUILD_AFTER = 4000


@contextlib.contextmanager
def _quiet_stderr_fd():
    """File descriptor 2 on the null device for the block: pybullet's C code
    prints "pybullet build time: ..." there on import, past ``sys.stderr``,
    into the middle of every rig command's progress bars."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no file descriptor 2: nothing to silence
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(null)


def require_pybullet():
    """Import pybullet (and pybullet_data) or fail naming the extra to install;
    the first import's build-time line is not printed (:func:`_quiet_stderr_fd`)."""
    try:
        if "pybullet" in sys.modules:
            import pybullet
        else:
            with _quiet_stderr_fd():
                import pybullet
        import pybullet_data
    except ImportError as err:  # pragma: no branch - message is the point
        raise ImportError(
            "the synthetic rig renders with pybullet, which is not installed; "
            "install the simulation extra: pip install 'jaxrecog[sim]'"
        ) from err
    return pybullet, pybullet_data


@dataclasses.dataclass(frozen=True)
class Part:
    """One rigid piece of an object, in the object frame (metres, radians).

    ``shape`` and ``size``: ``"box"`` half extents (x, y, z); ``"cylinder"`` and
    ``"capsule"`` (radius, length) along local z; ``"sphere"`` (radius,);
    ``"mesh"`` scale (sx, sy, sz) of ``mesh``, a file in ``pybullet_data``.
    ``position`` is the part's centre -- for meshes, where the bottom centre of
    the rotated, scaled mesh's bounding box goes.  ``rotation`` is xyz Euler.
    ``rgba`` is ignored for meshes that bring a texture when ``rgba`` is None.
    """

    shape: str
    size: tuple[float, ...]
    position: tuple[float, float, float]
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rgba: tuple[float, float, float, float] | None = (0.7, 0.7, 0.7, 1.0)
    mesh: str | None = None

    def __post_init__(self):
        need = {"box": 3, "cylinder": 2, "capsule": 2, "sphere": 1, "mesh": 3}
        if self.shape not in need:
            raise ValueError(f"Part shape {self.shape!r} is not one of {sorted(need)}")
        if len(self.size) != need[self.shape] or min(self.size) <= 0:
            raise ValueError(f"Part {self.shape!r} needs {need[self.shape]} positive sizes, got {self.size}")
        if (self.shape == "mesh") != (self.mesh is not None):
            raise ValueError("a 'mesh' part needs a mesh file, and only a mesh part takes one")


@dataclasses.dataclass(frozen=True)
class ObjectSpec:
    """An object: a name and its rigid parts (object frame, see the module doc)."""

    name: str
    parts: tuple[Part, ...]


@dataclasses.dataclass(frozen=True)
class Lighting:
    """Fixed light of the room (TinyRenderer's directional light)."""

    direction: tuple[float, float, float] = (0.5, -0.7, 1.2)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    distance: float = 3.0
    ambient: float = 0.5
    diffuse: float = 0.6
    specular: float = 0.05
    shadows: bool = True
    background: int = 40  # gray level where no surface is seen (a dark room)


@dataclasses.dataclass(frozen=True)
class Intrinsics:
    """Camera intrinsics: image size, clip planes, and the zoom rule.

    The zoom (vertical field of view) is set per position, as the thesis's
    predefined zoom tables do (ch. 6.5, 7): the object's bounding sphere of
    radius R, seen from distance r, fills ``fill`` of the image height,
    ``fov = 2 asin(R / r) / fill`` -- so every object lies fully inside the
    frame from every position, at a similar size.
    """

    height: int = 120
    width: int = 160
    near: float = 0.02
    far: float = 10.0
    fill: float = 0.9

    def __post_init__(self):
        if self.height < 8 or self.width < 8:
            raise ValueError(f"image size {self.height} x {self.width} is too small")
        if not 0 < self.near < self.far:
            raise ValueError(f"clip planes need 0 < near < far, got near={self.near}, far={self.far}")
        if not 0 < self.fill <= 1:
            raise ValueError(f"fill must lie in (0, 1], got {self.fill}")

    def fov(self, radius: float, distance: float) -> float:
        """Vertical field of view in degrees for an object of bounding ``radius`` at ``distance``."""
        if not distance > radius:
            raise ValueError(f"camera at distance {distance:.3f} m is inside the object's bounding sphere ({radius:.3f} m)")
        return math.degrees(2.0 * math.asin(radius / distance) / self.fill)


# ---------------------------------------------------------------- objects


def _c(gray: float) -> tuple[float, float, float, float]:
    return (gray, gray, gray, 1.0)


def _niche(face: str, centre: tuple[float, float, float], rgba, sticker_rgba=None) -> tuple[Part, ...]:
    """Two fins and an awning on a wall facing ``face`` (``"-x"``, ``"-y"``, ...),
    optionally a sticker on the wall between them.  ``centre`` is the middle of
    the sticker on the wall surface.  The niche is 3 cm wide inside and 5 cm
    deep, so its back wall is hidden beyond atan(3/5) = 31° off its normal."""
    axis = {"x": 0, "y": 1}[face[1]]
    sign = -1.0 if face[0] == "-" else 1.0
    depth, half_w, half_h, t = 0.05, 0.017, 0.03, 0.002
    cx, cy, cz = centre

    def at(normal_off: float, lateral: float, dz: float) -> tuple[float, float, float]:
        p = [cx, cy, cz + dz]
        p[axis] += sign * normal_off
        p[1 - axis] += lateral
        return (p[0], p[1], p[2])

    def he(normal: float, lateral: float, z: float) -> tuple[float, float, float]:
        h = [0.0, 0.0, z]
        h[axis] = normal
        h[1 - axis] = lateral
        return (h[0], h[1], h[2])

    parts = [
        Part("box", he(depth / 2, t, half_h), at(depth / 2, -half_w, 0.0), rgba=rgba),
        Part("box", he(depth / 2, t, half_h), at(depth / 2, +half_w, 0.0), rgba=rgba),
        Part("box", he(depth / 2, half_w + t, t), at(depth / 2, 0.0, half_h + t), rgba=rgba),
    ]
    if sticker_rgba is not None:
        parts.append(Part("box", he(0.0015, half_w - t - 0.001, half_h - 0.004), at(0.0015, 0.0, -0.002), rgba=sticker_rgba))
    return tuple(parts)


def _house(sticker: bool) -> ObjectSpec:
    wall, roof = (0.86, 0.80, 0.66, 1.0), (0.55, 0.16, 0.12, 1.0)
    parts = [
        Part("box", (0.06, 0.05, 0.05), (0.0, 0.0, 0.05), rgba=wall),
        # gable roof: two slabs meeting over the ridge along x
        Part("box", (0.066, 0.036, 0.004), (0.0, -0.026, 0.118), rotation=(math.radians(35), 0, 0), rgba=roof),
        Part("box", (0.066, 0.036, 0.004), (0.0, 0.026, 0.118), rotation=(math.radians(-35), 0, 0), rgba=roof),
        Part("box", (0.012, 0.012, 0.03), (0.032, 0.02, 0.15), rgba=_c(0.35)),  # chimney, off-centre
        Part("box", (0.016, 0.002, 0.032), (-0.025, 0.051, 0.032), rgba=(0.25, 0.15, 0.08, 1.0)),  # door (+y)
        Part("box", (0.002, 0.018, 0.014), (-0.061, 0.0, 0.06), rgba=(0.15, 0.2, 0.35, 1.0)),  # window (-x)
    ]
    parts += _niche("-y", (0.015, -0.05, 0.042), wall, (0.08, 0.08, 0.30, 1.0) if sticker else None)
    return ObjectSpec("house+sticker" if sticker else "house", tuple(parts))


def _truck(sticker: bool) -> ObjectSpec:
    cargo, cab = (0.62, 0.78, 0.62, 1.0), (0.78, 0.12, 0.10, 1.0)
    wheel = _c(0.12)
    parts = [
        Part("box", (0.05, 0.04, 0.045), (-0.025, 0.0, 0.07), rgba=cargo),
        Part("box", (0.051, 0.0015, 0.012), (-0.025, 0.041, 0.085), rgba=(0.15, 0.3, 0.7, 1.0)),  # stripe (+y)
        Part("box", (0.028, 0.04, 0.035), (0.053, 0.0, 0.06), rgba=cab),
        Part("box", (0.002, 0.032, 0.014), (0.082, 0.0, 0.075), rgba=_c(0.1)),  # windscreen
    ]
    for x in (-0.05, 0.055):
        for y in (-0.046, 0.046):
            parts.append(Part("cylinder", (0.022, 0.012), (x, y, 0.022), rotation=(math.pi / 2, 0, 0), rgba=wheel))
    parts += _niche("-x", (-0.075, 0.0, 0.065), cargo, (0.08, 0.08, 0.30, 1.0) if sticker else None)
    return ObjectSpec("truck+sticker" if sticker else "truck", tuple(parts))


def default_objects() -> tuple[ObjectSpec, ...]:
    """The 8 default objects (module doc); pairs (4, 5) and (6, 7) differ only by a sticker."""
    up = (math.pi / 2, 0.0, 0.0)  # y-up meshes -> z up
    duck = ObjectSpec("duck", (Part("mesh", (0.1,) * 3, (0.0, 0.0, 0.0), rotation=up, rgba=None, mesh="duck.obj"),))
    bunny = ObjectSpec(
        "bunny", (Part("mesh", (0.09,) * 3, (0.0, 0.0, 0.0), rotation=up, rgba=(0.85, 0.7, 0.5, 1.0), mesh="bunny.obj"),)
    )
    mug = ObjectSpec(
        "mug",
        (
            Part("mesh", (1.55,) * 3, (0.0, 0.0, 0.0), rgba=_c(0.9), mesh="objects/mug.obj"),
            Part("box", (0.002, 0.02, 0.028), (0.0645, -0.008, 0.085), rgba=(0.1, 0.25, 0.55, 1.0)),  # logo (+x)
            Part("cylinder", (0.0642, 0.012), (0.0, 0.0, 0.028), rgba=(0.7, 0.2, 0.15, 1.0)),  # band
        ),
    )
    blue, light, red = (0.2, 0.35, 0.75, 1.0), _c(0.85), (0.8, 0.2, 0.15, 1.0)
    robot = ObjectSpec(
        "robot",
        (
            Part("cylinder", (0.014, 0.04), (0.0, -0.02, 0.02), rgba=_c(0.3)),
            Part("cylinder", (0.014, 0.04), (0.0, 0.02, 0.02), rgba=_c(0.3)),
            Part("box", (0.035, 0.045, 0.05), (0.0, 0.0, 0.09), rgba=blue),
            Part("sphere", (0.032,), (0.0, 0.0, 0.168), rgba=light),
            Part("box", (0.004, 0.008, 0.005), (0.03, -0.012, 0.175), rgba=_c(0.05)),  # eye
            Part("box", (0.004, 0.008, 0.005), (0.03, 0.012, 0.175), rgba=_c(0.05)),  # eye
            Part("capsule", (0.012, 0.07), (0.04, 0.058, 0.11), rotation=(0, math.pi / 2, 0), rgba=red),  # arm (+y)
            Part("cylinder", (0.012, 0.03), (0.0, -0.055, 0.1), rotation=(math.pi / 2, 0, 0), rgba=_c(0.5)),  # stub
            Part("box", (0.015, 0.03, 0.035), (-0.05, 0.0, 0.095), rgba=(0.9, 0.75, 0.2, 1.0)),  # backpack (-x)
        ),
    )
    return (duck, bunny, mug, robot, _house(False), _house(True), _truck(False), _truck(True))


# ---------------------------------------------------------------- geometry helpers


@functools.lru_cache(maxsize=None)
def mesh_bounds(path: str) -> tuple[np.ndarray, np.ndarray]:
    verts = []
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                verts.append([float(x) for x in line.split()[1:4]])
    if not verts:
        raise ValueError(f"mesh {path} has no vertices")
    v = np.asarray(verts)
    return v.min(axis=0), v.max(axis=0)


def _rotation(euler: Sequence[float]) -> np.ndarray:
    """R = Rz @ Ry @ Rx (pybullet's getQuaternionFromEuler convention)."""
    rx, ry, rz = euler
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _part_corners(part: Part, data_path: str) -> tuple[np.ndarray, np.ndarray]:
    """Corners of the part's local bounding box in the object frame, and the
    offset added to ``position`` to place the part's origin (meshes are
    re-centred on their bottom centre)."""
    R = _rotation(part.rotation)
    if part.shape == "mesh":
        lo, hi = mesh_bounds(os.path.join(data_path, part.mesh))
        scale = np.asarray(part.size)
        local = _box_corners(lo * scale, hi * scale) @ R.T
        rlo, rhi = local.min(axis=0), local.max(axis=0)
        offset = -np.array([(rlo[0] + rhi[0]) / 2, (rlo[1] + rhi[1]) / 2, rlo[2]])
        return local + offset + np.asarray(part.position), offset
    if part.shape == "box":
        h = np.asarray(part.size)
    elif part.shape == "sphere":
        h = np.full(3, part.size[0])
    elif part.shape == "cylinder":
        h = np.array([part.size[0], part.size[0], part.size[1] / 2])
    else:  # capsule
        h = np.array([part.size[0], part.size[0], part.size[1] / 2 + part.size[0]])
    return _box_corners(-h, h) @ R.T + np.asarray(part.position), np.zeros(3)


def object_radius(objects: Sequence[ObjectSpec], data_path: str | None = None) -> float:
    """Radius of the smallest sphere about the object centre (0, 0, CENTRE_HEIGHT)
    that holds every object in every pose (bounding boxes of the parts)."""
    if data_path is None:
        _, pybullet_data = require_pybullet()
        data_path = pybullet_data.getDataPath()
    centre = np.array([0.0, 0.0, CENTRE_HEIGHT])
    r = 0.0
    for obj in objects:
        for part in obj.parts:
            corners, _ = _part_corners(part, data_path)
            r = max(r, float(np.linalg.norm(corners - centre, axis=1).max()))
    return r


# ---------------------------------------------------------------- the scene


class Scene:
    """One pybullet DIRECT client: turn-table, the object on it, occluder boards.

    Args:
        objects: object specs (default :func:`default_objects`).
        object_xyz: the object centre in the world (the workspace's ``object_xyz``).
        n_poses: poses per object; pose ``p`` turns the table by ``360° p / n_poses``.
        lighting: fixed light.
    """

    def __init__(
        self,
        objects: Sequence[ObjectSpec] | None = None,
        object_xyz: Sequence[float] = (0.0, 0.0, CENTRE_HEIGHT),
        n_poses: int = 4,
        lighting: Lighting = Lighting(),
    ):
        self._p, pybullet_data = require_pybullet()
        self.data_path = pybullet_data.getDataPath()
        self.objects = tuple(default_objects() if objects is None else objects)
        if not self.objects:
            raise ValueError("the scene needs at least one object")
        if int(n_poses) < 1:
            raise ValueError(f"n_poses must be >= 1, got {n_poses}")
        self.n_poses = int(n_poses)
        self.lighting = lighting
        self.centre = tuple(float(v) for v in object_xyz)
        self.origin = np.array([self.centre[0], self.centre[1], self.centre[2] - CENTRE_HEIGHT])
        self.radius = object_radius(self.objects, self.data_path)
        self._connect()
        self._boards: tuple = ()

    def _connect(self) -> None:
        """A fresh client with the room and the objects' shapes, nothing placed."""
        self._bodies_made = 0
        self.client = self._p.connect(self._p.DIRECT)
        self._textures: dict[str, int] = {}
        try:
            self._build_room()
            self._shapes: list[list[tuple[int, np.ndarray, np.ndarray]]] = [self._build(o) for o in self.objects]
        except Exception:
            self.close()
            raise
        self._current: tuple[int, int, float] | None = None
        self.object_ids: np.ndarray = np.zeros(0, dtype=np.int32)
        self.occluder_ids: list[int] = []
        self._occluder_poses: list[tuple[tuple[float, float, float], tuple[float, ...]]] = []
        self._occluder_key: object = None
        self._occluders_shown = False

    def _rebuild(self) -> None:
        """Move to a fresh client (freeing what pybullet kept of removed bodies),
        with the same boards, shown or parked as they were; the caller places
        the object (:meth:`set_object`)."""
        boards, key, shown = self._boards, self._occluder_key, self._occluders_shown
        self.close()
        self._connect()
        if boards:
            self.set_occluders(boards, key)
            self.show_occluders(shown)

    # -- construction
    def _visual(self, part: Part) -> int:
        p, kw = self._p, {"physicsClientId": self.client}
        if part.rgba is not None:
            kw["rgbaColor"] = part.rgba
        if part.shape == "box":
            return p.createVisualShape(p.GEOM_BOX, halfExtents=part.size, **kw)
        if part.shape == "sphere":
            return p.createVisualShape(p.GEOM_SPHERE, radius=part.size[0], **kw)
        if part.shape == "cylinder":
            return p.createVisualShape(p.GEOM_CYLINDER, radius=part.size[0], length=part.size[1], **kw)
        if part.shape == "capsule":
            return p.createVisualShape(p.GEOM_CAPSULE, radius=part.size[0], length=part.size[1], **kw)
        path = os.path.join(self.data_path, part.mesh)
        if not os.path.exists(path):
            raise FileNotFoundError(f"mesh {part.mesh!r} is not in pybullet_data ({self.data_path})")
        return p.createVisualShape(p.GEOM_MESH, fileName=path, meshScale=part.size, **kw)

    def _body(self, visual: int, pos, orn=(0.0, 0.0, 0.0, 1.0)) -> int:
        body = self._p.createMultiBody(
            baseMass=0.0, baseVisualShapeIndex=visual, basePosition=pos, baseOrientation=orn, physicsClientId=self.client
        )
        if body < 0:
            raise RuntimeError("pybullet could not create a body")
        self._bodies_made += 1
        return body

    def _build_room(self) -> None:
        p, o = self._p, self.origin
        # No floor: TinyRenderer pays per shaded pixel, and a floor filling the
        # frame tripled the frame time; the background is its uniform clear colour.
        table = p.createVisualShape(p.GEOM_CYLINDER, radius=0.15, length=0.03, rgbaColor=_c(0.5), physicsClientId=self.client)
        self.table_id = self._body(table, (o[0], o[1], o[2] - 0.015))

    def _build(self, obj: ObjectSpec) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """Visual shapes of the parts (built once), with their placement in the object frame."""
        out = []
        for part in obj.parts:
            _, offset = _part_corners(part, self.data_path)
            orn = np.asarray(self._p.getQuaternionFromEuler(part.rotation))
            # The mesh origin sits at position + offset (see _part_corners).
            out.append((self._visual(part), np.asarray(part.position) + offset, orn))
        return out

    # -- state
    def set_object(self, obj: int, pose: int, yaw_offset_deg: float = 0.0) -> None:
        """Put object ``obj`` in pose ``pose`` on the turn-table (only its bodies exist),
        turned by a further ``yaw_offset_deg`` degrees (held-out perturbed views)."""
        if not 0 <= int(obj) < len(self.objects):
            raise ValueError(f"object {obj} is out of range 0..{len(self.objects) - 1}")
        if not 0 <= int(pose) < self.n_poses:
            raise ValueError(f"pose {pose} is out of range 0..{self.n_poses - 1}")
        obj, pose, off = int(obj), int(pose), float(yaw_offset_deg)
        if self._bodies_made > REBUILD_AFTER:
            self._rebuild()
        if self._current == (obj, pose, off):
            return
        p, cid = self._p, self.client
        if self._current is None or self._current[0] != obj:
            # Only the object on the table has bodies: TinyRenderer transforms
            # every body's triangles, even parked ones (~1.3 ms a frame for the
            # 8 default objects), while making bodies from built shapes is cheap.
            for body in self.object_ids:
                p.removeBody(int(body), physicsClientId=cid)
            self.object_ids = np.array([self._body(vis, _PARK, orn) for vis, _, orn in self._shapes[obj]], dtype=np.int32)
        yaw = 2.0 * math.pi * pose / self.n_poses + math.radians(off)
        q_yaw = p.getQuaternionFromEuler((0.0, 0.0, yaw))
        Rz = _rotation((0.0, 0.0, yaw))
        for body, (_, pos, orn) in zip(self.object_ids, self._shapes[obj]):
            world = self.origin + Rz @ pos
            _, q = p.multiplyTransforms((0, 0, 0), q_yaw, (0, 0, 0), orn.tolist())
            p.resetBasePositionAndOrientation(int(body), world.tolist(), q, physicsClientId=cid)
        self._current = (obj, pose, off)

    def set_occluders(self, boards, key: object = None) -> None:
        """Replace the occluder boards: ``boards`` is a sequence of objects with
        ``centre``, ``half_extents``, ``quaternion``, ``gray`` (see
        :mod:`.occluders`).  ``key`` identifies the layout; the same key keeps
        the bodies already built."""
        if key is not None and key == self._occluder_key:
            return
        p, cid = self._p, self.client
        for body in self.occluder_ids:
            p.removeBody(body, physicsClientId=cid)
        self.occluder_ids, self._occluder_poses = [], []
        self._boards = tuple(boards)
        for b in boards:
            vis = p.createVisualShape(
                p.GEOM_BOX, halfExtents=b.half_extents, rgbaColor=(b.gray * 1.05, b.gray * 0.95, b.gray * 0.8, 1.0),
                physicsClientId=cid,
            )
            self.occluder_ids.append(self._body(vis, _PARK, b.quaternion))
            self._occluder_poses.append((tuple(b.centre), tuple(b.quaternion)))
        self._occluder_key = key
        self._occluders_shown = False

    def show_occluders(self, shown: bool) -> None:
        """Put the boards in the scene (``True``) or park them (``False``)."""
        if shown == self._occluders_shown:
            return
        p, cid = self._p, self.client
        for body, (pos, q) in zip(self.occluder_ids, self._occluder_poses):
            p.resetBasePositionAndOrientation(body, pos if shown else _PARK, q, physicsClientId=cid)
        self._occluders_shown = shown

    # -- rendering
    def render(
        self,
        eye: Sequence[float],
        fov_deg: float,
        intrinsics: Intrinsics,
        shift: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[np.ndarray, np.ndarray]:
        """Render from ``eye`` looking at the object centre.

        Returns:
            gray ``uint8 [H, W]`` (ITU-R 601 luma of the RGB render) and the
            segmentation ``int32 [H, W]`` (body id per pixel, -1 = nothing).
            ``shift = (dx, dy)`` moves the image content by dx pixels right and
            dy down (a principal-point offset, so no border is invented).
        """
        p, L = self._p, self.lighting
        H, W = intrinsics.height, intrinsics.width
        eye = [float(v) for v in eye]
        fwd = np.asarray(self.centre) - np.asarray(eye)
        up = (0.0, 0.0, 1.0)
        if np.linalg.norm(np.cross(fwd, up)) < 1e-6 * np.linalg.norm(fwd):
            up = (0.0, 1.0, 0.0)  # looking straight down: any horizontal up works
        view = p.computeViewMatrix(eye, self.centre, up, physicsClientId=self.client)
        proj = list(p.computeProjectionMatrixFOV(fov_deg, W / H, intrinsics.near, intrinsics.far, physicsClientId=self.client))
        # column-major 4x4: proj[8] = P[0][2], proj[9] = P[1][2]; x_ndc gains -P[0][2].
        proj[8] = -2.0 * shift[0] / W
        proj[9] = 2.0 * shift[1] / H
        _, _, rgba, _, seg = p.getCameraImage(
            W, H, view, proj,
            renderer=p.ER_TINY_RENDERER,
            shadow=int(L.shadows),
            lightDirection=L.direction,
            lightColor=L.color,
            lightDistance=L.distance,
            lightAmbientCoeff=L.ambient,
            lightDiffuseCoeff=L.diffuse,
            lightSpecularCoeff=L.specular,
            physicsClientId=self.client,
        )
        rgb = np.asarray(rgba, dtype=np.uint8).reshape(H, W, 4)[:, :, :3].astype(np.float32)
        gray = rgb @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
        gray = np.clip(np.rint(gray), 0, 255).astype(np.uint8)
        seg = np.asarray(seg, dtype=np.int32).reshape(H, W)
        gray[seg < 0] = L.background
        return gray, seg

    def close(self) -> None:
        if getattr(self, "client", None) is not None:
            try:
                self._p.disconnect(physicsClientId=self.client)
            except Exception:  # already gone (interpreter shutdown)
                pass
            self.client = None

    def __del__(self):
        self.close()
