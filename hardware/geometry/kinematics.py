"""Appendix-C kinematics: planner angles <-> camera positions in the workspace.

The planner outputs three angles (thesis eq. 4.21): camera 1 pan ``theta1`` and
tilt ``nu1`` (a pan-tilt unit on an x-y gantry at fixed height) and camera 2 pan
``theta2`` (a pan-tilt unit on a linear track along y, fixed x and z).  Both
cameras always look at the object, so the positions follow from the angles.

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

Camera 2 (eq. C.34-C.40) has fixed ``x_c2`` and ``z_c2``; with
``tan(theta2) = dy / dx``::

    y_c2 = y_o + dx tan(theta2),   nu2 = atan(dz / sqrt(dx^2 + dy^2))

Angles are in radians throughout this module (its error messages give them in
degrees, the unit of rig files), except the pan-tilt unit's own angles of
:func:`ptu_angles` / :func:`line_of_sight`, which are in degrees like the
rig file's mounts (:class:`Mount`).  Positions are in metres.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Iterable

import numpy as np

__all__ = [
    "DEFAULT_MOUNTS",
    "Mount",
    "WorkspaceError",
    "Workspace",
    "line_of_sight",
    "ptu_angles",
    "camera1_position",
    "camera1_angles",
    "camera2_position",
    "camera2_angles",
]


class WorkspaceError(ValueError):
    """A requested camera placement lies outside the workspace limits."""


@dataclasses.dataclass(frozen=True)
class Workspace:
    """Fixed geometry of the rig (thesis ch. 6, fig. C.1).  Metres.

    Attributes:
        object_xyz: centre of the object on the turn-table.
        cam1_z: height of camera 1 (the gantry does not move in z).
        gantry_x, gantry_y: (min, max) travel of the x-y gantry.
        cam2_x, cam2_z: fixed x and z of camera 2 on its linear track.
        track_y: (min, max) travel of the linear track.
        tilt1_range: (min, max) tilt of camera 1 (radians, elevation, > 0).
    """

    object_xyz: tuple[float, float, float] = (0.0, 0.0, 0.10)
    cam1_z: float = 0.70
    gantry_x: tuple[float, float] = (-1.5, 1.5)
    gantry_y: tuple[float, float] = (-1.5, 1.5)
    cam2_x: float = 0.75
    cam2_z: float = 0.25
    track_y: tuple[float, float] = (-1.5, 1.5)
    tilt1_range: tuple[float, float] = (math.radians(10.0), math.radians(89.0))

    def __post_init__(self):
        if self.cam1_z <= self.object_xyz[2]:
            raise WorkspaceError("camera 1 must fly above the object (cam1_z > object z)")
        if abs(self.cam2_x - self.object_xyz[0]) < 1e-9:
            raise WorkspaceError("camera 2's track must not pass through the object (cam2_x != object x)")


def _check(name: str, value: float, bounds: tuple[float, float], angle: bool = False) -> None:
    """Messages give angles in degrees (as rig files and people write them), lengths in metres."""
    lo, hi = bounds
    if not (lo - 1e-9 <= value <= hi + 1e-9) or not math.isfinite(value):
        if angle:
            value, lo, hi = (math.degrees(v) for v in (value, lo, hi))
            raise WorkspaceError(f"{name} = {value:.4g} deg is outside the workspace limits [{lo:.4g}, {hi:.4g}] deg")
        raise WorkspaceError(f"{name} = {value:.4f} m is outside the workspace limits [{lo:.4f}, {hi:.4f}] m")


def camera1_position(ws: Workspace, pan: float, tilt: float, *, check: bool = True) -> tuple[float, float, float]:
    """Gantry position (x, y, z) of camera 1 for pan ``theta1`` and tilt ``nu1`` (consistent eq. C.27-C.28)."""
    if check:
        _check("camera 1 tilt", tilt, ws.tilt1_range, angle=True)
    xo, yo, zo = ws.object_xyz
    dz = ws.cam1_z - zo
    d = dz / math.tan(tilt)
    x = xo + d * math.sin(pan)
    y = yo + d * math.cos(pan)
    if check:
        _check("gantry x", x, ws.gantry_x)
        _check("gantry y", y, ws.gantry_y)
    return (x, y, ws.cam1_z)


def camera1_angles(ws: Workspace, x: float, y: float) -> tuple[float, float]:
    """Pan and tilt (eq. C.27-C.28) that make camera 1 at gantry (x, y) look at the object."""
    xo, yo, zo = ws.object_xyz
    dx, dy, dz = x - xo, y - yo, ws.cam1_z - zo
    pan = math.atan2(dx, dy)
    tilt = math.atan2(dz, math.hypot(dx, dy))
    return pan, tilt


def camera2_position(ws: Workspace, pan: float, *, check: bool = True) -> tuple[tuple[float, float, float], float]:
    """Track position (x, y, z) and tilt ``nu2`` of camera 2 for pan ``theta2`` (eq. C.39-C.40)."""
    if check and not (-math.pi / 2 < pan < math.pi / 2):
        raise WorkspaceError(f"camera 2 pan = {math.degrees(pan):.4g} deg must lie in (-90, 90) deg")
    xo, yo, zo = ws.object_xyz
    dx = ws.cam2_x - xo
    dz = ws.cam2_z - zo
    y = yo + dx * math.tan(pan)
    if check:
        _check("track y", y, ws.track_y)
    tilt = math.atan2(dz, math.hypot(dx, y - yo))
    return (ws.cam2_x, y, ws.cam2_z), tilt


def camera2_angles(ws: Workspace, y: float) -> tuple[float, float]:
    """Pan (eq. C.34) and tilt (eq. C.35) of camera 2 at track position ``y``."""
    xo, yo, zo = ws.object_xyz
    dx, dy, dz = ws.cam2_x - xo, y - yo, ws.cam2_z - zo
    return math.atan2(dy, dx), math.atan2(dz, math.hypot(dx, dy))


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
