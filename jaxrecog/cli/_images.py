"""Images the belief must not silently ignore (``plan --images``, the captures of ``recognize``).

The recognizer leaves the belief unchanged for an image set it cannot use
(``Decision.valid``); at the command line that must not pass as a result.
:func:`usable` checks each image first (the model's size, then
:func:`jaxrecog.features.check_image`: finite, not negative, not all black,
not constant) and fails with one line naming the image and the reason, or,
with ``--skip-invalid``, warns on stderr and hands the recognizer a black image
in its place, which its valid mask leaves out.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ..features import ImageError, check_image
from ._common import CLIError

__all__ = ["read_gray", "usable"]


def read_gray(path: str) -> np.ndarray:
    """A gray image file: 8-bit (colour converted to gray) or float (e.g. a
    32-bit TIFF).  A missing or unreadable file is an error whatever
    ``--skip-invalid`` says; the content is for :func:`usable` to judge."""
    if not Path(path).is_file():
        raise CLIError(f"image {path} not found")
    img = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CLIError(f"image {path} cannot be read as an image")
    if img.dtype != np.uint8 and not np.issubdtype(img.dtype, np.floating):
        raise CLIError(f"image {path} is {img.dtype}, expected 8-bit gray (or float)")
    if img.ndim == 3:
        img = img.astype(np.float32) if img.dtype.kind == "f" else img  # cv2 converts 8-bit and float32 colour
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    return img


def _problem(image: np.ndarray, shape: tuple[int, int], name: str) -> str | None:
    """Why the belief cannot use ``image`` (a message naming it), or ``None``."""
    a = np.asarray(image)
    if a.shape != tuple(shape):
        size = "x".join(str(n) for n in a.shape)
        return f"{name} is {size}, the model expects {shape[0]}x{shape[1]}"
    try:
        check_image(a, shape, name)
    except ImageError as e:
        return str(e)
    return None


def usable(images: Sequence[np.ndarray], shape: tuple[int, int], names: Sequence[str],
           skip_invalid: bool) -> np.ndarray:
    """The images as one ``[n, H, W]`` array for ``Recognizer.step``, each checked.

    Raises:
        CLIError: naming the first image the belief cannot use and why, unless
            ``skip_invalid``: then each one is a warning on stderr and is
            replaced by a black image (the recognizer's valid mask rejects it,
            so the belief does not use this image set).
    """
    out = []
    for img, name in zip(images, names):
        problem = _problem(img, shape, name)
        if problem is None:
            out.append(np.asarray(img))
            continue
        if not skip_invalid:
            raise CLIError(f"{problem}; rejected (--skip-invalid goes on without it)")
        print(f"jaxrecog: warning: {problem}; skipped (--skip-invalid): the belief does not use this image set",
              file=sys.stderr)
        out.append(np.zeros(shape, np.uint8))
    return np.stack(out)
