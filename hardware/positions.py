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

from .kinematics import Workspace, camera1_position, camera2_position

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
            "workspace": dataclasses.asdict(self.workspace),
            "camera1": [[math.degrees(v.pan), math.degrees(v.tilt)] for v in self.views[0]],
        }
        if self.n_cameras > 1:
            d["camera2"] = [math.degrees(v.pan) for v in self.views[1]]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CameraTable":
        """Read a table from plain data: ``camera1`` = [[pan, tilt], ...] and
        ``camera2`` = [pan, ...] in degrees, optional ``workspace`` fields."""
        ws_fields = {k: tuple(v) if isinstance(v, list) else v for k, v in d.get("workspace", {}).items()}
        ws = Workspace(**ws_fields)
        if "camera1" not in d:
            raise ValueError("camera table needs a 'camera1' list of [pan, tilt] pairs in degrees")
        cam1 = [(math.radians(p), math.radians(t)) for p, t in d["camera1"]]
        cam2 = [math.radians(p) for p in d.get("camera2", [])]
        return cls.from_angles(ws, cam1, cam2)

    def single_camera(self, camera: int = 0) -> "CameraTable":
        """The table of one camera alone (the single-camera baseline)."""
        return CameraTable(self.workspace, (self.views[camera],))


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
