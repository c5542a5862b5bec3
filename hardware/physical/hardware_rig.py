"""The thesis's physical rig behind the ``Rig`` interface, and its simulated twin.

:class:`HardwareRig` (thesis ch. 6):

* ``move(configuration)`` looks up the planner angles of each camera's
  position in the :class:`..geometry.positions.CameraTable`, sends every camera's
  pan and tilt and the turn-table angle to the motion controller over UDP
  (:class:`..devices.udp_link.ControllerLink`), waits for ``IN_POSITION`` (the capture
  signal, §6.6), then points each pan-tilt unit (a :class:`..devices.pan_tilt.PanTilt`,
  by default :class:`..devices.pan_tilt_drivers.ptu_d46.PTU`) from the *achieved*
  camera position (each carrier's, as the controller reports it) at the object:
  ``az = atan2(dx, dy)``, ``el = atan2(dz, hypot(dx, dy))`` with
  ``d = object - eye``, turned into PTU angles by the mount
  (:class:`.config.PTUConfig`).
* ``capture()`` reads one frame per camera (:mod:`..devices.camera`), only after the rig
  reported in position.
* ``reset(object, pose)`` turns the turn-table to ``360 deg * pose / n_poses``;
  placing the object is a person's job on a real rig (``on_reset`` callback).

A pan-tilt unit whose device disappears during a move (USB unplug, power
cycle: :class:`..devices.pan_tilt.PanTiltConnectionError`) is reconnected: the rig tries
its ``port`` and the paths matching its ``reconnect_glob`` (not those of the
other units) with a backoff from ``RECONNECT_FIRST_DELAY_S`` doubling up to
``RECONNECT_MAX_DELAY_S``, for at most the unit's ``reconnect_s``
(``[[ptu]]`` key) plus the attempt in progress; the driver re-reads the unit
(resolution, limits, axes; it waits for a homing unit) and the rig re-applies
the speed and repeats the interrupted pointing once.  Each success is logged
and recorded in :attr:`HardwareRig.reconnects`; a unit that is not back in
time, or is lost again in the repeat, fails the move with one ``RigError``.
A camera that delivers no frame at all during ``capture()``
(:class:`..devices.camera.CameraLostError`: unplugged, stream dropped) is reopened
the same way for up to its ``reconnect_s`` (``[[camera]]`` key) and read
again; that too is recorded in :attr:`HardwareRig.reconnects`.

:class:`SimulatedHardwareRig` runs the same code path against the device
simulators (:class:`..sim.ptu_sim.PTUSimulator` on ptys,
:class:`..sim.controller_sim.ControllerSimulator` on 127.0.0.1) and renders each
camera's image with a renderer (duck-typed like ``SyntheticRig``:
``reset(object, pose, occluders)`` and ``render_at(camera, eye) -> (uint8 image,
occluded fraction)``) at the eye position the controller reported, after
checking that the simulated PTU really points at the object.
"""

from __future__ import annotations

import dataclasses
import glob
import logging
import math
import time
from typing import Any, Callable, Protocol, Sequence, runtime_checkable

import numpy as np

from ..devices.camera import CameraError, CameraLostError, ImageSequenceCamera, VideoCamera
from .config import CameraConfig, ConfigError, RigConfig, load_config
from ..geometry.kinematics import line_of_sight, ptu_angles  # re-exported: the angle functions used to live here
from ..devices.pan_tilt import PanTilt, PanTiltConnectionError, PanTiltError, open_pan_tilt
from ..geometry.positions import CameraTable
from ..rigs.rig import Capture, RigError
from ..devices.datagram import Move
from ..devices.udp_link import ControllerLink, LinkError, MoveResult

__all__ = [
    "HardwareRig",
    "SimulatedHardwareRig",
    "Reconnect",
    "Renderer",
    "ptu_angles",
    "line_of_sight",
    "rig_from_config",
]

log = logging.getLogger(__name__)

RECONNECT_FIRST_DELAY_S = 0.05
RECONNECT_MAX_DELAY_S = 0.5


@dataclasses.dataclass(frozen=True)
class Reconnect:
    """One device brought back: camera (0-based), the port (for a camera: its source)
    it came back on, seconds from the failure to the device answering again, attempts
    made, and which device of that camera (``"pan-tilt"`` or ``"camera"``)."""

    camera: int
    port: str
    seconds: float
    attempts: int
    device: str = "pan-tilt"


class _UnitLost(Exception):
    def __init__(self, camera: int, error: PanTiltConnectionError):
        self.camera, self.error = camera, error


@runtime_checkable  # a parameter's annotation: the test suite's type checker isinstance-checks it
class Renderer(Protocol):
    def reset(self, object: int, pose: int, occluders: Any = None) -> None: ...

    def render_at(self, camera: int, eye: tuple[float, float, float]) -> tuple[np.ndarray, float]: ...


def _check_config(configuration: Sequence[int], positions: tuple[int, ...]) -> tuple[int, ...]:
    try:
        cfg = tuple(int(v) for v in configuration)
    except (TypeError, ValueError) as e:
        raise RigError(f"configuration {configuration!r} is not a sequence of position indices") from e
    if len(cfg) != len(positions):
        raise RigError(f"configuration {cfg} has {len(cfg)} entries; the rig has {len(positions)} cameras")
    for i, (v, n) in enumerate(zip(cfg, positions)):
        if not 0 <= v < n:
            raise RigError(f"camera {i} position {v} is outside 0..{n - 1}")
    return cfg


class HardwareRig:
    """A real rig (n cameras on PTUs on their carriers, and a turn-table, on a UDP controller).

    Args:
        config: a :class:`.config.RigConfig` (``load_config("rig.toml")``) or a path.
        ptus, link, cameras: ready-made devices (built from ``config`` when omitted;
            the pan-tilt units with the driver each ``[[ptu]] driver`` key names).
        on_reset: called as ``on_reset(object, pose, occluders)`` before the
            turn-table turns (default: log a request to place the object).
    """

    def __init__(
        self,
        config: RigConfig | str,
        *,
        ptus: Sequence[PanTilt] | None = None,
        link: ControllerLink | None = None,
        cameras: Sequence[Any] | None = None,
        on_reset: Callable[[int, int, Any], None] | None = None,
    ):
        if not isinstance(config, RigConfig):
            config = load_config(config)
        self.config = config
        self.table: CameraTable = config.table
        n = self.table.n_cameras
        self._opened: list[Any] = []
        try:
            if link is None:
                c = config.controller
                link = ControllerLink((c.host, c.port), timeout=c.timeout_s, retries=c.retries,
                                      max_motion_s=c.max_motion_s, key=c.key, version=c.protocol_version)
                self._opened.append(link)
            self.link = link
            if ptus is None:
                ptus = []
                for i in range(n):
                    unit = open_pan_tilt(config.ptu(i))
                    self._opened.append(unit)
                    ptus.append(unit)
            self.ptus = list(ptus)
            for i, unit in enumerate(self.ptus):
                self._apply_speed(i, unit)
            if cameras is None:
                cameras = []
                for c in config.cameras:
                    common = dict(image_shape=config.image_shape, retries=c.retries, black_level=c.black_level)
                    if c.kind == "video":
                        cam = VideoCamera(c.source, read_timeout_s=c.read_timeout_s, **common)
                    else:
                        cam = ImageSequenceCamera(c.source, **common)
                    self._opened.append(cam)
                    cameras.append(cam)
            self.cameras = list(cameras)
        except (PanTiltError, LinkError, CameraError) as e:
            self.close()
            raise RigError(f"cannot open the rig: {e}") from e
        except BaseException:
            self.close()
            raise
        if len(self.ptus) != n:
            raise RigError(f"{len(self.ptus)} pan-tilt units for {n} cameras")
        self.on_reset = on_reset or (lambda o, p, occ: log.info("place object %d in pose %d on the turn-table", o, p))
        self._turntable = 0.0
        self._configuration: tuple[int, ...] | None = None
        self.in_position = False
        self.last_move: MoveResult | None = None
        self.eyes: list[tuple[float, float, float]] = []
        self.reconnects: list[Reconnect] = []

    def _apply_speed(self, i: int, unit: PanTilt) -> None:
        s = self.config.ptu(i).speed_deg_s
        if s is not None:
            unit.set_speed(s, s)

    # ------------------------------------------------------------ Rig
    @property
    def positions(self) -> tuple[int, ...]:
        return self.table.positions

    @property
    def image_shape(self) -> tuple[int, int]:
        return self.config.image_shape

    def reset(self, object: int, pose: int, occluders: object | None = None) -> None:
        """Ask for ``object`` to be placed, turn the turn-table to pose ``pose``, re-point the cameras."""
        n = self.config.n_poses
        if not (isinstance(pose, (int, np.integer)) and 0 <= pose < n):
            raise RigError(f"pose {pose!r} is outside 0..{n - 1}")
        if not isinstance(object, (int, np.integer)) or object < 0:
            raise RigError(f"object {object!r} must be a non-negative integer")
        self.on_reset(int(object), int(pose), occluders)
        self._turntable = 2.0 * math.pi * int(pose) / n
        self.move(self._configuration or (0,) * self.table.n_cameras)

    def move(self, configuration: Sequence[int]) -> None:
        """UDP move of the planner angles, wait for in-position, then point the PTUs."""
        cfg = _check_config(configuration, self.positions)
        self.in_position = False
        views = [self.table.views[i][v] for i, v in enumerate(cfg)]
        try:
            res = self.link.move(Move(tuple((v.pan, v.tilt) for v in views), self._turntable))
        except LinkError as e:
            raise RigError(f"motion controller: move to configuration {cfg} failed: {e}") from e
        self.eyes = list(res.eyes(self.table.carriers))[: len(cfg)]
        try:
            self._point()
        except _UnitLost as lost:  # the device vanished: bring it back, then point once more
            self._reconnect(lost.camera, lost.error)
            try:
                self._point()
            except _UnitLost as again:
                raise RigError(f"pan-tilt unit of camera {again.camera + 1}: lost again after reconnecting: "
                               f"{again.error}") from again.error
        self.last_move = res
        self._configuration = cfg
        self.in_position = True

    def _point(self) -> None:
        """Point every unit from its eye at the object: all start at once, then each is awaited."""
        ws = self.table.workspace
        i = 0
        try:
            for i, unit in enumerate(self.ptus):
                pan, tilt = ptu_angles(self.eyes[i], ws.object_xyz, self.config.ptu(i))
                unit.move_to(pan, tilt, wait=False)  # (after an earlier fault it reads the unit back first)
            for i, unit in enumerate(self.ptus):
                unit.await_motion()
        except PanTiltConnectionError as e:
            raise _UnitLost(i, e) from e
        except PanTiltError as e:
            raise RigError(f"pan-tilt unit of camera {i}: {e}") from e

    def _ports(self, i: int) -> list[str]:
        """Where unit ``i`` may come back: its ``port``, then the ``reconnect_glob`` matches
        (sorted), leaving out the devices the other units hold."""
        p = self.config.ptu(i)
        found = [p.port] if p.port else []
        if p.reconnect_glob:
            found += sorted(glob.glob(p.reconnect_glob))
        taken = {getattr(u, "url", None) for j, u in enumerate(self.ptus) if j != i}
        return [u for u in dict.fromkeys(found) if u not in taken]

    def _reconnect(self, i: int, error: PanTiltConnectionError) -> None:
        """Reopen unit ``i`` with a bounded backoff; one ``RigError`` if it is not back in time."""
        unit, limit = self.ptus[i], self.config.ptu(i).reconnect_s
        log.warning("pan-tilt unit of camera %d lost its device (%s); reconnecting for up to %.3g s", i, error, limit)
        t0 = time.monotonic()
        deadline, delay, attempts, last = t0 + limit, RECONNECT_FIRST_DELAY_S, 0, error
        tried: list[str] = []
        while True:
            for url in self._ports(i):
                attempts += 1
                tried.append(url)
                try:
                    unit.reconnect(url)
                    self._apply_speed(i, unit)
                except PanTiltError as e:
                    last = e
                    continue
                done = Reconnect(i, url, time.monotonic() - t0, attempts)
                self.reconnects.append(done)
                log.warning("pan-tilt unit of camera %d is back on %s after %.3f s (%d attempts)",
                            i, url, done.seconds, attempts)
                return
            left = deadline - time.monotonic()
            if left <= 0:
                unit.close()
                where = ", ".join(dict.fromkeys(tried)) or "no port to try (set [[ptu]] port or reconnect_glob)"
                raise RigError(
                    f"pan-tilt unit of camera {i}: lost its device and it did not come back within "
                    f"reconnect_s = {limit:.3g} s ({attempts} attempts on {where}); last error: {last}"
                ) from error
            time.sleep(min(delay, left))
            delay = min(2.0 * delay, RECONNECT_MAX_DELAY_S)

    def capture(self) -> Capture:
        """One ``uint8 [H, W]`` image per camera, camera 0 first (occluded
        fractions are unknown on real images)."""
        if not self.in_position:
            raise RigError("capture() before the rig reported in position: call move() first")
        images = []
        for i, cam in enumerate(self.cameras):
            try:
                img = cam.read()
            except CameraLostError as e:  # the device is gone: reopen it, bounded, and read once more
                img = self._reconnect_camera(i, cam, e)
            except CameraError as e:
                raise RigError(f"camera {i}: {e}") from e
            images.append(self._checked_image(i, img))
        return Capture.of(images)

    def _reconnect_camera(self, i: int, cam: Any, error: CameraLostError) -> np.ndarray:
        """Reopen camera ``i`` with a bounded backoff and read a frame; one ``RigError`` if it
        is not back within its ``reconnect_s`` (or cannot be reopened)."""
        reopen = getattr(cam, "reconnect", None)
        c = self.config.cameras[i] if i < len(self.config.cameras) else CameraConfig()
        limit = c.reconnect_s
        if reopen is None or limit <= 0:
            why = "it cannot be reopened" if reopen is None else "reconnect_s = 0"
            raise RigError(f"camera {i}: {error} ({why})") from error
        log.warning("camera %d delivers no frame (%s); reopening it for up to %.3g s", i, error, limit)
        t0 = time.monotonic()
        deadline, delay, attempts, last = t0 + limit, RECONNECT_FIRST_DELAY_S, 0, error
        while True:
            attempts += 1
            try:
                reopen()
                img = cam.read()
            except CameraError as e:
                last = e
            else:
                done = Reconnect(i, str(getattr(cam, "source", "")), time.monotonic() - t0, attempts, "camera")
                self.reconnects.append(done)
                log.warning("camera %d is back after %.3f s (%d attempts)", i, done.seconds, attempts)
                return img
            left = deadline - time.monotonic()
            if left <= 0:
                raise RigError(f"camera {i}: lost its device and it did not come back within reconnect_s = "
                               f"{limit:.3g} s ({attempts} attempts); last error: {last}") from error
            time.sleep(min(delay, left))
            delay = min(2.0 * delay, RECONNECT_MAX_DELAY_S)

    def reseed(self, seed) -> None:
        """Real cameras draw no random numbers: nothing to reseed (the
        simulated rig passes it to its renderer)."""

    def _checked_image(self, i: int, img: np.ndarray) -> np.ndarray:
        if not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.shape != self.image_shape:
            raise RigError(
                f"camera {i} delivered {getattr(img, 'dtype', type(img))} {getattr(img, 'shape', '')};"
                f" expected uint8 {self.image_shape}"
            )
        return img

    def close(self) -> None:
        for dev in reversed(self._opened):
            try:
                dev.close()
            except Exception:  # noqa: BLE001 - closing must not mask the original error
                pass
        self._opened = []

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class SimulatedHardwareRig(HardwareRig):
    """The hardware code path closed around the device simulators and a renderer.

    Args:
        renderer: ``reset(object, pose, occluders)`` and ``render_at(camera, eye)``
            (``SyntheticRig`` or a test double).
        config: a :class:`RigConfig` (``kind = "simulated"``), a path, or ``None``
            for the default table and mounts without faults.
        ptu_time_scale: wall seconds per simulated PTU second.
        pointing_tolerance_deg: largest angle allowed between a PTU's line of
            sight (queried from the simulator) and the direction to the object.
    """

    def __init__(
        self,
        renderer: Renderer,
        config: RigConfig | str | None = None,
        *,
        pointing_tolerance_deg: float = 0.5,
    ):
        from ..sim.controller_sim import ControllerSimulator
        from ..geometry.positions import default_table
        from ..sim.ptu_sim import PTUSimulator

        if config is None:
            config = RigConfig("simulated", default_table())
        elif not isinstance(config, RigConfig):
            config = load_config(config)
        if config.kind != "simulated":
            raise ConfigError(f"SimulatedHardwareRig needs kind = 'simulated', got {config.kind!r}")
        s = config.simulation
        self.renderer = renderer
        self.pointing_tolerance_deg = float(pointing_tolerance_deg)
        self.controller_sim = ControllerSimulator(
            config.table.workspace, faults=s.faults, seed=s.seed, time_scale=s.time_scale, key=config.controller.key
        )
        self.ptu_sims = [PTUSimulator(time_scale=s.time_scale, seed=s.seed + i) for i in range(config.table.n_cameras)]
        opened: list[Any] = [self.controller_sim, *self.ptu_sims]
        try:
            c = config.controller
            link = ControllerLink(self.controller_sim.address, timeout=c.timeout_s, retries=c.retries,
                                  max_motion_s=c.max_motion_s, key=c.key, version=c.protocol_version)
            opened.append(link)
            ptus: list[PanTilt] = []
            for i, sim in enumerate(self.ptu_sims):
                ptus.append(open_pan_tilt(config.ptu(i), port=sim.port))
                opened.append(ptus[-1])
            super().__init__(config, ptus=ptus, link=link, cameras=[])
        except BaseException:
            for dev in reversed(opened):
                dev.close()
            raise
        self._opened = opened

    def _ports(self, i: int) -> list[str]:
        """The simulator's current pty (it may come back under a new path), if it is plugged in."""
        sim = self.ptu_sims[i]
        return [sim.port] if sim.plugged else []

    def reseed(self, seed) -> None:
        """Restart the renderer's capture noise from ``seed`` (passed through to
        ``renderer.reseed``; a no-op for a renderer without one).

        The trial driver reseeds every rig with ``(seed, trial, step)`` before
        each capture, so a campaign
        on the simulated hardware draws the same capture noise as the same
        campaign on the synthetic rig it renders with."""
        reseed = getattr(self.renderer, "reseed", None)
        if reseed is not None:
            reseed(seed)

    def reset(self, object: int, pose: int, occluders: object | None = None) -> None:
        """Turn the simulated turn-table, then reset the scene to the pose it *reports*."""
        super().reset(object, pose, occluders)
        assert self.last_move is not None
        step = 2.0 * math.pi / self.config.n_poses
        reported = self.last_move.turntable
        got = int(round(reported / step)) % self.config.n_poses
        if abs(math.remainder(reported - pose * step, 2.0 * math.pi)) > math.radians(0.5):
            raise RigError(f"turn-table reports {math.degrees(reported):.3f} deg for pose {pose}")
        self.renderer.reset(object, got, occluders)

    def capture(self) -> Capture:
        """Render each camera at the eye the controller reported, once its PTU
        points at the object; the renderer's true occluded fractions come with it."""
        if not self.in_position:
            raise RigError("capture() before the rig reported in position: call move() first")
        ws = self.table.workspace
        images, occl = [], []
        for i, unit in enumerate(self.ptus):
            eye = self.eyes[i]
            try:
                pan, tilt = unit.position()
            except PanTiltError as e:
                raise RigError(f"pan-tilt unit of camera {i}: {e}") from e
            want = np.asarray(ws.object_xyz, float) - np.asarray(eye, float)
            want /= np.linalg.norm(want)
            have = line_of_sight(pan, tilt, self.config.ptu(i))
            err = math.degrees(math.acos(float(np.clip(want @ have, -1.0, 1.0))))
            if err > self.pointing_tolerance_deg:
                raise RigError(f"camera {i} points {err:.2f} deg away from the object (PTU at {pan:.3f}, {tilt:.3f} deg)")
            img, frac = self.renderer.render_at(i, eye)
            images.append(self._checked_image(i, img))
            occl.append(float(frac))
        return Capture.of(images, occl)


def rig_from_config(config: RigConfig | str, renderer: Renderer | None = None) -> HardwareRig:
    """Build the rig a TOML file describes: ``HardwareRig`` or ``SimulatedHardwareRig``.

    For a simulated rig without ``renderer`` this imports ``.synthetic.SyntheticRig``
    (pybullet) and renders with ``SyntheticRig(config.table)``."""
    if not isinstance(config, RigConfig):
        config = load_config(config)
    if config.kind == "hardware":
        return HardwareRig(config)
    if renderer is None:
        from ..render.synthetic import SyntheticRig  # deferred: pybullet is heavy and optional

        renderer = SyntheticRig(config.table)
    return SimulatedHardwareRig(renderer, config)
