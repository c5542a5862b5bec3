"""Rig description files (TOML, read with ``tomllib``) -> configuration objects.

A file describes one rig: which kind (``"hardware"`` for a real rig,
``"simulated"`` for the device simulators), the configuration table, the
controller's UDP address, one ``[[ptu]]`` and one ``[[camera]]`` per camera
(camera 1 first).  ``docs/hardware.md`` documents every key;
``examples/simulated_rig.toml`` is a complete example.  Unknown keys are
errors (a typo must not silently fall back to a default).
"""

from __future__ import annotations

import dataclasses
import os
import tomllib
from typing import Any

from .controller_sim import LinkFaults
from .motion import MotionSpeeds
from .pan_tilt import DEFAULT_PAN_TILT, pan_tilt_driver
from .positions import CameraTable, default_table

__all__ = [
    "ConfigError",
    "PTUConfig",
    "CameraConfig",
    "ControllerConfig",
    "SimulationConfig",
    "RigConfig",
    "load_config",
]

KINDS = ("hardware", "simulated")


class ConfigError(ValueError):
    """A rig description is invalid; the message names the file section and key."""


@dataclasses.dataclass(frozen=True)
class PTUConfig:
    """One pan-tilt unit and how it is mounted.

    The unit's pan/tilt (degrees) for a line of sight with azimuth ``az``
    (from +y towards +x, the thesis's ``tan(theta) = dx/dy``) and elevation
    ``el`` (up positive) are ``pan = pan_sign * wrap(az - pan_zero_deg)`` and
    ``tilt = el - tilt_zero_deg``: ``pan_zero_deg`` / ``tilt_zero_deg`` are the
    azimuth / elevation the camera looks along at PTU position (0, 0).

    ``driver`` names the pan-tilt driver (:mod:`.pan_tilt`; default the
    PTU-D46).  When the unit's device disappears, the rig tries ``port``
    and every path matching ``reconnect_glob`` (e.g.
    ``"/dev/serial/by-id/usb-FTDI_*"``) with a bounded backoff for
    ``reconnect_s`` seconds (0: fail at once); ``homing_timeout_s`` bounds
    the wait for a unit that is still homing after a reset or power-up.
    """

    port: str = ""
    baudrate: int = 9600
    timeout_s: float = 0.5
    pan_zero_deg: float = 0.0
    tilt_zero_deg: float = 0.0
    pan_sign: int = 1
    speed_deg_s: float | None = None
    driver: str = DEFAULT_PAN_TILT
    reconnect_s: float = 10.0
    reconnect_glob: str = ""
    homing_timeout_s: float = 30.0


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """``kind = "video"``: ``source`` is a device index, file, URL or ``%d`` pattern;
    ``kind = "sequence"``: a folder or glob of image files."""

    source: int | str = 0
    kind: str = "video"
    retries: int = 3
    black_level: int = 0


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """``max_motion_s`` bounds how long ``MOVING`` replies may extend the wait for one move."""

    host: str = "127.0.0.1"
    port: int = 0
    timeout_s: float = 0.25
    retries: int = 5
    max_motion_s: float = 600.0


@dataclasses.dataclass(frozen=True)
class SimulationConfig:
    seed: int = 0
    time_scale: float = 0.001
    faults: LinkFaults = dataclasses.field(default_factory=LinkFaults)


@dataclasses.dataclass(frozen=True)
class RigConfig:
    kind: str
    table: CameraTable
    image_shape: tuple[int, int] = (120, 160)
    n_poses: int = 4
    controller: ControllerConfig = ControllerConfig()
    ptus: tuple[PTUConfig, ...] = ()
    cameras: tuple[CameraConfig, ...] = ()
    simulation: SimulationConfig = SimulationConfig()
    #: axis speeds for planned travel times (``[motion]``; :mod:`.motion`)
    motion: MotionSpeeds = MotionSpeeds()

    @classmethod
    def from_dict(cls, d: dict[str, Any], base_dir: str | os.PathLike = ".") -> "RigConfig":
        """Build from parsed TOML; relative camera paths are resolved against ``base_dir``."""
        top = _fields(d, "rig file", {"kind", "image_shape", "n_poses", "table", "controller", "ptu", "camera", "simulation",
                                         "motion"})
        kind = top.get("kind", "hardware")
        if kind not in KINDS:
            raise ConfigError(f"kind = {kind!r}: must be one of {KINDS}")
        try:
            table = CameraTable.from_dict(top["table"]) if "table" in top else default_table()
        except (TypeError, ValueError) as e:
            raise ConfigError(f"[table]: {e}") from e
        shape = top.get("image_shape", [120, 160])
        if not (isinstance(shape, list) and len(shape) == 2 and all(isinstance(v, int) and v > 0 for v in shape)):
            raise ConfigError(f"image_shape = {shape!r}: must be [height, width], positive integers")
        n_poses = top.get("n_poses", 4)
        if not isinstance(n_poses, int) or n_poses < 1:
            raise ConfigError(f"n_poses = {n_poses!r}: must be a positive integer")
        controller = _build(ControllerConfig, top.get("controller", {}), "[controller]")
        ptus = tuple(_build(PTUConfig, p, f"[[ptu]] #{i + 1}") for i, p in enumerate(_list(top, "ptu")))
        cams = []
        for i, c in enumerate(_list(top, "camera")):
            cam = _build(CameraConfig, c, f"[[camera]] #{i + 1}")
            if cam.kind not in ("video", "sequence"):
                raise ConfigError(f"[[camera]] #{i + 1}: kind = {cam.kind!r} must be 'video' or 'sequence'")
            if isinstance(cam.source, str) and not _is_url(cam.source) and not os.path.isabs(cam.source):
                cam = dataclasses.replace(cam, source=os.path.join(os.fspath(base_dir), cam.source))
            cams.append(cam)
        for i, p in enumerate(ptus):
            where = f"[[ptu]] #{i + 1}"
            if p.pan_sign not in (1, -1):
                raise ConfigError(f"{where}: pan_sign = {p.pan_sign!r} must be 1 or -1")
            if not p.reconnect_s >= 0:
                raise ConfigError(f"{where}: reconnect_s = {p.reconnect_s!r} must be >= 0 seconds")
            if not p.homing_timeout_s > 0:
                raise ConfigError(f"{where}: homing_timeout_s = {p.homing_timeout_s!r} must be > 0 seconds")
            try:
                pan_tilt_driver(p.driver)
            except (KeyError, ImportError) as e:
                raise ConfigError(f"{where}: driver = {p.driver!r}: {e.args[0]}") from e
        sim_d = dict(top.get("simulation", {}))
        faults_d = sim_d.pop("faults", {})
        faults_d = {k: tuple(v) if isinstance(v, list) else v for k, v in faults_d.items()}
        faults = _build(LinkFaults, faults_d, "[simulation.faults]")
        sim = _build(SimulationConfig, sim_d, "[simulation]", faults=faults)
        motion = _build(MotionSpeeds, top.get("motion", {}), "[motion]", ptu_deg_s_per_camera=())
        cfg = cls(kind, table, (shape[0], shape[1]), n_poses, controller, ptus, tuple(cams), sim, motion)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        """Check that the parts fit together (counts, the controller address)."""
        n = self.table.n_cameras
        if not self.controller.max_motion_s > 0:
            raise ConfigError(f"[controller] max_motion_s = {self.controller.max_motion_s!r} must be > 0 seconds")
        if n not in (1, 2):
            raise ConfigError(f"[table] describes {n} cameras; the controller protocol drives 1 or 2")
        if self.kind == "hardware":
            if len(self.ptus) != n:
                raise ConfigError(f"{len(self.ptus)} [[ptu]] entries for {n} cameras: give one per camera")
            if len(self.cameras) != n:
                raise ConfigError(f"{len(self.cameras)} [[camera]] entries for {n} cameras: give one per camera")
            if not self.controller.port:
                raise ConfigError("[controller] port must be set for a hardware rig")
            for i, p in enumerate(self.ptus):
                if not p.port:
                    raise ConfigError(f"[[ptu]] #{i + 1}: port must be set for a hardware rig")
        elif self.ptus and len(self.ptus) != n:
            raise ConfigError(f"{len(self.ptus)} [[ptu]] entries for {n} cameras: give one per camera or none")

    def travel_times(self):
        """Per camera ``[V_i, V_i]`` travel seconds between its positions
        (:func:`.motion.camera_travel_times` with this rig's table, mounts and
        speeds)."""
        from .motion import camera_travel_times

        return camera_travel_times(self.table, MotionSpeeds.from_config(self),
                                   tuple(self.ptu(i) for i in range(self.table.n_cameras)))

    def ptu(self, camera: int) -> PTUConfig:
        """The PTU entry of ``camera`` (defaults when a simulated rig leaves them out)."""
        return self.ptus[camera] if self.ptus else default_mounts(self.table.n_cameras)[camera]


def default_mounts(n_cameras: int) -> tuple[PTUConfig, ...]:
    """Mounts that keep the default table inside the PTU-D46-17.5 limits (+/-159 deg pan,
    -46.6..+31.1 deg tilt): camera 1 looks along azimuth -22.5 deg, 45 deg down at
    (0, 0); camera 2 along azimuth -90 deg (towards -x), level, pan mirrored."""
    mounts = (PTUConfig(pan_zero_deg=-22.5, tilt_zero_deg=-45.0), PTUConfig(pan_zero_deg=-90.0, pan_sign=-1))
    return mounts[:n_cameras]


def load_config(path: str | os.PathLike) -> RigConfig:
    """Read a TOML rig description (see ``docs/hardware.md``)."""
    try:
        with open(path, "rb") as f:
            d = tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{os.fspath(path)}: not valid TOML: {e}") from e
    try:
        return RigConfig.from_dict(d, base_dir=os.path.dirname(os.path.abspath(path)))
    except ConfigError as e:
        raise ConfigError(f"{os.fspath(path)}: {e}") from e


# ---------------------------------------------------------------- helpers
def _is_url(s: str) -> bool:
    return "://" in s or "%" in s


def _fields(d: Any, where: str, allowed: set[str]) -> dict[str, Any]:
    if not isinstance(d, dict):
        raise ConfigError(f"{where}: expected a table, got {type(d).__name__}")
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    return d


def _list(d: dict[str, Any], key: str) -> list:
    v = d.get(key, [])
    if not isinstance(v, list):
        raise ConfigError(f"{key}: expected an array of tables ([[{key}]]), got {type(v).__name__}")
    return v


def _build(cls, d: Any, where: str, **extra):
    names = {f.name: f for f in dataclasses.fields(cls)}
    d = _fields(d, where, set(names) - set(extra))
    for k, v in d.items():
        default = names[k].default
        if isinstance(default, bool) and not isinstance(v, bool):
            raise ConfigError(f"{where}: {k} = {v!r} must be true or false")
        if isinstance(default, (int, float)) and not isinstance(default, bool):
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                if not (k == "source" and isinstance(v, str)):
                    raise ConfigError(f"{where}: {k} = {v!r} must be a number")
        if isinstance(default, str) and not isinstance(v, str):
            raise ConfigError(f"{where}: {k} = {v!r} must be a string")
    try:
        return cls(**d, **extra)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from e
