"""Images -> eigenspace features, with the boundary checks (thesis eq. 4.1-4.11).

``g = basis[v]ᵀ (y / ||y|| - mean_image[v])`` for a gray image ``y`` flattened
row-major to ``D = H * W``.

:func:`project` is the checked entry point for one image: an image of the
wrong size, with NaN/inf, negative values, values that overflow float32, all
black (zero energy, eq. 4.2 undefined) or constant raises :class:`ImageError`
naming the image; nothing NaN leaves this layer.
:func:`project_batch` / :func:`project_camera` are the pure, jittable batched
versions for the recognizer: invalid images (non-finite, negative, all zero,
constant) give ``g = 0`` and ``valid = False`` (a value, not an exception,
inside traced code).

Neither path can overflow or underflow the energy: :func:`project`
normalises in float64 (with training's ``eigenspace.unit_energy``), the batched
paths divide each row by its brightest pixel before the float32 norm
(``y / ||y||`` is unchanged by that scale, eq. 4.2), so ``y / ||y||`` is finite
for every valid image.
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

from .eigenspace import unit_energy
from .sensor_model import SensorModel, CameraModel

__all__ = ["ImageError", "HostFeatures", "check_image", "host_features", "host_features_batch", "host_planes", "project", "project_at", "project_batch",
           "project_camera"]


class ImageError(ValueError):
    """An image cannot be projected (wrong size, NaN, negative, overflow, zero
    energy, constant)."""


def check_image(image, image_shape: tuple[int, int], name: str = "image") -> np.ndarray:
    """Validate one gray image and return it as ``float32 [D]``.

    Checked, in order: a real (integer or float) dtype, the model's image
    shape, every pixel finite, no negative pixel, every pixel finite after the
    cast to float32 (no overflow), and - on the float32 values returned - not
    all zero (eq. 4.2 needs energy) and not constant.

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
    if np.any(y < 0):
        n_neg = int(np.sum(y < 0))
        raise ImageError(f"{name}: {n_neg} pixel(s) are negative (min {y.min():g}); "
                         f"gray levels must be >= 0")
    with np.errstate(over="ignore"):
        y32 = y.astype(np.float32)
    if not np.all(np.isfinite(y32)):
        n_big = int(np.sum(~np.isfinite(y32)))
        raise ImageError(f"{name}: {n_big} pixel(s) overflow float32 (max {y.max():g} > "
                         f"{float(np.finfo(np.float32).max):g})")
    if not np.any(y32 != 0.0):
        raise ImageError(f"{name}: all-black image has zero energy (eq. 4.2), cannot normalise")
    if y32.min() == y32.max():
        raise ImageError(f"{name}: constant image (every pixel {y32[0]:g}) carries no appearance")
    return y32


@jax.jit
def _project_one(mean_image: Float[Array, " D"], basis: Float[Array, "D K"],
                 xhat: Float[Array, " D"]) -> Float[Array, " K"]:
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
    # float64 (training's normaliser): a float32-finite image's energy can
    # neither overflow nor underflow there
    xhat = unit_energy(check_image(image, model.image_shape, label)[None])[0]
    return _project_one(cam.mean_image[position], cam.basis[position],
                        jnp.asarray(xhat, dtype=cam.basis.dtype))


def project_batch(mean_image: Float[ArrayLike, " D"], basis: Float[ArrayLike, "D K"],
                  images: Real[ArrayLike, "B D"]) -> tuple[Float[Array, "B K"], Bool[Array, " B"]]:
    """Pure batched projection for one position: ``(g [B, K], valid [B])``.

    Rows that are non-finite, negative somewhere, all zero or constant are
    invalid: their ``g`` is 0.
    """
    y_hat, valid = _unit_energy(jnp.asarray(images, dtype=basis.dtype))
    g = (y_hat - mean_image[None, :]) @ basis
    return jnp.where(valid[:, None], g, 0.0), valid


def _unit_energy(y: Float[Array, "*B D"]) -> tuple[Float[Array, "*B D"], Bool[Array, " *B"]]:
    """``y / ||y||`` per image vector (last axis; eq. 4.1-4.2) and its validity:
    vectors that are non-finite, negative somewhere, all zero or constant are
    invalid (and returned as 0).  Each vector is divided by its brightest pixel
    before the norm, so a valid vector's norm lies in ``[1, sqrt(D)]``: no
    overflow (e.g. pixels of 1e30, whose squares are inf in float32), no
    underflow to zero energy."""
    finite = jnp.all(jnp.isfinite(y), axis=-1)
    nonneg = jnp.all(y >= 0, axis=-1)
    usable = finite & nonneg
    y = jnp.where(usable[..., None], y, 0.0)
    peak = jnp.max(y, axis=-1)
    varies = peak > jnp.min(y, axis=-1)
    valid = usable & (peak > 0) & varies
    scaled = y / jnp.where(valid, peak, 1.0)[..., None]
    norm = jnp.linalg.norm(scaled, axis=-1)
    safe = jnp.where(valid, norm, 1.0)
    return jnp.where(valid[..., None], scaled / safe[..., None], 0.0), valid


def project_camera(camera: CameraModel, positions: Int[ArrayLike, " B"],
                   images: Real[ArrayLike, "B H W"]) -> tuple[Float[Array, "B K"], Bool[Array, " B"]]:
    """Pure batched projection of images of one camera at per-image positions
    (gathers each position's mean and basis): ``(g [B, K], valid [B])``."""
    B = images.shape[0]
    y = jnp.asarray(images, dtype=camera.basis.dtype).reshape(B, -1)
    mean = camera.mean_image[positions]           # [B, D]
    basis = camera.basis[positions]               # [B, D, K]
    y_hat, valid = _unit_energy(y)
    g = jnp.einsum("bd,bdk->bk", y_hat - mean, basis)
    return jnp.where(valid[:, None], g, 0.0), valid


def project_at(camera: CameraModel, position: Int[Array, ""],
               image: Shaped[Array, "H W"]) -> tuple[Float[Array, " K"], Bool[Array, ""]]:
    """Pure projection of one image of one camera at ``position`` (traced):
    ``g = V_v^T (y/||y|| - x_v)`` (eq. 4.1-4.11) and its validity (``g = 0``
    when the image is unusable, see :func:`_unit_energy`)."""
    y_hat, valid = _unit_energy(jnp.asarray(image, dtype=camera.basis.dtype).reshape(-1))
    g = (y_hat - camera.mean_image[position]) @ camera.basis[position]
    return jnp.where(valid, g, 0.0), valid


class HostFeatures(NamedTuple):
    """Features of one image set already projected on the host
    (:func:`host_features`): one ``[K_i]`` vector per camera and one validity
    flag, what :func:`project_at` gives per camera inside a program."""

    gs: tuple[Float[ArrayLike, " _K"], ...]
    ok: Bool[ArrayLike, ""]


def host_planes(camera: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """One camera's ``(basis [V, D, K], projected means [V, K])`` for
    :func:`host_features`: the basis a NumPy view of the model's CPU buffer,
    and ``x̄_vᵀ V_v`` per position (made once, in float64)."""
    basis = np.asarray(camera.basis)
    means = np.einsum("vd,vdk->vk", np.asarray(camera.mean_image, np.float64), basis.astype(np.float64))
    return basis, means.astype(basis.dtype)


def host_features(planes: Sequence[tuple[np.ndarray, np.ndarray]], config, images,
                  image_shape: tuple[int, int]) -> HostFeatures | None:
    """:func:`project_at` for every camera with NumPy (eq. 4.1-4.11), or
    ``None`` where it does not apply (a traced or wrongly shaped input: the
    compiled path then sees it, and raises where it should).

    ``planes``: per camera its :func:`host_planes`.  Why: inside a program
    XLA on the CPU first copies the position's basis out of ``[V, D, K]``
    (1.5 MB at thesis size) and then runs its matrix-vector product ~5x
    slower than the host's BLAS: 0.46 ms for two cameras against ~0.1 ms
    here (2-core CPU), half of a single-trial step.  The same checks as
    :func:`_unit_energy` (an image that is non-finite, negative somewhere,
    all zero or constant gives ``g = 0`` and ``ok = False``) and the same
    value, ``g = V_vᵀ y / ||y|| - V_vᵀ x̄_v``, to float32 rounding."""
    if isinstance(config, jax.core.Tracer) or isinstance(images, jax.core.Tracer):
        return None
    one = host_features_batch(planes, np.asarray(config)[None], np.asarray(images)[None], image_shape)
    return None if one is None else HostFeatures(tuple(g[0] for g in one.gs), np.asarray(one.ok[0]))


def _project_row(basis: np.ndarray, means: np.ndarray, v, y: np.ndarray) -> np.ndarray:
    """``g = V_vᵀ y / ||y|| - V_vᵀ x̄_v`` for one usable row ``y`` (one
    matrix-vector product: a row's value does not depend on its batch)."""
    return (y @ basis[v]) * (np.asarray(1, basis.dtype) / np.sqrt(np.dot(y, y))) - means[v]


def _host_shapes(planes, configs: np.ndarray, imgs: np.ndarray, image_shape) -> bool:
    """Whether ``configs [B, n]`` and ``imgs [B, n, H, W]`` are image sets of
    the model's cameras and size, gray levels, and positions each camera has
    (else the program sees them, as before)."""
    n = len(planes)
    return (imgs.ndim == 4 and imgs.shape[1:] == (n, *image_shape) and configs.shape == (len(imgs), n)
            and imgs.dtype.kind in "uif" and configs.dtype.kind in "iu"
            and all(0 <= int(configs[:, i].min(initial=0)) and int(configs[:, i].max(initial=0)) < len(b)
                    for i, (b, _) in enumerate(planes)))


def _usable_rows(y: np.ndarray, dtype) -> tuple[np.ndarray, np.ndarray]:
    """``(rows in dtype, usable [B])`` of image vectors ``y [B, D]``, as
    :func:`_unit_energy` judges them after the same cast to ``dtype``
    (finite, >= 0, not all zero, not constant), each row divided by its peak
    (no overflow of the energy); 8- and 16-bit unsigned rows, exact in
    float32 and without overflow, are checked on their own values and not
    scaled.  Call under ``np.errstate(all="ignore")``."""
    if y.dtype.kind == "u" and y.dtype.itemsize <= 2:
        hi = y.max(1)
        return y.astype(dtype), (hi > 0) & (hi > y.min(1))
    out = y.astype(dtype)
    out[np.abs(out) < np.finfo(dtype).tiny] = 0  # subnormal: zero, as XLA on the CPU reads it
    good = np.isfinite(out).all(1) & (out >= 0).all(1)
    hi = np.where(good, out.max(1), 0)
    good &= (hi > 0) & (hi > out.min(1))
    return out * (np.asarray(1, dtype) / np.where(good, hi, 1).astype(dtype))[:, None], good


def host_features_batch(planes: Sequence[tuple[np.ndarray, np.ndarray]], configs, images,
                        image_shape: tuple[int, int]) -> HostFeatures | None:
    """:func:`host_features` of ``B`` image sets (``configs [B, n]``,
    ``images [B, n, H, W]``): per camera ``g [B, K_i]`` and ``ok [B]``, or
    ``None`` where the inputs are traced or not ``B`` image sets of the
    model's cameras and size.  Each set's features are computed as
    :func:`host_features` computes them, bit for bit: a slot's value does
    not depend on the other slots (the driver's batches are split and
    sharded in different ways, with the same results)."""
    if isinstance(configs, jax.core.Tracer) or isinstance(images, jax.core.Tracer):
        return None
    configs, imgs = np.asarray(configs), np.asarray(images)
    if not _host_shapes(planes, configs, imgs, image_shape):
        return None
    ok, gs = np.ones(len(imgs), bool), []
    with np.errstate(all="ignore"):  # NaN, inf and zero rows are flagged, not computed with
        for i, (basis, means) in enumerate(planes):
            y, good = _usable_rows(imgs[:, i].reshape(len(imgs), -1), basis.dtype)
            g = np.zeros((len(y), basis.shape[-1]), basis.dtype)
            for b in np.flatnonzero(good):  # one product per image set: a slot's value is its own alone
                v = configs[b, i]
                g[b] = _project_row(basis, means, v, y[b])
            gs.append(g)
            ok &= good
    return HostFeatures(tuple(gs), ok)
