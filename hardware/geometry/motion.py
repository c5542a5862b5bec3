"""Travel times between camera positions: the motion model of motion-cost-aware
planning (``Recognizer(..., motion=...)``, ``docs/planners.md``).

The model, per camera ``i`` and pair of its positions ``v -> w``::

    T_i[v, w] = max( |dx| / s_lin, |dy| / s_lin, |dz| / s_lin,
                     |d pan_ptu| / s_ptu, |d tilt_ptu| / s_ptu )

every axis moves at once at its constant speed (no acceleration phase), so
the slowest axis sets the time.  ``dx, dy, dz`` are the changes of the eye
position in the table (appendix-C kinematics, :mod:`.kinematics`): camera 1's
gantry moves x and y (two motors, thesis §6.1; z is fixed), camera 2's track
moves y only (x and z are fixed, §6.2), so the unused axes contribute 0.
``pan_ptu, tilt_ptu`` are the pan-tilt unit's own angles for the line of
sight from that eye to the object (:func:`.kinematics.ptu_angles` with the
unit's mount): the PTU-D46's pan range is +/-159 deg, so it cannot take the
short way across +/-180 deg and the difference is taken without wrapping.

The cameras move in parallel (one controller ``MOVE`` drives the gantry and
the track, the PTUs are pointed together, ``docs/hardware.md``), so a change
of configuration takes ``max_i T_i[c_i, a_i]``.

The controller simulator (:mod:`..sim.controller_sim`) times a move by the
gantry's straight-line distance, ``hypot(dx, dy) / linear_speed``; the model
here treats the gantry's x and y as independent axes (thesis §6.1: one DC
motor and PID loop each), which is at most sqrt(2) shorter on a diagonal.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from ...kernels.config_grid import ConfigGrid
from .kinematics import DEFAULT_MOUNTS, default_mounts, ptu_angles
from .positions import CameraTable

__all__ = ["MotionSpeeds", "DEFAULT_PTU_DEG_S", "DEFAULT_LINEAR_M_S", "camera_travel_times",
           "configuration_travel_times", "path_travel_s"]

#: Pan-tilt speed, deg/s: the thesis's PTU-D46-17.5 move "with speed over
#: 300°/second" (§6.4).  A unit set slower (``[[ptu]] speed_deg_s``) is timed
#: at its own speed (:meth:`MotionSpeeds.from_config`).
DEFAULT_PTU_DEG_S = 300.0

#: Gantry and track speed, m/s.  The thesis gives no speed for them (§6.1-6.2
#: give only encoder resolutions and the 512 Hz control rate); 0.25 m/s is the
#: linear speed of the controller simulator (:class:`.ControllerSimulator`),
#: so simulated moves and planned travel times agree.  Set the real rig's
#: speeds in the rig file's ``[motion]`` table.
DEFAULT_LINEAR_M_S = 0.25


@dataclasses.dataclass(frozen=True)
class MotionSpeeds:
    """Axis speeds of the rig (the rig file's ``[motion]`` table).

    Attributes:
        gantry_m_s: camera 1's x-y gantry, each axis (m/s).
        track_m_s: camera 2's linear track (m/s).
        ptu_deg_s: pan and tilt of every pan-tilt unit (deg/s), unless
            ``ptu_deg_s_per_camera`` gives one per camera.
        ptu_deg_s_per_camera: optional per-camera PTU speeds (deg/s).
    """

    gantry_m_s: float = DEFAULT_LINEAR_M_S
    track_m_s: float = DEFAULT_LINEAR_M_S
    ptu_deg_s: float = DEFAULT_PTU_DEG_S
    ptu_deg_s_per_camera: tuple[float, ...] = ()

    def __post_init__(self):
        for name in ("gantry_m_s", "track_m_s", "ptu_deg_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} = {v!r} must be a speed > 0")
        for v in self.ptu_deg_s_per_camera:
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"ptu_deg_s_per_camera = {self.ptu_deg_s_per_camera!r}: every speed must be > 0")

    def linear(self, camera: int, kind: str | None = None) -> float:
        """The linear axes' speed of ``camera``'s carrier of ``kind`` (``"gantry"``:
        :attr:`gantry_m_s`, ``"track"``: :attr:`track_m_s`); without ``kind``, as on
        the thesis rig: camera 0 rides the gantry, any other a track."""
        kind = kind or ("gantry" if camera == 0 else "track")
        speed = getattr(self, f"{kind}_m_s", None)
        if speed is None:
            raise ValueError(f"camera {camera + 1}: no [motion] speed for a carrier of kind {kind!r}")
        return speed

    def ptu(self, camera: int) -> float:
        if self.ptu_deg_s_per_camera:
            return float(self.ptu_deg_s_per_camera[camera])
        return self.ptu_deg_s

    @classmethod
    def from_config(cls, config) -> "MotionSpeeds":
        """The speeds of a :class:`~..physical.config.RigConfig`: its ``[motion]`` table,
        with each ``[[ptu]] speed_deg_s`` that is set (the unit runs at it)."""
        base = config.motion
        n = config.table.n_cameras
        own = [config.ptu(i).speed_deg_s for i in range(n)]
        if all(s is None for s in own):
            return base
        return dataclasses.replace(base, ptu_deg_s_per_camera=tuple(float(s) if s is not None else base.ptu(i)
                                                                    for i, s in enumerate(own)))


def camera_travel_times(table: CameraTable, speeds: MotionSpeeds | None = None,
                        mounts: Sequence | None = None) -> tuple[np.ndarray, ...]:
    """Per camera ``i``, ``[V_i, V_i]`` seconds to move from position ``v``
    (row) to ``w`` (column) (module doc); the diagonal is 0.

    ``mounts``: one PTU mount per camera (``pan_zero_deg``, ``tilt_zero_deg``,
    ``pan_sign``; default: each carrier's :func:`~.kinematics.default_mounts`,
    the angles of :func:`~..physical.config.default_mounts`; for a table of more
    cameras than carriers :data:`~.kinematics.DEFAULT_MOUNTS`)."""
    speeds = speeds or MotionSpeeds()
    n, carriers = table.n_cameras, table.workspace.carriers
    if mounts is None:
        mounts = default_mounts(table.workspace, n) if n <= len(carriers) else DEFAULT_MOUNTS[:n]
    mounts = tuple(mounts)
    if len(mounts) != n:
        raise ValueError(f"{len(mounts)} PTU mounts for {n} cameras")
    target = table.workspace.object_xyz
    out = []
    for i, views in enumerate(table.views):
        eye = np.array([v.eye for v in views], float)  # [V, 3]
        ang = np.array([ptu_angles(v.eye, target, mounts[i]) for v in views], float)  # [V, 2] degrees
        kind = carriers[i].kind if i < len(carriers) else None
        linear = np.abs(eye[:, None, :] - eye[None, :, :]).max(-1) / speeds.linear(i, kind)
        angular = np.abs(ang[:, None, :] - ang[None, :, :]).max(-1) / speeds.ptu(i)
        out.append(np.maximum(linear, angular))
    return tuple(out)


def configuration_travel_times(times: Sequence[np.ndarray]) -> np.ndarray:
    """``[A, A]``: seconds from configuration ``a`` (row) to ``b`` (column),
    ``max_i T_i[a_i, b_i]`` (the cameras move in parallel); configurations
    are flat row-major indices as everywhere (:class:`~jaxrecog.kernels.config_grid.ConfigGrid`)."""
    grid = ConfigGrid(tuple(t.shape[0] for t in times))
    start = grid.configurations()  # [A, n]: row a's configuration
    rows = [t[start[:, i]] for i, t in enumerate(times)]  # [A, V_i]: from a's position of camera i
    return grid.combine(np.maximum, rows, np.zeros((grid.size,) + grid.positions))


def path_travel_s(times: Sequence[np.ndarray], configurations: Sequence[Sequence[int]]) -> float:
    """Seconds to visit ``configurations`` in order, starting at the first
    (the trial's initial configuration costs nothing)."""
    total = 0.0
    for a, b in zip(configurations, configurations[1:]):
        total += max(float(t[int(u), int(v)]) for t, u, v in zip(times, a, b))
    return total
