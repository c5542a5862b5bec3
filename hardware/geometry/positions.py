"""The configuration table: which discrete positions each camera can take.

The thesis rig has 32 positions for camera 1 (here 8 pans x 4 tilts) and 7 for
camera 2 (7 pans).  Each position is stored as planner angles (pan, tilt) and
the eye position the appendix-C kinematics gives for them.  Users can replace
the table (``CameraTable.from_dict``), e.g. from a TOML or JSON file.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence

from .kinematics import Workspace, WorkspaceError, camera1_position, camera2_position

__all__ = ["View", "CameraTable", "default_table"]


@dataclasses.dataclass(frozen=True)
class View:
    """One camera position: planner angles (radians) and eye position (metres)."""

    pan: float
    tilt: float
    eye: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class CameraTable:
    """Positions per camera. ``views[i][v]`` is camera ``i`` at position ``v``."""

    workspace: Workspace
    views: tuple[tuple[View, ...], ...]

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.views)

    @property
    def n_cameras(self) -> int:
        return len(self.views)

    @classmethod
    def from_angles(
        cls,
        workspace: Workspace,
        cam1: Sequence[tuple[float, float]],
        cam2: Sequence[float] = (),
    ) -> "CameraTable":
        """Build the thesis rig's table from camera-1 (pan, tilt) pairs and
        camera-2 pans (radians); positions follow from the kinematics, and any
        angle outside the workspace raises ``WorkspaceError``."""
        v1 = tuple(View(float(p), float(t), camera1_position(workspace, p, t)) for p, t in cam1)
        v2 = []
        for p in cam2:
            eye, tilt = camera2_position(workspace, p)
            v2.append(View(float(p), float(tilt), eye))
        views = (v1, tuple(v2)) if v2 else (v1,)
        return cls(workspace, views)

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (degrees), the inverse of :meth:`from_dict`."""
        d: dict[str, Any] = {
            "workspace": _workspace_dict(self.workspace),
            "camera1": [[math.degrees(v.pan), math.degrees(v.tilt)] for v in self.views[0]],
        }
        if self.n_cameras > 1:
            d["camera2"] = [math.degrees(v.pan) for v in self.views[1]]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CameraTable":
        """Read a table from plain data: ``camera1`` = [[pan, tilt], ...] and
        ``camera2`` = [pan, ...] in degrees, optional ``workspace`` fields.

        Raises ``ValueError`` (a ``WorkspaceError`` for a position outside the
        workspace) naming the entry, in the units of the data: degrees, metres."""
        if not isinstance(d, dict):
            raise ValueError(f"expected a table, got {type(d).__name__}")
        unknown = sorted(set(d) - {"camera1", "camera2", "workspace"})
        if unknown:
            raise ValueError(f"unknown key(s) {unknown}; allowed: ['camera1', 'camera2', 'workspace']")
        ws = _workspace(d.get("workspace", {}))
        if "camera1" not in d:
            raise ValueError("camera table needs a 'camera1' list of [pan, tilt] pairs in degrees")
        cam1, cam2 = d["camera1"], d.get("camera2", [])
        if not isinstance(cam1, list) or not cam1:
            raise ValueError(f"camera1 = {_short(cam1)} must be a non-empty list of [pan, tilt] pairs in degrees")
        if not isinstance(cam2, list):
            raise ValueError(f"camera2 = {_short(cam2)} must be a list of pans in degrees")
        for i, pt in enumerate(cam1):
            if not (isinstance(pt, list) and len(pt) == 2 and all(_finite(v) for v in pt)):
                raise ValueError(f"camera1[{i}] = {_short(pt)} must be a [pan, tilt] pair of finite numbers (degrees)")
            try:
                camera1_position(ws, math.radians(pt[0]), math.radians(pt[1]))
            except WorkspaceError as e:
                raise WorkspaceError(f"camera1[{i}] = [{pt[0]:g}, {pt[1]:g}] deg: {e}") from None
        for i, p in enumerate(cam2):
            if not _finite(p):
                raise ValueError(f"camera2[{i}] = {_short(p)} must be a finite number (a pan in degrees)")
            try:
                camera2_position(ws, math.radians(p))
            except WorkspaceError as e:
                raise WorkspaceError(f"camera2[{i}] = {p:g} deg: {e}") from None
        return cls.from_angles(ws, [(math.radians(p), math.radians(t)) for p, t in cam1],
                               [math.radians(p) for p in cam2])

    def single_camera(self, camera: int = 0) -> "CameraTable":
        """The table of one camera alone (the single-camera baseline)."""
        return CameraTable(self.workspace, (self.views[camera],))


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _short(v: Any) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


# workspace key -> number of values (0: one number); the degree-valued one is given in degrees
_WS_FIELDS = {"object_xyz": 3, "cam1_z": 0, "gantry_x": 2, "gantry_y": 2, "cam2_x": 0, "cam2_z": 0, "track_y": 2,
              "tilt1_range_deg": 2}


def _workspace_dict(ws: Workspace) -> dict[str, Any]:
    """The plain-data form :func:`_workspace` reads (lists, the tilt range in degrees)."""
    d: dict[str, Any] = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(ws).items()}
    d["tilt1_range_deg"] = [math.degrees(v) for v in d.pop("tilt1_range")]
    return d


def _workspace(d: Any) -> Workspace:
    """A :class:`Workspace` from plain data (metres; ``tilt1_range_deg`` in degrees), every value checked."""
    if not isinstance(d, dict):
        raise ValueError(f"workspace: expected a table, got {type(d).__name__}")
    unknown = sorted(set(d) - set(_WS_FIELDS))
    if unknown:
        raise ValueError(f"workspace: unknown key(s) {unknown}; allowed: {sorted(_WS_FIELDS)}")
    fields: dict[str, Any] = {}
    for k, v in d.items():
        n = _WS_FIELDS[k]
        unit = "degrees" if k.endswith("_deg") else "metres"
        if n == 0:
            if not _finite(v):
                raise ValueError(f"workspace {k} = {_short(v)} must be a finite number ({unit})")
            fields[k] = float(v)
            continue
        if not (isinstance(v, list) and len(v) == n and all(_finite(x) for x in v)):
            raise ValueError(f"workspace {k} = {_short(v)} must be a list of {n} finite numbers ({unit})")
        if n == 2 and not v[0] <= v[1]:
            raise ValueError(f"workspace {k} = {_short(v)} must be [min, max] with min <= max ({unit})")
        fields[k] = tuple(float(x) for x in v)
    if "tilt1_range_deg" in fields:
        lo, hi = fields.pop("tilt1_range_deg")
        if not 0 < lo <= hi < 90:
            raise ValueError(f"workspace tilt1_range_deg = [{lo:g}, {hi:g}] must lie in (0, 90) degrees")
        fields["tilt1_range"] = (math.radians(lo), math.radians(hi))
    try:
        return Workspace(**fields)
    except WorkspaceError as e:
        raise ValueError(f"workspace: {e}") from None


def default_table(workspace: Workspace | None = None) -> CameraTable:
    """The thesis-sized table: camera 1 = 8 pans (0..315 deg) x 4 tilts
    (30, 45, 60, 75 deg) = 32 positions; camera 2 = 7 pans (-60..60 deg)."""
    ws = workspace or Workspace()
    cam1 = [
        (math.radians(pan), math.radians(tilt))
        for tilt in (30.0, 45.0, 60.0, 75.0)
        for pan in range(0, 360, 45)
    ]
    cam2 = [math.radians(p) for p in (-60.0, -40.0, -20.0, 0.0, 20.0, 40.0, 60.0)]
    return CameraTable.from_angles(ws, cam1, cam2)
