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
"""

from __future__ import annotations

import glob
import os
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
]

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


class VideoCamera(_Retrying):
    """An OpenCV ``VideoCapture`` camera.

    Args:
        source: device index (``0``), file path, URL or image-sequence pattern.
        image_shape: (H, W) of the images returned.
        retries: extra attempts after a failed or black frame.
        black_level: a frame whose maximum is at or below this is "black".
        capture_factory: builds the capture object (tests pass a fake).
    """

    def __init__(
        self,
        source: int | str,
        *,
        image_shape: tuple[int, int] = (120, 160),
        retries: int = 3,
        black_level: int = 0,
        capture_factory: Callable[[Any], Any] = cv2.VideoCapture,
    ):
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
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
        try:
            ok, frame = self._cap.read()
        except cv2.error as e:
            return None, f"VideoCapture.read raised {e}"
        if not ok or frame is None:
            return None, "VideoCapture.read returned no frame"
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
