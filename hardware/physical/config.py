"""Rig description files (TOML, read with ``tomllib``) -> configuration objects.

A file describes one rig: which kind (``"hardware"`` for a real rig,
``"simulated"`` for the device simulators), the configuration table, the
controller's UDP address, one ``[[ptu]]`` and one ``[[camera]]`` per camera
(camera 1 first).  ``docs/hardware.md`` documents every key;
``examples/simulated_rig.toml`` is a complete example.  Unknown keys are
errors (a typo must not silently fall back to a default), and so is every
value of the wrong type or outside its range (:data:`_RULES`: a timeout of
-1 or ``inf``, a probability of 2): the message names the file, the section
and the key, in the file's units.  Checked when the file is loaded, not when
the rig first needs them: two pan-tilt units on one serial port, a table
position outside the workspace or a pan-tilt unit's range, the shared key.
Every problem is a :class:`ConfigError` -- nothing else leaves
:func:`load_config`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
import urllib.parse
from typing import Any

from ..._files import TextFileError, read_text
from ...problems import one_line
from ..devices.datagram import MAX_CAMERAS, VERSION, SharedKey
from ..devices.pan_tilt import DEFAULT_PAN_TILT, pan_tilt_driver
from ..geometry.kinematics import Gantry, Track, Workspace, default_mounts as kinematic_mounts, ptu_angles
from ..geometry.motion import MotionSpeeds
from ..geometry.positions import CameraTable, default_table, entry_text
from ..sim.controller_sim import LinkFaults

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

    ``driver`` names the pan-tilt driver (:mod:`..devices.pan_tilt`; default the
    PTU-D46).  When the unit's device disappears, the rig tries ``port``
    and every path matching ``reconnect_glob`` (e.g.
    ``"/dev/serial/by-id/usb-FTDI_*"``) with a bounded backoff for
    ``reconnect_s`` seconds (0: fail at once); ``homing_timeout_s`` bounds
    the wait for a unit that is still homing after a reset or power-up, and
    ``max_motion_s`` the wait for one motion, whatever distance and speed the
    unit reports.
    ``pan_range_deg`` / ``tilt_range_deg`` ([min, max], the unit's own angles)
    bound what the table may ask of it, checked when the file is loaded;
    default: the driver's ``nominal_range_deg`` (the PTU-D46-17.5's +/-158.9
    deg pan, -46.6..+31.1 deg tilt).
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
    max_motion_s: float = 120.0  # the PTU-D46 driver's MAX_MOTION_S
    pan_range_deg: tuple[float, float] | None = None
    tilt_range_deg: tuple[float, float] | None = None


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """``kind = "video"``: ``source`` is a device index, file, URL or ``%d`` pattern;
    ``kind = "sequence"``: a folder or glob of image files.  A video camera that
    delivers no frame at all during a capture is reopened for up to
    ``reconnect_s`` seconds (0: fail at once); one read that does not return
    within ``read_timeout_s`` seconds counts as no frame (the device is reopened)."""

    source: int | str = 0
    kind: str = "video"
    retries: int = 3
    black_level: int = 0
    reconnect_s: float = 5.0
    read_timeout_s: float = 5.0  # the camera module's READ_TIMEOUT_S


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """``max_motion_s`` bounds how long ``MOVING`` replies may extend the wait for one move.

    ``protocol_version``: 4 (``docs/protocol.md``), or 3 / 2 / 1 for a controller
    that speaks only that version (2 and 1: the thesis rig's two cameras).  A shared key (HMAC over every datagram) is read
    from the file ``key_file`` (relative to the rig file) or the environment
    variable ``key_env``, when the rig file is loaded, into ``key`` (hidden
    from ``repr``; never a key in the rig file itself)."""

    host: str = "127.0.0.1"
    port: int = 0
    timeout_s: float = 0.25
    retries: int = 5
    max_motion_s: float = 600.0
    protocol_version: int = VERSION
    key_file: str = ""
    key_env: str = ""
    key: SharedKey | None = dataclasses.field(default=None, repr=False)


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
    #: axis speeds for planned travel times (``[motion]``; :mod:`..geometry.motion`)
    motion: MotionSpeeds = MotionSpeeds()

    @classmethod
    def from_dict(cls, d: dict[str, Any], base_dir: str | os.PathLike = ".") -> "RigConfig":
        """Build from parsed TOML; relative camera paths are resolved against ``base_dir``."""
        top = _fields(d, "rig file", {"kind", "image_shape", "n_poses", "table", "controller", "ptu", "camera", "simulation",
                                         "motion"})
        kind = top.get("kind", "hardware")
        if kind not in KINDS:
            raise ConfigError(f"kind = {_short(kind)}: must be one of {KINDS}")
        try:
            table = CameraTable.from_dict(top["table"]) if "table" in top else default_table()
        except (TypeError, ValueError) as e:
            raise ConfigError(f"[table]: {e}") from e
        shape = top.get("image_shape", [120, 160])
        if not (isinstance(shape, list) and len(shape) == 2
                and all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= 65535 for v in shape)):
            raise ConfigError(f"image_shape = {_short(shape)}: must be [height, width], integers in 1..65535")
        n_poses = top.get("n_poses", 4)
        if not isinstance(n_poses, int) or isinstance(n_poses, bool) or not 1 <= n_poses <= 1_000_000:
            raise ConfigError(f"n_poses = {_short(n_poses)}: must be an integer in 1..1000000")
        controller = _build(ControllerConfig, top.get("controller", {}), "[controller]", key=None)
        controller = dataclasses.replace(controller, key=_shared_key(controller, base_dir))
        ptus = tuple(_build(PTUConfig, p, f"[[ptu]] #{i + 1}") for i, p in enumerate(_list(top, "ptu")))
        cams = []
        for i, c in enumerate(_list(top, "camera")):
            cam = _build(CameraConfig, c, f"[[camera]] #{i + 1}")
            if cam.kind not in ("video", "sequence"):
                raise ConfigError(f"[[camera]] #{i + 1}: kind = {_short(cam.kind)} must be 'video' or 'sequence'")
            if isinstance(cam.source, str) and not _is_url(cam.source) and not os.path.isabs(cam.source):
                cam = dataclasses.replace(cam, source=os.path.join(os.fspath(base_dir), cam.source))
            cams.append(cam)
        for i, p in enumerate(ptus):
            where = f"[[ptu]] #{i + 1}"
            try:
                pan_tilt_driver(p.driver)
            except (KeyError, ImportError) as e:
                raise ConfigError(f"{where}: driver = {_short(p.driver)}: {e.args[0]}") from e
        sim_d = _fields(top.get("simulation", {}), "[simulation]", {f.name for f in dataclasses.fields(SimulationConfig)})
        sim_d = dict(sim_d)
        faults = _build(LinkFaults, sim_d.pop("faults", {}), "[simulation.faults]")
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
        if self.controller.key is not None and self.controller.protocol_version == 1:
            raise ConfigError("[controller]: a shared key (key_file / key_env) needs protocol_version = 2 or later: "
                              "version 1 carries no HMAC tag")
        if not 1 <= n <= MAX_CAMERAS:
            raise ConfigError(f"[table] describes {n} cameras; the controller protocol drives 1 to {MAX_CAMERAS}")
        version = self.controller.protocol_version
        if version <= 2 and [type(c) for c in self.table.carriers] != [Gantry, Track][:n]:
            kinds = ", ".join(c.kind for c in self.table.carriers)
            raise ConfigError(f"[controller] protocol_version = {version} moves camera 1 on a gantry and camera 2 on a "
                              f"track; this table's cameras ride {kinds}: set protocol_version = 3 or 4")
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
        self._check_ports()
        self._check_ranges()

    def _check_ports(self) -> None:
        """Every pan-tilt unit on its own serial port (two on one: one camera never points)."""
        seen: dict[str, int] = {}
        for i, p in enumerate(self.ptus):
            if not p.port:
                continue
            dev = _device(p.port)
            if dev in seen:
                j = seen[dev]
                same = f"port = {p.port!r}" if p.port == self.ptus[j].port else \
                    f"ports {self.ptus[j].port!r} and {p.port!r} (the same device)"
                raise ConfigError(f"[[ptu]] #{j + 1} and [[ptu]] #{i + 1} both have {same}: "
                                  f"each pan-tilt unit needs its own serial port")
            seen[dev] = i

    def _check_ranges(self) -> None:
        """Every table position within its pan-tilt unit's range (degrees, the unit's angles)."""
        ws = self.table.workspace
        for i, views in enumerate(self.table.views):
            mount = self.ptu(i)
            ranges = _ranges(mount)
            if ranges is None:
                continue
            bad = []
            for v, view in enumerate(views):
                angles = ptu_angles(view.eye, ws.object_xyz, mount)
                for axis, a, (lo, hi) in zip(("pan", "tilt"), angles, ranges):
                    if not lo - 1e-9 <= a <= hi + 1e-9:
                        bad.append((v, view, axis, a, lo, hi))
                        break
            if bad:
                v, view, axis, a, lo, hi = bad[0]
                where = f"[[ptu]] #{i + 1}" if self.ptus else f"the default mount of camera {i}"
                at = entry_text(self.table.carriers[i], view)
                more = f" (and {len(bad) - 1} more position(s))" if len(bad) > 1 else ""
                raise ConfigError(
                    f"[table] camera{i + 1}[{v}] = {at} deg: {where} would have to {axis} to {a:.4g} deg, outside "
                    f"its range [{lo:.4g}, {hi:.4g}] deg{more}; change the mount (pan_zero_deg, tilt_zero_deg, "
                    f"pan_sign) or, if the unit really goes that far, {axis}_range_deg")

    def travel_times(self):
        """Per camera ``[V_i, V_i]`` travel seconds between its positions
        (:func:`..geometry.motion.camera_travel_times` with this rig's table, mounts and
        speeds)."""
        from ..geometry.motion import camera_travel_times

        return camera_travel_times(self.table, MotionSpeeds.from_config(self),
                                   tuple(self.ptu(i) for i in range(self.table.n_cameras)))

    def ptu(self, camera: int) -> PTUConfig:
        """The PTU entry of ``camera`` (defaults when a simulated rig leaves them out)."""
        if self.ptus:
            return self.ptus[camera]
        return default_mounts(self.table.n_cameras, self.table.workspace)[camera]


def default_mounts(n_cameras: int, workspace: Workspace | None = None) -> tuple[PTUConfig, ...]:
    """PTU entries with each carrier's default mount (:func:`..geometry.kinematics.default_mounts`):
    for the thesis rig the mounts that keep the default table inside the PTU-D46-17.5
    limits (+/-159 deg pan, -46.6..+31.1 deg tilt): camera 1 looks along azimuth
    -22.5 deg, 45 deg down at (0, 0); camera 2 along azimuth -90 deg (towards -x),
    level, pan mirrored."""
    return tuple(PTUConfig(pan_zero_deg=m.pan_zero_deg, tilt_zero_deg=m.tilt_zero_deg, pan_sign=m.pan_sign)
                 for m in kinematic_mounts(workspace or Workspace(), n_cameras))


def load_config(path: str | os.PathLike) -> RigConfig:
    """Read a TOML rig description (see ``docs/hardware.md``).

    Raises:
        ConfigError: for every problem (unreadable file, not TOML, a bad key or
            value), one line naming the file and the key.
    """
    name = os.fspath(path)
    try:  # a regular UTF-8 file of at most 1 MiB: /dev/zero or a FIFO is refused before a byte is read
        d = tomllib.loads(read_text(path, "rig file"))
    except TextFileError as e:  # every rig-file error starts with the file's name
        raise ConfigError(f"{name}: {e}") from None
    except OSError as e:
        raise ConfigError(f"{name}: cannot read the rig file: {e.strerror or e}") from e
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ConfigError(f"{name}: not valid TOML: {one_line(e)}") from e
    except RecursionError as e:
        raise ConfigError(f"{name}: not valid TOML: nested too deeply") from e
    try:
        return RigConfig.from_dict(d, base_dir=os.path.dirname(os.path.abspath(path)))
    except ConfigError as e:
        raise ConfigError(one_line(f"{name}: {e}", cap=600)) from e


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


def _short(v: Any) -> str:
    """``repr(v)``, cut so a 10 kB value cannot blow up a message."""
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def _fmt(v: float) -> str:
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else f"{v:g}"


@dataclasses.dataclass(frozen=True)
class _Number:
    """A number in [lo, hi] (``lo_open``: > lo), an integer if ``integer``."""

    lo: float
    hi: float
    lo_open: bool = False
    integer: bool = False
    unit: str = ""

    def text(self) -> str:
        kind = "an integer" if self.integer else "a number"
        return f"{kind} {'>' if self.lo_open else '>='} {_fmt(self.lo)} and <= {_fmt(self.hi)}{self.unit}"

    def ok(self, v: Any) -> bool:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (self.integer and not isinstance(v, int)):
            return False
        return math.isfinite(v) and (v > self.lo if self.lo_open else v >= self.lo) and v <= self.hi


@dataclasses.dataclass(frozen=True)
class _Choice:
    values: tuple

    def text(self) -> str:
        return "one of " + ", ".join(map(repr, self.values))

    def ok(self, v: Any) -> bool:
        return not isinstance(v, bool) and type(v) in (int, str) and v in self.values


@dataclasses.dataclass(frozen=True)
class _Range:
    """``[min, max]``, two numbers with ``lo <= min < max <= hi``."""

    lo: float
    hi: float
    strict: bool = True
    unit: str = ""

    def text(self) -> str:
        rel = "<" if self.strict else "<="
        return f"[min, max] with {_fmt(self.lo)} <= min {rel} max <= {_fmt(self.hi)}{self.unit}"

    def ok(self, v: Any) -> bool:
        num = _Number(self.lo, self.hi)
        return (isinstance(v, (list, tuple)) and len(v) == 2 and all(num.ok(x) for x in v)
                and (v[0] < v[1] if self.strict else v[0] <= v[1]))


_S = " seconds"
_SECONDS = _Number(0, 3600, lo_open=True, unit=_S)
_LONG_SECONDS = _Number(0, 86400, lo_open=True, unit=_S)
_PROBABILITY = _Number(0, 1)
#: what each key of each section may hold (keys without a rule: their default's type)
_RULES: dict[type, dict[str, Any]] = {
    ControllerConfig: {
        "port": _Number(0, 65535, integer=True), "timeout_s": _SECONDS, "retries": _Number(0, 10_000, integer=True),
        "max_motion_s": _LONG_SECONDS, "protocol_version": _Choice((1, 2, 3, 4)),
    },
    PTUConfig: {
        "baudrate": _Number(0, 10_000_000, lo_open=True, integer=True), "timeout_s": _SECONDS,
        "pan_zero_deg": _Number(-360, 360, unit=" degrees"), "tilt_zero_deg": _Number(-180, 180, unit=" degrees"),
        "pan_sign": _Choice((1, -1)), "speed_deg_s": _Number(0, 100_000, lo_open=True, unit=" degrees/s"),
        "reconnect_s": _Number(0, 86400, unit=_S), "homing_timeout_s": _LONG_SECONDS,
        "max_motion_s": _SECONDS, "pan_range_deg": _Range(-360, 360, unit=" degrees"), "tilt_range_deg": _Range(-180, 180, unit=" degrees"),
    },
    CameraConfig: {
        "retries": _Number(0, 1000, integer=True), "black_level": _Number(0, 255, integer=True),
        "reconnect_s": _Number(0, 86400, unit=_S), "read_timeout_s": _SECONDS,
    },
    SimulationConfig: {"seed": _Number(-2**63, 2**63 - 1, integer=True), "time_scale": _Number(0, 1000)},
    LinkFaults: {
        "loss": _PROBABILITY, "duplicate": _PROBABILITY, "reorder": _PROBABILITY, "corrupt": _PROBABILITY,
        "delay_s": _Range(0, 60, strict=False, unit=_S), "reorder_delay_s": _Number(0, 60, unit=_S),
    },
    MotionSpeeds: {
        "gantry_m_s": _Number(0, 1000, lo_open=True, unit=" m/s"), "track_m_s": _Number(0, 1000, lo_open=True, unit=" m/s"),
        "ptu_deg_s": _Number(0, 100_000, lo_open=True, unit=" degrees/s"),
    },
}


def _build(cls, d: Any, where: str, **extra):
    names = {f.name: f for f in dataclasses.fields(cls)}
    d = dict(_fields(d, where, set(names) - set(extra)))
    rules = _RULES.get(cls, {})
    for k, v in d.items():
        rule = rules.get(k)
        if rule is not None:
            if not rule.ok(v):
                raise ConfigError(f"{where}: {k} = {_short(v)} must be {rule.text()}")
            if isinstance(rule, _Range):
                d[k] = (float(v[0]), float(v[1]))
            continue
        default = names[k].default
        if k == "source":  # a camera: a device index or a path / URL / pattern
            if not (isinstance(v, str) or (isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 2**31)):
                raise ConfigError(f"{where}: {k} = {_short(v)} must be a device index (an integer >= 0) or a string")
        elif isinstance(default, bool) and not isinstance(v, bool):
            raise ConfigError(f"{where}: {k} = {_short(v)} must be true or false")
        elif isinstance(default, (int, float)) and not isinstance(default, bool):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{where}: {k} = {_short(v)} must be a finite number")
        elif isinstance(default, str) and not isinstance(v, str):
            raise ConfigError(f"{where}: {k} = {_short(v)} must be a string")
    try:
        return cls(**d, **extra)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{where}: {e}") from e


def _shared_key(c: ControllerConfig, base_dir: str | os.PathLike) -> SharedKey | None:
    """The key ``key_file`` / ``key_env`` name (None without either); errors never show it."""
    if c.key_file and c.key_env:
        raise ConfigError("[controller]: give key_file or key_env, not both")
    try:
        if c.key_file:
            path = os.path.join(os.fspath(base_dir), os.path.expanduser(c.key_file))
            try:
                return SharedKey.from_file(path)
            except OSError as e:
                raise ValueError(f"cannot read it: {e.strerror or e}") from None
        if c.key_env:
            return SharedKey.from_env(c.key_env)
    except ValueError as e:
        key = f"key_file = {c.key_file!r}" if c.key_file else f"key_env = {c.key_env!r}"
        raise ConfigError(f"[controller]: {key}: {e}") from None
    return None


#: pyserial URLs that open the port written after them, adding something (a log, another class)
_WRAPPING_URLS = ("spy", "alt")
#: pyserial URLs of a serial port served over the network at HOST:PORT
_NETWORK_URLS = ("rfc2217", "socket")


def _device(port: str) -> str:
    """What a serial port names, for comparing two ports: a local path resolved through its
    links (``/dev/serial/by-id/...`` -> ``/dev/ttyUSB0``); ``spy://`` and ``alt://`` stripped
    to the port they wrap (``spy:///dev/ttyUSB0`` is ``/dev/ttyUSB0``); ``rfc2217://`` and
    ``socket://`` as scheme, lowercased host and port, options dropped (``rfc2217://HOST:7001``
    is ``rfc2217://host:7001``); any other URL as written, scheme lowercased."""
    scheme, sep, rest = port.partition("://")
    if not sep:
        try:
            return os.path.realpath(port)
        except (OSError, ValueError):
            return port
    scheme = scheme.lower()
    rest = rest.split("?", 1)[0]  # pyserial's options (?logging=debug, ?class=...) name no other device
    if scheme in _WRAPPING_URLS:
        return _device(rest)
    if scheme in _NETWORK_URLS:
        try:
            parts = urllib.parse.urlsplit("//" + rest.split("/", 1)[0])
            host, number = parts.hostname, parts.port
        except ValueError:
            host = number = None
        if host:
            host = host.rstrip(".")
            return f"{scheme}://{f'[{host}]' if ':' in host else host}:{number}"
    return f"{scheme}://{rest}"


def _ranges(mount: PTUConfig) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """(pan, tilt) ranges in degrees of a mount: its own keys, else its driver's nominal ones."""
    nominal = None
    try:
        nominal = getattr(pan_tilt_driver(mount.driver), "nominal_range_deg", None)
    except (KeyError, ImportError):
        pass
    pan = mount.pan_range_deg or (nominal[0] if nominal else None)
    tilt = mount.tilt_range_deg or (nominal[1] if nominal else None)
    if pan is None and tilt is None:
        return None
    return (pan or (-math.inf, math.inf), tilt or (-math.inf, math.inf))
