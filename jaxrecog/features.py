"""Images -> eigenspace features, with the boundary checks (thesis eq. 4.1-4.11).

``g = basis[v]ᵀ (y / ||y|| - mean_image[v])`` for a gray image ``y`` flattened
row-major to ``D = H * W``.

:func:`project` is the checked entry point for one image: an image of the
wrong size, with NaN/inf, all black (zero energy, eq. 4.2 undefined) or constant
raises :class:`ImageError` naming the image; nothing NaN leaves this layer.
:func:`project_batch` / :func:`project_camera` are the pure, jittable batched
versions for the recognizer: invalid images give ``g = 0`` and ``valid = False``
(a value, not an exception, inside traced code).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .sensor_model import SensorModel, CameraModel

__all__ = ["ImageError", "check_image", "project", "project_batch", "project_camera"]


class ImageError(ValueError):
    """An image cannot be projected (wrong size, NaN, zero energy, constant)."""


def check_image(image, image_shape: tuple[int, int], name: str = "image") -> np.ndarray:
    """Validate one gray image and return it as ``float32 [D]``.

    Raises:
        ImageError: naming ``name`` and what is wrong.
    """
    a = np.asarray(image)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)):
        raise ImageError(f"{name}: dtype {a.dtype} is not a gray image (expected uint8 or float)")
    if a.shape != tuple(image_shape):
        raise ImageError(
            f"{name}: shape {a.shape} does not match the model's image shape {tuple(image_shape)}"
        )
    y = a.astype(np.float64).ravel()
    if not np.all(np.isfinite(y)):
        n_bad = int(np.sum(~np.isfinite(y)))
        raise ImageError(f"{name}: {n_bad} pixel(s) are NaN or infinite")
    if not np.any(y != 0.0):
        raise ImageError(f"{name}: all-black image has zero energy (eq. 4.2), cannot normalise")
    if y.min() == y.max():
        raise ImageError(f"{name}: constant image (every pixel {y[0]:g}) carries no appearance")
    return y.astype(np.float32)


@jax.jit
def _project_one(mean_image: Float[Array, " D"], basis: Float[Array, "D K"],
                 y: Float[Array, " D"]) -> Float[Array, " K"]:
    xhat = y / jnp.linalg.norm(y)
    return (xhat - mean_image) @ basis


def project(model: SensorModel, camera: int, position: int, image, *, name: str | None = None
            ) -> Float[Array, " K"]:
    """Features of one image taken by ``camera`` at ``position`` (eq. 4.1-4.11).

    Raises:
        ImageError: bad image (see :func:`check_image`).
        IndexError: camera or position out of range.
    """
    if not 0 <= camera < model.n_cameras:
        raise IndexError(f"camera {camera} out of range (model has {model.n_cameras})")
    cam = model.cameras[camera]
    if not 0 <= position < cam.n_positions:
        raise IndexError(f"position {position} out of range for camera {camera} "
                         f"({cam.n_positions} positions)")
    label = name or f"image (camera {camera}, position {position})"
    y = check_image(image, model.image_shape, label)
    return _project_one(cam.mean_image[position], cam.basis[position], jnp.asarray(y))


def project_batch(mean_image: Float[Array, " D"], basis: Float[Array, "D K"],
                  images: Float[Array, "B D"]) -> tuple[Float[Array, "B K"], Bool[Array, " B"]]:
    """Pure batched projection for one position: ``(g [B, K], valid [B])``.

    Rows that are non-finite, all zero or constant are invalid: their ``g`` is 0.
    """
    y_hat, valid = _unit_energy(jnp.asarray(images, dtype=basis.dtype))
    g = (y_hat - mean_image[None, :]) @ basis
    return jnp.where(valid[:, None], g, 0.0), valid


def _unit_energy(y: Float[Array, "B D"]) -> tuple[Float[Array, "B D"], Bool[Array, " B"]]:
    """``y / ||y||`` per row (eq. 4.1-4.2) and its validity: rows that are
    non-finite, all zero or constant are invalid (and returned as 0)."""
    finite = jnp.all(jnp.isfinite(y), axis=1)
    y = jnp.where(finite[:, None], y, 0.0)
    norm = jnp.linalg.norm(y, axis=1)
    varies = jnp.max(y, axis=1) > jnp.min(y, axis=1)
    valid = finite & (norm > 0) & varies
    safe = jnp.where(valid, norm, 1.0)
    return jnp.where(valid[:, None], y / safe[:, None], 0.0), valid


def project_camera(camera: CameraModel, positions: Int[Array, " B"],
                   images: Float[Array, "B H W"]) -> tuple[Float[Array, "B K"], Bool[Array, " B"]]:
    """Pure batched projection of images of one camera at per-image positions
    (gathers each position's mean and basis): ``(g [B, K], valid [B])``."""
    B = images.shape[0]
    y = jnp.asarray(images, dtype=camera.basis.dtype).reshape(B, -1)
    mean = camera.mean_image[positions]           # [B, D]
    basis = camera.basis[positions]               # [B, D, K]
    y_hat, valid = _unit_energy(y)
    g = jnp.einsum("bd,bdk->bk", y_hat - mean, basis)
    return jnp.where(valid[:, None], g, 0.0), valid
