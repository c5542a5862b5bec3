"""Cameras that deliver 8-bit gray images at the model's size (thesis §6.5: 120 x 160).

Two sources:

* :class:`VideoCamera` -- an OpenCV ``VideoCapture`` (device index, file, URL
  or an image-sequence pattern such as ``frames/%03d.png``);
* :class:`ImageSequenceCamera` -- the image files of a folder (or a glob
  pattern), in sorted order.

Every frame goes through :func:`to_gray`:

1. colour -> gray with OpenCV's BT.601 weights (``Y = 0.299 R + 0.587 G + 0.114 B``;
   BGR and BGRA as OpenCV delivers them);
2. 16-bit -> 8-bit by dropping the low byte (``v >> 8``), float in [0, 1] -> ``round(255 v)``;
3. resize to ``(H, W)`` with ``cv2.INTER_AREA`` when shrinking and
   ``cv2.INTER_LINEAR`` when enlarging.  The aspect ratio is *not* preserved
   (no cropping): the model was trained on whole frames of that size, so the
   camera must be set up (zoom, crop in the driver) to give the same field of view.

A frame that cannot be read, or a *black* frame (every pixel <= ``black_level``:
lens cap, camera still starting), is retried up to ``retries`` times; then a
:class:`CameraError` names the source and the last reason.  When a
:class:`VideoCamera` delivered no frame at all in those attempts (unplugged,
stream dropped) the error is a :class:`CameraLostError`, and
:meth:`VideoCamera.reconnect` reopens the device (``HardwareRig.capture``
does so with a bounded backoff, ``[[camera]] reconnect_s``).

Every read of a :class:`VideoCamera` is bounded: ``VideoCapture.read`` runs on
a thread of its own and is waited for at most ``read_timeout_s`` seconds
(:data:`READ_TIMEOUT_S`, 5 s; ``[[camera]] read_timeout_s``).  A read that
does not return in time is abandoned with its capture (released once it
returns, if ever) and is a :class:`CameraLostError` naming the source and the
timeout, so the rig reopens the device.  A read that raises (whatever the
exception), returns no ``(ok, frame)`` pair, returns ``ok`` false, no frame or
an empty one is *no frame*: retried, then one :class:`CameraLostError` line
naming the source and what the last read returned.
"""

from __future__ import annotations

import glob
import math
import os
import threading
from typing import Any, Callable, Protocol, runtime_checkable

import cv2
import numpy as np

__all__ = [
    "Camera",
    "CameraError",
    "CameraLostError",
    "VideoCamera",
    "ImageSequenceCamera",
    "to_gray",
    "IMAGE_SUFFIXES",
    "READ_TIMEOUT_S",
]

#: Default bound (seconds) on one ``VideoCapture.read`` (a camera delivers a frame in
#: well under a second; a network stream may take a few)
READ_TIMEOUT_S = 5.0

IMAGE_SUFFIXES = (".png", ".pgm", ".ppm", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


class CameraError(RuntimeError):
    """A camera could not deliver a usable frame."""


class CameraLostError(CameraError):
    """A device camera delivered no frame at all (unplugged, stream gone): reopen it."""


@runtime_checkable
class Camera(Protocol):
    image_shape: tuple[int, int]

    def read(self) -> np.ndarray:
        """One ``uint8`` gray image of ``image_shape``."""
        ...

    def close(self) -> None: ...


def to_gray(frame: np.ndarray, image_shape: tuple[int, int]) -> np.ndarray:
    """Convert any OpenCV frame to ``uint8 [H, W]`` gray of ``image_shape`` (steps in the module doc)."""
    if not isinstance(frame, np.ndarray) or frame.size == 0:
        raise CameraError(f"frame is empty or not an array ({type(frame).__name__})")
    if frame.dtype == np.uint16:
        frame = (frame >> 8).astype(np.uint8)
    elif frame.dtype in (np.float32, np.float64):
        if not np.all(np.isfinite(frame)):
            raise CameraError("frame holds NaN or infinite values")
        frame = np.clip(np.rint(frame * 255.0), 0, 255).astype(np.uint8)
    elif frame.dtype != np.uint8:
        raise CameraError(f"unsupported frame dtype {frame.dtype}")
    if frame.ndim == 3 and frame.shape[2] == 1:
        frame = frame[:, :, 0]
    if frame.ndim == 3 and frame.shape[2] == 3:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    elif frame.ndim == 3 and frame.shape[2] == 4:
        frame = cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY)
    elif frame.ndim != 2:
        raise CameraError(f"unsupported frame shape {frame.shape}")
    h, w = image_shape
    if frame.shape != (h, w):
        shrink = frame.shape[0] * frame.shape[1] > h * w
        frame = cv2.resize(frame, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return np.ascontiguousarray(frame, dtype=np.uint8)


def _check_shape(image_shape) -> tuple[int, int]:
    shape = tuple(int(v) for v in image_shape)
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"image_shape must be (height, width) with positive sizes, got {image_shape!r}")
    return shape  # type: ignore[return-value]


class _Retrying:
    image_shape: tuple[int, int]
    retries: int
    black_level: int
    _device = False  # a device that may be lost (and reopened), not a list of files

    def _grab(self) -> tuple[np.ndarray | None, str]:
        raise NotImplementedError

    def _name(self) -> str:
        raise NotImplementedError

    def read(self) -> np.ndarray:
        """One gray ``uint8 [H, W]`` frame; failed or black frames are retried ``retries`` times."""
        why = ""
        grabbed = False
        for _ in range(self.retries + 1):
            frame, why = self._grab()
            if frame is None:
                continue
            grabbed = True
            try:
                img = to_gray(frame, self.image_shape)
            except CameraError as e:
                why = str(e)
                continue
            if int(img.max()) <= self.black_level:
                why = f"black frame (every pixel <= {self.black_level})"
                continue
            return img
        error = CameraLostError if self._device and not grabbed else CameraError
        raise error(f"source {self._name()}: no usable frame after {self.retries + 1} attempts: {why}")


class _Read:
    """One ``capture.read()`` on a daemon thread of its own, so that the caller can wait
    for it a bounded time; a read given up on releases its capture when it returns."""

    def __init__(self, capture: Any):
        self.capture = capture
        self.value: Any = None
        self.error: BaseException | None = None
        self.finished = threading.Event()
        self._lock = threading.Lock()
        self._abandoned = False
        threading.Thread(target=self._run, name="camera-read", daemon=True).start()

    def _run(self) -> None:
        try:
            self.value = self.capture.read()
        except BaseException as e:  # noqa: BLE001 - reported to the caller as no frame
            self.error = e
        with self._lock:
            self.finished.set()
            abandoned = self._abandoned
        if abandoned:
            _release_quietly(self.capture)

    def abandon(self) -> None:
        """Nobody waits any more: release the capture now if the read is over, else when it returns."""
        with self._lock:
            self._abandoned = not self.finished.is_set()
        if not self._abandoned:
            _release_quietly(self.capture)


def _release_quietly(capture: Any) -> None:
    try:
        capture.release()
    except Exception:  # noqa: BLE001 - a capture given up on: nothing left to report to
        pass


def _first_line(e: BaseException) -> str:
    text = (str(e).strip().splitlines() or [""])[0][:200]
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


class VideoCamera(_Retrying):
    """An OpenCV ``VideoCapture`` camera.

    Args:
        source: device index (``0``), file path, URL or image-sequence pattern.
        image_shape: (H, W) of the images returned.
        retries: extra attempts after a failed or black frame.
        black_level: a frame whose maximum is at or below this is "black".
        read_timeout_s: the longest one ``VideoCapture.read`` is waited for.
        capture_factory: builds the capture object (tests pass a fake).
    """

    def __init__(
        self,
        source: int | str,
        *,
        image_shape: tuple[int, int] = (120, 160),
        retries: int = 3,
        black_level: int = 0,
        read_timeout_s: float = READ_TIMEOUT_S,
        capture_factory: Callable[[Any], Any] = cv2.VideoCapture,
    ):
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        if not (read_timeout_s > 0 and math.isfinite(read_timeout_s)):
            raise ValueError(f"read_timeout_s must be > 0 seconds, got {read_timeout_s}")
        self.read_timeout_s = float(read_timeout_s)
        self.source = source
        self.image_shape = _check_shape(image_shape)
        self.retries = int(retries)
        self.black_level = int(black_level)
        self._factory = capture_factory
        self._cap = None
        self._closed = False
        self.open()

    _device = True

    def _name(self) -> str:
        return repr(self.source)

    def reconnect(self) -> None:
        """Release and reopen the device (after a :class:`CameraLostError`)."""
        self.open()

    def open(self) -> None:
        self._release()
        self._closed = False
        cap = self._factory(self.source)
        if cap is None or not cap.isOpened():
            raise CameraLostError(f"video source {self.source!r}: VideoCapture could not open it")
        self._cap = cap

    def _grab(self):
        if self._cap is None:
            if self._closed:
                raise CameraError(f"video source {self.source!r} is closed")
            raise CameraLostError(f"video source {self.source!r} is not open (the last reopen failed)")
        read = _Read(self._cap)
        if not read.finished.wait(self.read_timeout_s):
            self._cap = None  # it may never return: the capture goes with it, reopen the device
            read.abandon()
            raise CameraLostError(f"video source {self.source!r}: VideoCapture.read did not return within "
                                  f"read_timeout_s = {self.read_timeout_s:g} s; the capture was abandoned")
        if read.error is not None:
            return None, f"VideoCapture.read raised {_first_line(read.error)}"
        value = read.value
        if not (isinstance(value, (tuple, list)) and len(value) == 2):
            return None, f"VideoCapture.read returned {type(value).__name__}, not (ok, frame)"
        ok, frame = value
        if not ok or frame is None:
            return None, "VideoCapture.read returned no frame"
        if not isinstance(frame, np.ndarray) or frame.size == 0:
            return None, f"VideoCapture.read returned an empty frame ({getattr(frame, 'shape', type(frame).__name__)})"
        return frame, ""

    def _release(self) -> None:
        if self._cap is not None:
            cap, self._cap = self._cap, None
            cap.release()

    def close(self) -> None:
        self._closed = True
        self._release()


class ImageSequenceCamera(_Retrying):
    """Frames from image files, in sorted order (a folder, or a glob pattern).

    Each :meth:`read` consumes the next file; an unreadable or black file is
    skipped and counts as one retry.  At the end of the list it starts over
    (``loop=True``) or raises :class:`CameraError`.
    """

    def __init__(
        self,
        source: str | os.PathLike,
        *,
        image_shape: tuple[int, int] = (120, 160),
        retries: int = 3,
        black_level: int = 0,
        loop: bool = True,
    ):
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        src = os.fspath(source)
        if os.path.isdir(src):
            files = [os.path.join(src, f) for f in os.listdir(src) if f.lower().endswith(IMAGE_SUFFIXES)]
        else:
            files = [f for f in glob.glob(src) if f.lower().endswith(IMAGE_SUFFIXES)]
        if not files:
            raise CameraError(f"image sequence {src!r}: no image files ({', '.join(IMAGE_SUFFIXES)})")
        self.source = src
        self.files = sorted(files)
        self.image_shape = _check_shape(image_shape)
        self.retries = int(retries)
        self.black_level = int(black_level)
        self.loop = bool(loop)
        self.index = 0

    def _name(self) -> str:
        return repr(self.source)

    def _grab(self):
        if self.index >= len(self.files):
            if not self.loop:
                raise CameraError(f"image sequence {self.source!r} is exhausted after {len(self.files)} frames")
            self.index = 0
        path = self.files[self.index]
        self.index += 1
        frame = cv2.imread(path, cv2.IMREAD_UNCHANGED)
        if frame is None:
            return None, f"cannot read image {path!r}"
        return frame, ""

    def close(self) -> None:
        pass
