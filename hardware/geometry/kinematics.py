"""Appendix-C kinematics: planner angles <-> camera positions in the workspace.

Every camera rides a *carrier* that its pan-tilt unit sits on; the planner
gives each camera a pan ``theta`` and a tilt ``nu`` and, since every camera
looks at the object, the carrier's position follows from the angles.  The
thesis rig (eq. 4.21) has two carriers, and this module has both kinds:

* :class:`Gantry` -- an x-y gantry at fixed height (camera 1: pan ``theta1``
  and tilt ``nu1``);
* :class:`Track` -- a linear track along y at fixed x and z (camera 2: pan
  ``theta2``; its tilt follows).

A :class:`Workspace` holds the object's position and one carrier per camera
(default: the thesis's gantry and track), so a rig of more cameras lists more
carriers (a rig file's ``[[table.workspace.carrier]]``); a new kind of carrier
is a class here with the members of :class:`Carrier`, added to
:data:`CARRIERS`.

With ``Delta = camera - object`` the thesis defines (eq. C.27-C.28)::

    tan(theta) = dx / dy,        tan(nu) = dz / sqrt(dx^2 + dy^2)

so the horizontal distance is ``d = dz / tan(nu)`` and ``dx = d sin(theta)``,
``dy = d cos(theta)``.

.. note::
   The printed eq. C.32-C.33 (``x = x_o + dz cos(theta) / tan(nu)`` and
   ``y = y_o + dz cos(theta) / (tan(nu) tan(theta))``) are not consistent with
   C.27-C.28: they satisfy C.27 but give a horizontal distance of
   ``d cot(theta)`` instead of ``d``, which breaks C.28 for every pan other than
   45 degrees.  We
   implement the consistent form above and test the round trip
   angles -> positions -> angles.

A track camera (eq. C.34-C.40) has fixed ``x_c`` and ``z_c``; with
``tan(theta2) = dy / dx``::

    y_c = y_o + dx tan(theta2),   nu2 = atan(dz / sqrt(dx^2 + dy^2))

Angles are in radians throughout this module (its error messages give them in
degrees, the unit of rig files), except the pan-tilt unit's own angles of
:func:`ptu_angles` / :func:`line_of_sight`, which are in degrees like the
rig file's mounts (:class:`Mount`).  Positions are in metres.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar, Iterable, Protocol, runtime_checkable

import numpy as np

__all__ = [
    "CARRIERS",
    "Carrier",
    "DEFAULT_MOUNTS",
    "Gantry",
    "Mount",
    "Track",
    "WorkspaceError",
    "Workspace",
    "default_mounts",
    "line_of_sight",
    "ptu_angles",
    "camera1_position",
    "camera1_angles",
    "camera2_position",
    "camera2_angles",
]

Point = tuple[float, float, float]


class WorkspaceError(ValueError):
    """A requested camera placement lies outside the workspace limits."""


def _check(name: str, value: float, bounds: tuple[float, float], angle: bool = False) -> None:
    """Messages give angles in degrees (as rig files and people write them), lengths in metres."""
    lo, hi = bounds
    if not (lo - 1e-9 <= value <= hi + 1e-9) or not math.isfinite(value):
        if angle:
            value, lo, hi = (math.degrees(v) for v in (value, lo, hi))
            raise WorkspaceError(f"{name} = {value:.4g} deg is outside the workspace limits [{lo:.4g}, {hi:.4g}] deg")
        raise WorkspaceError(f"{name} = {value:.4f} m is outside the workspace limits [{lo:.4f}, {hi:.4f}] m")


# ---- carriers: where a camera sits for its planner angles ---------------------------


@runtime_checkable
class Carrier(Protocol):
    """What a camera rides on (a :class:`Workspace` holds one per camera).

    ``kind`` names it in rig files; ``FIELDS`` lists its plain-data keys (the
    number of values: 0 a number, 2 a ``[min, max]`` range; a key ending in
    ``_deg`` holds the degrees of the radian field without the suffix);
    ``ENTRY`` describes one table entry (``camera<i>`` of a rig file's
    ``[table]``) and ``takes_tilt`` says whether the entry gives a tilt."""

    kind: ClassVar[str]
    FIELDS: ClassVar[dict[str, int]]
    ENTRY: ClassVar[str]
    takes_tilt: ClassVar[bool]

    def validate(self, target: Point, camera: int) -> None:
        """Raise :class:`WorkspaceError` if this carrier cannot see ``target`` at all."""
        ...

    def place(self, target: Point, pan: float, tilt: float, *, camera: int = 0,
              check: bool = True) -> tuple[Point, float]:
        """The eye (x, y, z) for planner ``pan`` / ``tilt`` (radians) and the tilt it
        then looks at ``target`` with; :class:`WorkspaceError` outside its limits."""
        ...

    def angles(self, target: Point, eye: Point) -> tuple[float, float]:
        """The planner (pan, tilt) that put the camera at ``eye`` (inverse of :meth:`place`)."""
        ...

    def axes(self, eye: Point) -> tuple[float, ...]:
        """The coordinates its motors set at ``eye`` (what the encoders read)."""
        ...

    def eye(self, axes: tuple[float, ...]) -> Point:
        """The eye at motor coordinates ``axes`` (inverse of :meth:`axes`)."""
        ...

    def default_mount(self, target: Point) -> "Mount":
        """A pan-tilt mount that keeps its usual positions inside the PTU-D46's range."""
        ...


@dataclasses.dataclass(frozen=True)
class Gantry:
    """A pan-tilt unit on an x-y gantry at height ``z`` (camera 1 of the thesis,
    eq. C.27-C.28): planner pan and tilt give the gantry's (x, y).

    Attributes:
        z: camera height (the gantry does not move in z).
        x_range, y_range: (min, max) travel of the gantry.
        tilt_range: (min, max) tilt (radians, elevation, > 0).
    """

    kind: ClassVar[str] = "gantry"
    FIELDS: ClassVar[dict[str, int]] = {"z": 0, "x_range": 2, "y_range": 2, "tilt_range_deg": 2}
    ENTRY: ClassVar[str] = "a [pan, tilt] pair"
    takes_tilt: ClassVar[bool] = True

    z: float = 0.70
    x_range: tuple[float, float] = (-1.5, 1.5)
    y_range: tuple[float, float] = (-1.5, 1.5)
    tilt_range: tuple[float, float] = (math.radians(10.0), math.radians(89.0))

    def validate(self, target: Point, camera: int) -> None:
        if self.z <= target[2]:
            raise WorkspaceError(f"camera {camera} must fly above the object (gantry z > object z)")
        lo, hi = (math.degrees(v) for v in self.tilt_range)
        if not 0 < lo <= hi < 90:
            raise WorkspaceError(f"camera {camera}: tilt range [{lo:g}, {hi:g}] deg must lie in (0, 90) deg")

    def place(self, target: Point, pan: float, tilt: float, *, camera: int = 0,
              check: bool = True) -> tuple[Point, float]:
        if check:
            _check(f"camera {camera} tilt", tilt, self.tilt_range, angle=True)
        xo, yo, zo = target
        d = (self.z - zo) / math.tan(tilt)
        x = xo + d * math.sin(pan)
        y = yo + d * math.cos(pan)
        if check:
            _check("gantry x", x, self.x_range)
            _check("gantry y", y, self.y_range)
        return (x, y, self.z), tilt

    def angles(self, target: Point, eye: Point) -> tuple[float, float]:
        dx, dy, dz = (e - t for e, t in zip(eye, target))
        return math.atan2(dx, dy), math.atan2(dz, math.hypot(dx, dy))

    def axes(self, eye: Point) -> tuple[float, ...]:
        return (eye[0], eye[1])

    def eye(self, axes: tuple[float, ...]) -> Point:
        x, y = axes
        return (x, y, self.z)

    def default_mount(self, target: Point) -> "Mount":
        """Looking along azimuth -22.5 deg, 45 deg down at PTU (0, 0): the 8 pans x
        30-75 deg tilts of the default table stay inside the PTU-D46's range."""
        return Mount(pan_zero_deg=-22.5, tilt_zero_deg=-45.0)


@dataclasses.dataclass(frozen=True)
class Track:
    """A pan-tilt unit on a linear track along y at fixed ``x`` and ``z`` (camera 2
    of the thesis, eq. C.34-C.40): the planner pan gives the track's y, the tilt
    follows (a table entry is a pan alone).

    Attributes:
        x, z: the track's fixed x and height.
        y_range: (min, max) travel of the track.
    """

    kind: ClassVar[str] = "track"
    FIELDS: ClassVar[dict[str, int]] = {"x": 0, "z": 0, "y_range": 2}
    ENTRY: ClassVar[str] = "a pan"
    takes_tilt: ClassVar[bool] = False

    x: float = 0.75
    z: float = 0.25
    y_range: tuple[float, float] = (-1.5, 1.5)

    def validate(self, target: Point, camera: int) -> None:
        if abs(self.x - target[0]) < 1e-9:
            raise WorkspaceError(f"camera {camera}'s track must not pass through the object (track x != object x)")

    def place(self, target: Point, pan: float, tilt: float = 0.0, *, camera: int = 0,
              check: bool = True) -> tuple[Point, float]:
        """``tilt`` is not used: on a track the pan fixes the eye."""
        if check and not (-math.pi / 2 < pan < math.pi / 2):
            raise WorkspaceError(f"camera {camera} pan = {math.degrees(pan):.4g} deg must lie in (-90, 90) deg")
        xo, yo, zo = target
        dx, dz = self.x - xo, self.z - zo
        y = yo + dx * math.tan(pan)
        if check:
            _check("track y", y, self.y_range)
        return (self.x, y, self.z), math.atan2(dz, math.hypot(dx, y - yo))

    def angles(self, target: Point, eye: Point) -> tuple[float, float]:
        dx, dy, dz = (e - t for e, t in zip(eye, target))
        return math.atan2(dy, dx), math.atan2(dz, math.hypot(dx, dy))

    def axes(self, eye: Point) -> tuple[float, ...]:
        return (eye[1],)

    def eye(self, axes: tuple[float, ...]) -> Point:
        (y,) = axes
        return (self.x, y, self.z)

    def default_mount(self, target: Point) -> "Mount":
        """Level, looking across the table at the object's x (azimuth -90 deg from
        x > object x), pan mirrored as the thesis's camera 2."""
        return Mount(pan_zero_deg=math.degrees(math.atan2(target[0] - self.x, 0.0)), pan_sign=-1)


#: The carrier kinds a rig file's ``[[table.workspace.carrier]] kind`` can name.
CARRIERS: dict[str, type] = {c.kind: c for c in (Gantry, Track)}


@dataclasses.dataclass(frozen=True)
class Workspace:
    """Fixed geometry of the rig (thesis ch. 6, fig. C.1).  Metres.

    Attributes:
        object_xyz: centre of the object on the turn-table.
        carriers: one :class:`Carrier` per camera of the rig, camera 1 first
            (default: the thesis's :class:`Gantry` and :class:`Track`).  A table
            of fewer cameras uses the first ones.
    """

    object_xyz: tuple[float, float, float] = (0.0, 0.0, 0.10)
    carriers: tuple[Carrier, ...] = (Gantry(), Track())

    def __post_init__(self):
        for i, c in enumerate(self.carriers):
            c.validate(self.object_xyz, i)

    def carrier(self, camera: int) -> Carrier:
        if not 0 <= camera < len(self.carriers):
            raise WorkspaceError(f"camera {camera}: the workspace has carriers for {len(self.carriers)} cameras")
        return self.carriers[camera]


def _thesis(ws: Workspace, camera: int, kind: type):
    c = ws.carrier(camera)
    if not isinstance(c, kind):
        raise WorkspaceError(f"camera {camera} rides a {c.kind}, not a {kind.kind}")
    return c


def camera1_position(ws: Workspace, pan: float, tilt: float, *, check: bool = True) -> tuple[float, float, float]:
    """Gantry position (x, y, z) of camera 1 for pan ``theta1`` and tilt ``nu1`` (consistent eq. C.27-C.28)."""
    return _thesis(ws, 0, Gantry).place(ws.object_xyz, pan, tilt, camera=0, check=check)[0]


def camera1_angles(ws: Workspace, x: float, y: float) -> tuple[float, float]:
    """Pan and tilt (eq. C.27-C.28) that make camera 1 at gantry (x, y) look at the object."""
    g = _thesis(ws, 0, Gantry)
    return g.angles(ws.object_xyz, g.eye((x, y)))


def camera2_position(ws: Workspace, pan: float, *, check: bool = True) -> tuple[tuple[float, float, float], float]:
    """Track position (x, y, z) and tilt ``nu2`` of camera 2 for pan ``theta2`` (eq. C.39-C.40)."""
    return _thesis(ws, 1, Track).place(ws.object_xyz, pan, camera=1, check=check)


def camera2_angles(ws: Workspace, y: float) -> tuple[float, float]:
    """Pan (eq. C.34) and tilt (eq. C.35) of camera 2 at track position ``y``."""
    t = _thesis(ws, 1, Track)
    return t.angles(ws.object_xyz, t.eye((y,)))


# ---- the pan-tilt unit's own angles (degrees) for a line of sight -----------------


@dataclasses.dataclass(frozen=True)
class Mount:
    """How a pan-tilt unit is mounted (the angle part of a rig file's ``[[ptu]]``
    entry, :class:`~jaxrecog.hardware.physical.config.PTUConfig`): ``pan_zero_deg`` /
    ``tilt_zero_deg`` are the azimuth / elevation the camera looks along at
    PTU position (0, 0), ``pan_sign`` = -1 for a unit whose pan turns the
    other way.  :func:`ptu_angles` reads only these three attributes, so a
    ``PTUConfig`` serves as well."""

    pan_zero_deg: float = 0.0
    tilt_zero_deg: float = 0.0
    pan_sign: int = 1


#: Mounts that keep the default table inside the PTU-D46-17.5 limits (+/-159 deg
#: pan, -46.6..+31.1 deg tilt): camera 1 looks along azimuth -22.5 deg, 45 deg
#: down at (0, 0); camera 2 along azimuth -90 deg (towards -x), level, pan mirrored.
DEFAULT_MOUNTS = (Mount(pan_zero_deg=-22.5, tilt_zero_deg=-45.0), Mount(pan_zero_deg=-90.0, pan_sign=-1))


def default_mounts(workspace: Workspace, n_cameras: int | None = None) -> tuple[Mount, ...]:
    """A mount per camera (the first ``n_cameras``), each its carrier's
    :meth:`~Carrier.default_mount`: :data:`DEFAULT_MOUNTS` for the thesis's two."""
    n = len(workspace.carriers) if n_cameras is None else n_cameras
    return tuple(workspace.carrier(i).default_mount(workspace.object_xyz) for i in range(n))


def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def ptu_angles(eye: Iterable[float], target: Iterable[float], mount) -> tuple[float, float]:
    """PTU (pan, tilt) in degrees that point a camera at ``eye`` towards ``target``.

    ``pan = pan_sign * wrap(az - pan_zero)``, ``tilt = el - tilt_zero`` with
    ``az = atan2(dx, dy)``, ``el = atan2(dz, hypot(dx, dy))``, ``d = target - eye``
    (``mount``: a :class:`Mount` or anything with its three attributes)."""
    dx, dy, dz = (float(t) - float(e) for t, e in zip(target, eye))
    az = math.degrees(math.atan2(dx, dy))
    el = math.degrees(math.atan2(dz, math.hypot(dx, dy)))
    return mount.pan_sign * _wrap_deg(az - mount.pan_zero_deg), el - mount.tilt_zero_deg


def line_of_sight(pan: float, tilt: float, mount) -> np.ndarray:
    """Unit vector [3] the camera looks along at PTU (pan, tilt) degrees (inverse of :func:`ptu_angles`)."""
    az = math.radians(mount.pan_sign * pan + mount.pan_zero_deg)
    el = math.radians(tilt + mount.tilt_zero_deg)
    return np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
