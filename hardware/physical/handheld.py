"""A hand-held rig: a person moves one camera to where the planner asks.

The positions are the user's own, in a small TOML *layout* file: one
``[[cameras]]`` entry per camera of the model, each with its ``positions``
in the order the model (its database) numbers them, every position a name
and the angles it is seen from (:func:`load_layout`)::

    distance_m = 0.4                      # camera to object (optional, 0.4)

    [[cameras]]
    name = "high"
    positions = [
      { name = "front", pan_deg = 0, tilt_deg = 45 },
      { name = "left", pan_deg = 90, tilt_deg = 45, note = "by the lamp" },
    ]

``pan_deg`` goes round the object (0 = front, 90 = the left of someone
standing at the front and facing it), ``tilt_deg`` is the height above the table (0 = level, 90 = from
above).  The eye of a position is ``object + d (sin pan cos tilt, cos pan cos
tilt, sin tilt)``, the appendix-C convention ``tan(pan) = dx / dy``.

:class:`HandheldRig` is a :class:`~..rigs.rig.Rig`: for each camera of a
configuration it says where to put the camera (:func:`instruction`; and draws
the layout with that position marked into ``picture``, when given), waits for
the user (Enter; ``wait`` in tests and for a camera that needs no person),
and reads one frame of the one OpenCV source -- a webcam index, a video file
or an image-sequence pattern (``frames/%03d.png``) or folder.  The trial
driver, recognizer, planner and stop rule are those of every rig.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from typing import Callable, Sequence

import cv2
import numpy as np

from ..._files import read_text
from ..devices.camera import CameraError, ImageSequenceCamera, VideoCamera
from ..rigs.rig import Capture, RigError

__all__ = ["HandheldRig", "Layout", "LayoutError", "LayoutGeometry", "LayoutPosition", "draw_layout", "instruction",
           "load_layout", "open_camera"]

_TOP_KEYS = ("cameras", "distance_m")
_CAMERA_KEYS = ("name", "positions")
_POSITION_KEYS = ("name", "note", "pan_deg", "tilt_deg")


class LayoutError(ValueError):
    """A layout file that cannot be used (one line: the file, where, what)."""


@dataclasses.dataclass(frozen=True)
class LayoutPosition:
    """One place for the camera: its name, angles (degrees) and an optional note."""

    name: str
    pan_deg: float
    tilt_deg: float
    note: str = ""


@dataclasses.dataclass(frozen=True)
class LayoutGeometry:
    """The object and every position's eye in metres (the live view's 3-D)."""

    object_xyz: tuple[float, float, float]
    eyes: tuple[np.ndarray, ...]


@dataclasses.dataclass(frozen=True)
class Layout:
    """The user's layout: per camera its name and positions."""

    cameras: tuple[tuple[str, tuple[LayoutPosition, ...]], ...]
    distance_m: float = 0.4

    @property
    def positions(self) -> tuple[int, ...]:
        return tuple(len(p) for _, p in self.cameras)

    def eye(self, camera: int, position: int) -> np.ndarray:
        """Where position ``position`` of ``camera`` puts the eye (object at the origin)."""
        p = self.cameras[camera][1][position]
        pan, tilt = math.radians(p.pan_deg), math.radians(p.tilt_deg)
        return self.distance_m * np.array([math.sin(pan) * math.cos(tilt), math.cos(pan) * math.cos(tilt),
                                           math.sin(tilt)])

    def geometry(self) -> LayoutGeometry:
        eyes = tuple(np.stack([self.eye(i, v) for v in range(n)]) for i, n in enumerate(self.positions))
        return LayoutGeometry((0.0, 0.0, 0.0), eyes)


def _keys(d, allowed: Sequence[str], where: str, path: str) -> None:
    if not isinstance(d, dict):
        raise LayoutError(f"layout {path}: {where} must be a table, got {type(d).__name__}")
    unknown = sorted(set(d) - set(allowed))
    if unknown:
        raise LayoutError(f"layout {path}: unknown key {unknown[0]!r} in {where} (expected: {', '.join(allowed)})")


def _number(d: dict, key: str, where: str, path: str, lo: float, hi: float) -> float:
    if key not in d:
        raise LayoutError(f"layout {path}: {where} needs {key!r}")
    v = d[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
        raise LayoutError(f"layout {path}: {where}: {key} = {v!r} is not a number in [{lo:g}, {hi:g}]")
    return float(v)


def _position(d, where: str, path: str) -> LayoutPosition:
    _keys(d, _POSITION_KEYS, where, path)
    name = d.get("name")
    if not isinstance(name, str) or not name.strip():
        raise LayoutError(f"layout {path}: {where} needs a 'name' (text)")
    return LayoutPosition(name.strip(), _number(d, "pan_deg", where, path, -360, 360),
                          _number(d, "tilt_deg", where, path, -90, 90), str(d.get("note", "")))


def load_layout(path: str | os.PathLike) -> Layout:
    """Read and check a layout file (module doc: the format); :class:`LayoutError` otherwise."""
    path = os.fspath(path)
    try:  # a regular UTF-8 file of at most 1 MiB (as every settings file)
        data = tomllib.loads(read_text(path, "layout"))
    except FileNotFoundError:
        raise LayoutError(f"layout {path} not found") from None
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise LayoutError(f"layout {path}: {' '.join(str(e).split())}") from None
    _keys(data, _TOP_KEYS, "the top level", path)
    distance = _number(data, "distance_m", "the top level", path, 1e-3, 100) if "distance_m" in data else 0.4
    cams = data.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise LayoutError(f"layout {path}: needs one [[cameras]] entry per camera of the model")
    cameras = []
    for i, cam in enumerate(cams, 1):
        _keys(cam, _CAMERA_KEYS, f"camera {i}", path)
        positions = cam.get("positions")
        if not isinstance(positions, list) or not positions:
            raise LayoutError(f"layout {path}: camera {i} needs a list of positions")
        cameras.append((str(cam.get("name", f"camera {i}")),
                        tuple(_position(p, f"camera {i} position {k}", path) for k, p in enumerate(positions, 1))))
    return Layout(tuple(cameras), distance)


def instruction(layout: Layout, step: int, camera: int, position: int) -> str:
    """The line that tells the user where to put the camera (step, camera, position 0-based)."""
    name, positions = layout.cameras[camera]
    p = positions[position]
    note = f" ({p.note})" if p.note else ""
    return (f"step {step + 1}, camera {camera + 1} of {len(layout.cameras)} '{name}': put the camera at "
            f"'{p.name}'{note}, position {position + 1} of {len(positions)}: pan {p.pan_deg:g} deg, "
            f"tilt {p.tilt_deg:g} deg, {layout.distance_m:g} m from the object, pointing at it")


def draw_layout(layout: Layout, camera: int, position: int, size: int = 480) -> np.ndarray:
    """A top view of the layout (``uint8 [size, size, 3]``, BGR) as someone
    at the front sees it from above: the object in the middle, the front
    down, every position a dot at its pan (positive pans on the left), nearer
    the middle the higher its tilt; ``position`` of ``camera`` ringed in red."""
    img = np.full((size, size, 3), 255, np.uint8)
    c, r = size // 2, size * 0.38
    cv2.circle(img, (c, c), int(size * 0.03), (60, 60, 60), -1)
    cv2.putText(img, "front", (c - 22, size - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    colours = [(200, 120, 0), (0, 150, 0), (150, 0, 150), (0, 150, 200)]
    for i, (_, positions) in enumerate(layout.cameras):
        for v, p in enumerate(positions):
            pan, tilt = math.radians(p.pan_deg), math.radians(p.tilt_deg)
            x = int(round(c - r * math.cos(tilt) * math.sin(pan)))
            y = int(round(c + r * math.cos(tilt) * math.cos(pan)))
            cv2.circle(img, (x, y), 6, colours[i % len(colours)], -1)
            if (i, v) == (camera, position):
                cv2.circle(img, (x, y), 13, (0, 0, 255), 3)
                cv2.putText(img, p.name, (x + 15, y + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 255), 1,
                            cv2.LINE_AA)
    name, positions = layout.cameras[camera]
    title = f"camera {camera + 1} '{name}': {positions[position].name}"
    cv2.putText(img, title, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def _enter() -> None:
    """Wait for Enter on stdin (the default ``wait``)."""
    try:
        input("press Enter to capture ")
    except EOFError:
        raise RigError("stdin closed while waiting for Enter (--no-wait captures without waiting)") from None


def open_camera(source: str | int, image_shape: tuple[int, int]):
    """The OpenCV camera of ``source``: a device index, a video file, an
    image-sequence pattern or a folder of images (one line if it cannot open)."""
    try:
        if isinstance(source, str) and os.path.isdir(source):
            return ImageSequenceCamera(source, image_shape=image_shape, loop=False)
        return VideoCamera(int(source) if str(source).isdigit() else source, image_shape=image_shape, retries=0)
    except CameraError as e:
        raise RigError(f"hand-held camera: {e}") from None


class HandheldRig:
    """One camera, moved by a person to the positions of a :class:`Layout`.

    Args:
        camera: where frames come from (:func:`open_camera`; anything with
            ``read()`` and ``close()``).
        layout: the user's positions (:func:`load_layout`).
        image_shape: the model's (H, W); frames are converted to it.
        wait: called before each frame (default: wait for Enter on stdin;
            ``lambda: None`` to capture at once).
        instruct: called with each instruction line (default ``print``).
        picture: write the layout with the next position marked to this image file.
    """

    def __init__(self, camera, layout: Layout, image_shape: tuple[int, int], *, wait: Callable[[], None] | None = None,
                 instruct: Callable[[str], None] | None = None, picture: str | os.PathLike | None = None):
        self.camera, self.layout = camera, layout
        self._shape = tuple(int(v) for v in image_shape)
        self.wait = _enter if wait is None else wait
        self.instruct = (lambda line: print(line, flush=True)) if instruct is None else instruct
        self.picture = picture
        self.geometry = layout.geometry()
        self._config: tuple[int, ...] | None = None
        self._step = 0

    @property
    def positions(self) -> tuple[int, ...]:
        return self.layout.positions

    @property
    def image_shape(self) -> tuple[int, int]:
        return self._shape  # type: ignore[return-value]

    def reset(self, object: int, pose: int, occluders: object | None = None) -> None:
        if occluders is not None:
            raise RigError("a hand-held rig cannot add occluders")
        self._step = 0

    def reseed(self, seed) -> None:
        """Nothing to reseed: the frames are the camera's."""

    def move(self, configuration: Sequence[int]) -> None:
        cfg = tuple(int(v) for v in configuration)
        if len(cfg) != len(self.positions) or any(not 0 <= v < n for v, n in zip(cfg, self.positions)):
            raise RigError(f"configuration {cfg} is outside the layout's positions {self.positions}")
        self._config = cfg

    def capture(self) -> Capture:
        """For each camera: say where to put it, wait, read a frame."""
        if self._config is None:
            raise RigError("call move() before capture()")
        images = []
        for i, v in enumerate(self._config):
            self.instruct(instruction(self.layout, self._step, i, v))
            if self.picture is not None and not cv2.imwrite(os.fspath(self.picture), draw_layout(self.layout, i, v)):
                raise RigError(f"could not write the layout picture {os.fspath(self.picture)}")
            self.wait()
            try:
                images.append(self.camera.read())
            except CameraError as e:
                raise RigError(f"the hand-held camera returned no image for step {self._step + 1}, "
                               f"camera {i + 1}: {e}") from None
        self._step += 1
        return Capture.of(images)  # how much of the object is hidden is not known

    def close(self) -> None:
        self.camera.close()
