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

from .kinematics import CARRIERS, Carrier, Gantry, Track, Workspace, WorkspaceError

__all__ = ["View", "CameraTable", "default_table", "entry_text"]


@dataclasses.dataclass(frozen=True)
class View:
    """One camera position: planner angles (radians) and eye position (metres)."""

    pan: float
    tilt: float
    eye: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class CameraTable:
    """Positions per camera. ``views[i][v]`` is camera ``i`` at position ``v``;
    camera ``i`` rides ``workspace.carriers[i]`` (:attr:`carriers`)."""

    workspace: Workspace
    views: tuple[tuple[View, ...], ...]

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(len(v) for v in self.views)

    @property
    def n_cameras(self) -> int:
        return len(self.views)

    @property
    def carriers(self) -> tuple[Carrier, ...]:
        """The carrier of each camera (:class:`~.kinematics.WorkspaceError` if the
        workspace lists fewer carriers than the table has cameras)."""
        return tuple(self.workspace.carrier(i) for i in range(self.n_cameras))

    @classmethod
    def from_angles(cls, workspace: Workspace, *cameras: Sequence) -> "CameraTable":
        """Build a table from planner angles (radians), one sequence per camera in
        its carrier's form: (pan, tilt) pairs for a gantry, pans for a track (the
        thesis rig: ``from_angles(ws, cam1_pairs, cam2_pans)``).  Positions follow
        from the kinematics, and any angle outside the workspace raises
        ``WorkspaceError``; empty trailing cameras are left out."""
        cameras = list(cameras)
        while len(cameras) > 1 and not len(cameras[-1]):
            cameras.pop()
        views = []
        for i, entries in enumerate(cameras):
            carrier = workspace.carrier(i)
            row = []
            for e in entries:
                pan, tilt = (e if carrier.takes_tilt else (e, 0.0))
                eye, tilt = carrier.place(workspace.object_xyz, pan, tilt, camera=i)
                row.append(View(float(pan), float(tilt), eye))
            views.append(tuple(row))
        return cls(workspace, tuple(views))

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (degrees), the inverse of :meth:`from_dict`."""
        d: dict[str, Any] = {"workspace": _workspace_dict(self.workspace)}
        for i, (carrier, views) in enumerate(zip(self.carriers, self.views)):
            d[f"camera{i + 1}"] = [_entry(carrier, v) for v in views]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "CameraTable":
        """Read a table from plain data: ``camera1``, ``camera2``, ... one list per
        camera of entries in degrees in its carrier's form (``[pan, tilt]`` on a
        gantry, a pan on a track; the thesis rig: ``camera1`` = [[pan, tilt],
        ...], ``camera2`` = [pan, ...]), optional ``workspace`` fields.

        Raises ``ValueError`` (a ``WorkspaceError`` for a position outside the
        workspace) naming the entry, in the units of the data: degrees, metres."""
        if not isinstance(d, dict):
            raise ValueError(f"expected a table, got {type(d).__name__}")
        ws = _workspace(d.get("workspace", {}))
        keys = [f"camera{i + 1}" for i in range(len(ws.carriers))]
        unknown = sorted(set(d) - {*keys, "workspace"})
        if unknown:
            more = [k for k in unknown if k.startswith("camera")]
            hint = (f"; a camera needs a carrier: list one per camera in the workspace's carrier list "
                    f"([[table.workspace.carrier]])" if more else "")
            raise ValueError(f"unknown key(s) {unknown}; allowed: {sorted({*keys, 'workspace'})}{hint}")
        if "camera1" not in d:
            raise ValueError(f"camera table needs a 'camera1' list of {_entries(ws.carrier(0))} in degrees")
        cameras = []
        for i, key in enumerate(keys):
            value = d.get(key, [])
            if key not in d:
                break
            carrier = ws.carrier(i)
            if not isinstance(value, list) or (i == 0 and not value):
                need = "a non-empty list" if i == 0 else "a list"
                raise ValueError(f"{key} = {_short(value)} must be {need} of {_entries(carrier)} in degrees")
            cameras.append([_read_entry(carrier, ws, i, k, e) for k, e in enumerate(value)])
        if len(cameras) < len([k for k in keys if k in d]):
            missing = keys[len(cameras)]
            raise ValueError(f"{missing} is missing: cameras are numbered 1, 2, ... without gaps")
        return cls.from_angles(ws, *cameras)

    def single_camera(self, camera: int = 0) -> "CameraTable":
        """The table of one camera alone (the single-camera baseline)."""
        return self.subset((camera,))

    def subset(self, cameras: Sequence[int]) -> "CameraTable":
        """The table of ``cameras`` alone, in that order, each with its carrier."""
        carriers = tuple(self.workspace.carriers[i] for i in cameras if i < len(self.workspace.carriers))
        ws = dataclasses.replace(self.workspace, carriers=carriers)
        return CameraTable(ws, tuple(self.views[i] for i in cameras))


def _entries(carrier: Carrier) -> str:
    """What a list of the carrier's table entries holds ("[pan, tilt] pairs", "pans")."""
    return "[pan, tilt] pairs" if carrier.takes_tilt else "pans"


def _entry(carrier: Carrier, view: View) -> Any:
    pan, tilt = math.degrees(view.pan), math.degrees(view.tilt)
    return [pan, tilt] if carrier.takes_tilt else pan


def entry_text(carrier: Carrier, view: View) -> str:
    """A view as its table entry is written: ``[0, 30]`` on a gantry, ``-60`` on a track (degrees)."""
    e = _entry(carrier, view)
    return f"[{e[0]:g}, {e[1]:g}]" if isinstance(e, list) else f"{e:g}"


def _read_entry(carrier: Carrier, ws: Workspace, camera: int, k: int, e: Any) -> Any:
    """One table entry in degrees -> radians in the carrier's form, checked against the workspace."""
    where = f"camera{camera + 1}[{k}]"
    if carrier.takes_tilt:
        if not (isinstance(e, list) and len(e) == 2 and all(_finite(v) for v in e)):
            raise ValueError(f"{where} = {_short(e)} must be a [pan, tilt] pair of finite numbers (degrees)")
        angles, text = (math.radians(e[0]), math.radians(e[1])), f"[{e[0]:g}, {e[1]:g}]"
    else:
        if not _finite(e):
            raise ValueError(f"{where} = {_short(e)} must be a finite number (a pan in degrees)")
        angles, text = (math.radians(e), 0.0), f"{e:g}"
    try:
        carrier.place(ws.object_xyz, *angles, camera=camera)
    except WorkspaceError as err:
        raise WorkspaceError(f"{where} = {text} deg: {err}") from None
    return angles if carrier.takes_tilt else angles[0]


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _short(v: Any) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


# The thesis rig's flat workspace keys (camera 1 on a gantry, camera 2 on a track):
# key -> (carrier index, that carrier's key)
_THESIS_KEYS = {"cam1_z": (0, "z"), "gantry_x": (0, "x_range"), "gantry_y": (0, "y_range"),
                "tilt1_range_deg": (0, "tilt_range_deg"), "cam2_x": (1, "x"), "cam2_z": (1, "z"),
                "track_y": (1, "y_range")}


def _workspace_dict(ws: Workspace) -> dict[str, Any]:
    """The plain-data form :func:`_workspace` reads: the thesis's flat keys for a
    gantry and a track, a ``carrier`` list otherwise (lists, angles in degrees)."""
    d: dict[str, Any] = {"object_xyz": list(ws.object_xyz)}
    carriers = [_carrier_dict(c) for c in ws.carriers]
    if [type(c) for c in ws.carriers] == [Gantry, Track]:
        for key, (i, field) in _THESIS_KEYS.items():
            d[key] = carriers[i][field]
    else:
        d["carrier"] = carriers
    return d


def _carrier_dict(c: Carrier) -> dict[str, Any]:
    d: dict[str, Any] = {"kind": c.kind}
    for key in c.FIELDS:
        v = getattr(c, key.removesuffix("_deg"))
        if key.endswith("_deg"):
            v = [math.degrees(x) for x in v]
        d[key] = list(v) if isinstance(v, tuple) else v
    return d


def _numbers(d: dict[str, Any], fields: dict[str, int], where: str) -> dict[str, Any]:
    """Checked values of ``d`` (every key in ``fields``: 0 = a number, n = a list of n;
    a 2-list is ``[min, max]``); ``*_deg`` keys become radians without the suffix."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        n = fields[k]
        unit = "degrees" if k.endswith("_deg") else "metres"
        if n == 0:
            if not _finite(v):
                raise ValueError(f"{where} {k} = {_short(v)} must be a finite number ({unit})")
            out[k] = float(v)
            continue
        if not (isinstance(v, list) and len(v) == n and all(_finite(x) for x in v)):
            raise ValueError(f"{where} {k} = {_short(v)} must be a list of {n} finite numbers ({unit})")
        if n == 2 and not v[0] <= v[1]:
            raise ValueError(f"{where} {k} = {_short(v)} must be [min, max] with min <= max ({unit})")
        if k.endswith("_deg"):
            k, v = k.removesuffix("_deg"), [math.radians(x) for x in v]
        out[k] = tuple(float(x) for x in v)
    return out


def _carrier(d: Any, i: int) -> Carrier:
    """One ``[[table.workspace.carrier]]`` entry."""
    where = f"workspace carrier #{i + 1}"
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected a table, got {type(d).__name__}")
    kind = d.get("kind")
    if kind not in CARRIERS:
        raise ValueError(f"{where}: kind = {_short(kind)} must be one of {sorted(CARRIERS)}")
    cls = CARRIERS[kind]
    unknown = sorted(set(d) - {"kind", *cls.FIELDS})
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; allowed for a {kind}: {sorted({'kind', *cls.FIELDS})}")
    return cls(**_numbers({k: v for k, v in d.items() if k != "kind"}, cls.FIELDS, where))


def _workspace(d: Any) -> Workspace:
    """A :class:`Workspace` from plain data (metres, angles in degrees), every value checked:
    ``object_xyz`` and either the thesis's flat keys or a ``carrier`` list (one per camera)."""
    if not isinstance(d, dict):
        raise ValueError(f"workspace: expected a table, got {type(d).__name__}")
    allowed = {"object_xyz", "carrier", *_THESIS_KEYS}
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise ValueError(f"workspace: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    flat = sorted(set(d) & set(_THESIS_KEYS))
    if "carrier" in d and flat:
        raise ValueError(f"workspace: give the carriers as a 'carrier' list or the thesis rig's keys, not both "
                         f"({flat[0]} and carrier)")
    obj = _numbers({k: d[k] for k in ("object_xyz",) if k in d}, {"object_xyz": 3}, "workspace")
    try:
        if "carrier" in d:
            entries = d["carrier"]
            if not (isinstance(entries, list) and entries):
                raise ValueError(f"workspace carrier = {_short(entries)} must be a non-empty list of carriers "
                                 f"([[table.workspace.carrier]], one per camera)")
            carriers = tuple(_carrier(c, i) for i, c in enumerate(entries))
        else:
            kinds = (Gantry, Track)
            fields: list[dict[str, Any]] = [{}, {}]
            for key in flat:  # checked under the key the file used
                i, field = _THESIS_KEYS[key]
                (value,) = _numbers({key: d[key]}, {key: kinds[i].FIELDS[field]}, "workspace").values()
                fields[i][field.removesuffix("_deg")] = value
            carriers = (Gantry(**fields[0]), Track(**fields[1]))
        return Workspace(**obj, carriers=carriers)
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
