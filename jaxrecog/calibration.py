"""Calibrated beliefs: variance inflation of the sensor model fitted on held-out views.

A Gaussian fitted to augmented copies of one training image (eq. 4.23-4.24)
is far too sure of itself on a view taken a little away from the training
view.  Calibration inflates its covariance per camera ``i``, position ``v``
(and optionally occlusion level ``k``) by a factor ``s = exp(θ)``::

    Σ'[v, c, k] = s[v, k] · Σ[v, c, k]          (var · s,  chol · sqrt(s))

through the likelihood's ``scaled(s)`` (:class:`~jaxrecog.kernels.Likelihood`).
For the Gaussians the log-likelihood (eq. 4.18-4.19) becomes, with the squared
Mahalanobis distance ``q = (g - μ)ᵀ Σ⁻¹ (g - μ)`` of the *uncalibrated* model,

    log p'(g | c, k, v) = -q / (2 s) - K/2 · log s - ½ log|2π Σ|,

i.e. a temperature ``1/s`` on the quadratic term.  ``θ[v]`` is the MAP
estimate of the negative log posterior of the true class ``c*`` of each
held-out image ``g_n`` (uniform prior over classes and levels, eq. 3.1)::

    J_v(θ) = 1/N_v · [ Σ_n -log p'(c*_n | g_n, v) + ||θ||² / (2 σ²) ],
    log p'(c | g, v) = logsumexp_k log p'(g | c, k, v) - logsumexp_{c', k} log p'(g | c', k, v)

The Gaussian prior on ``θ = log s`` (sd ``σ = prior_sd``) pulls ``s`` toward 1,
so a position with few images stays near uncalibrated and one with none
stays exactly at 1.  ``J_v`` is minimised with ``optax.lbfgs`` (zoom line
search) in a ``lax.while_loop``, jitted and ``vmap``-ed over positions; the
data enter through the likelihood's ``scaling_terms`` (for the Gaussians
``q [N, C, L]`` and ``log|Σ| [C, L]``), computed once, and its
``scaled_log_density``.

A calibrated model is an ordinary :class:`~jaxrecog.sensor_model.SensorModel`
(``Likelihood.scaled``; for the Gaussians ``var · s``, ``chol · sqrt(s)``), so
every kernel and planner uses it unchanged; the factors are kept in
``CameraModel.calibration`` ``[V, L]`` and saved in the model file (format
version 2).

Public entry for the CLI: :func:`calibrate_model`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from . import kernels as K
from .database import ImageDatabase, load_database
from .features import check_image
from .sensor_model import CameraModel, SensorModel

__all__ = [
    "CameraFeatures",
    "CalibrationFeatures",
    "CalibrationInfo",
    "CalibrationError",
    "features_from_database",
    "holdout_calibration",
    "mahalanobis_terms",
    "fit_factors",
    "apply_calibration",
    "calibration_factors",
    "uncalibrated",
    "calibrate_model",
]


class CalibrationError(ValueError):
    """Calibration data that cannot be used (no images, wrong sizes, bad labels)."""


class CameraFeatures(NamedTuple):
    """Held-out features of one camera.

    Attributes:
        g: ``float [N, K]`` eigenspace features (eq. 4.1-4.11).
        position: ``int [N]`` position index of each feature.
        cls: ``int [N]`` true class ``c = object · n_poses + pose``.
    """

    g: np.ndarray
    position: np.ndarray
    cls: np.ndarray


class CalibrationFeatures(NamedTuple):
    """Held-out features of every camera of a model (one entry per camera)."""

    cameras: tuple[CameraFeatures, ...]


@dataclasses.dataclass(frozen=True)
class CalibrationInfo:
    """What :func:`calibrate_model` fitted, per camera (lists over cameras).

    Attributes:
        factors: ``[V, L]`` variance factors applied this time (per camera).
        iterations: ``[V]`` L-BFGS iterations per position.
        converged: ``[V]`` whether the gradient norm fell below ``tol``.
        nll_before, nll_after: ``[V]`` mean negative log posterior of the true
            class on the calibration images at ``s = 1`` and at the fit
            (positions without images: 0).
        n_images: ``[V]`` calibration images per position.
        settings: the fit's settings (per_level, prior_sd, max_iter, tol).
    """

    factors: tuple[np.ndarray, ...]
    iterations: tuple[np.ndarray, ...]
    converged: tuple[np.ndarray, ...]
    nll_before: tuple[np.ndarray, ...]
    nll_after: tuple[np.ndarray, ...]
    n_images: tuple[np.ndarray, ...]
    settings: dict

    def to_dict(self) -> dict:
        """JSON-serialisable (for the model file's metadata)."""
        def lst(xs):
            return [np.asarray(x).tolist() for x in xs]

        return {
            "factors": lst(self.factors),
            "iterations": lst(self.iterations),
            "converged": lst(self.converged),
            "nll_before": lst(self.nll_before),
            "nll_after": lst(self.nll_after),
            "n_images": lst(self.n_images),
            "settings": dict(self.settings),
        }

    def summary(self) -> str:
        lines = []
        for i, f in enumerate(self.factors):
            n = self.n_images[i]
            used = n > 0
            nb = float(np.sum(self.nll_before[i] * n) / max(n.sum(), 1))
            na = float(np.sum(self.nll_after[i] * n) / max(n.sum(), 1))
            lines.append(
                f"camera {i}: {int(n.sum())} images at {int(used.sum())}/{len(n)} positions, "
                f"factors {f.min():.3g}..{f.max():.3g} (median {np.median(f):.3g}), "
                f"NLL {nb:.3f} -> {na:.3f}, L-BFGS iterations <= {int(self.iterations[i].max())}, "
                f"converged {int(self.converged[i].sum())}/{len(n)}"
            )
        return "\n".join(lines)


# ---------------------------------------------------------------- data


def features_from_database(model: SensorModel, database: ImageDatabase | str | os.PathLike,
                           split: str = "calib") -> CalibrationFeatures:
    """Project the ``split`` rows of an image database with ``model`` (eq. 4.1-4.11).

    Raises:
        CalibrationError: no rows of that split, or sizes that do not match the model.
        jaxrecog.features.ImageError: a bad image (named by its path).
    """
    db = database if isinstance(database, ImageDatabase) else load_database(database)
    rows = db.rows(split)
    if rows.size == 0:
        raise CalibrationError(
            f"database {db._where()}: no '{split}' rows to calibrate on (render a calib split, "
            f"or hold out part of the test split with holdout_calibration)"
        )
    if db.n_poses != model.n_poses or db.n_objects != model.n_objects:
        raise CalibrationError(
            f"database {db._where()}: {db.n_objects} objects x {db.n_poses} poses, the model has "
            f"{model.n_objects} x {model.n_poses}"
        )
    cams = []
    for i, cam in enumerate(model.cameras):
        sel = rows[db.camera[rows] == i]
        if np.any(db.position[sel] >= cam.n_positions):
            bad = sel[db.position[sel] >= cam.n_positions][0]
            raise CalibrationError(f"{db.paths[bad]}: camera {i} position {db.position[bad]} "
                                   f"not in the model ({cam.n_positions} positions)")
        mean = np.asarray(cam.mean_image, np.float64)
        basis = np.asarray(cam.basis, np.float64)
        g = np.zeros((sel.size, cam.n_components))
        for j, r in enumerate(sel):
            y = check_image(db.images[r], model.image_shape, name=db.paths[r]).astype(np.float64)
            v = db.position[r]
            g[j] = (y / np.linalg.norm(y) - mean[v]) @ basis[v]
        cams.append(CameraFeatures(g, db.position[sel].copy(), db.class_index[sel].copy()))
    extra = rows[db.camera[rows] >= model.n_cameras]
    if extra.size:
        raise CalibrationError(f"{db.paths[extra[0]]}: camera {db.camera[extra[0]]} not in the model "
                               f"({model.n_cameras} cameras)")
    return CalibrationFeatures(tuple(cams))


def holdout_calibration(database: ImageDatabase, fraction: float, *, seed: int = 0,
                        source: str = "test") -> ImageDatabase:
    """A copy of ``database`` with a seeded ``fraction`` of its ``source`` rows
    relabelled ``calib`` (held out from evaluation).

    The ``train`` split cannot be the source: the model needs exactly one train
    image per (camera, position, class).
    """
    if source == "train":
        raise CalibrationError("the train split cannot be held out: training needs exactly one "
                               "train image per (camera, position, object, pose); use source='test'")
    if not 0.0 < fraction < 1.0:
        raise CalibrationError(f"fraction must be in (0, 1), got {fraction}")
    rows = database.rows(source)
    if rows.size == 0:
        raise CalibrationError(f"database {database._where()}: no '{source}' rows to hold out")
    rng = np.random.default_rng(seed)
    take = rng.choice(rows, size=max(1, int(round(fraction * rows.size))), replace=False)
    split = database.split.astype(object).copy()
    split[take] = "calib"
    return ImageDatabase.from_arrays(database.images, database.camera, database.position,
                                     database.object, database.pose, split.astype(str),
                                     paths=database.paths, root=database.root)


def _as_features(model: SensorModel, calib, split: str) -> CalibrationFeatures:
    if isinstance(calib, CalibrationFeatures):
        feats = calib
    elif isinstance(calib, (ImageDatabase, str, os.PathLike)):
        return features_from_database(model, calib, split)
    elif isinstance(calib, (tuple, list)) and all(isinstance(c, CameraFeatures) for c in calib):
        feats = CalibrationFeatures(tuple(calib))
    else:
        raise TypeError(f"calibration data must be an ImageDatabase, a folder or CalibrationFeatures, "
                        f"got {type(calib).__name__}")
    if len(feats.cameras) != model.n_cameras:
        raise CalibrationError(f"calibration features for {len(feats.cameras)} camera(s), the model "
                               f"has {model.n_cameras}")
    out = []
    for i, (f, cam) in enumerate(zip(feats.cameras, model.cameras)):
        g = np.asarray(f.g, np.float64)
        pos = np.asarray(f.position)
        cls = np.asarray(f.cls)
        if g.ndim != 2 or g.shape[1] != cam.n_components or pos.shape != (g.shape[0],) \
                or cls.shape != (g.shape[0],):
            raise CalibrationError(f"camera {i}: features {g.shape}, positions {pos.shape}, classes "
                                   f"{cls.shape}; expected [N, {cam.n_components}], [N], [N]")
        if not np.all(np.isfinite(g)):
            raise CalibrationError(f"camera {i}: calibration features contain NaN or inf")
        if pos.size and (pos.min() < 0 or pos.max() >= cam.n_positions):
            raise CalibrationError(f"camera {i}: positions must be in 0..{cam.n_positions - 1}")
        if cls.size and (cls.min() < 0 or cls.max() >= model.n_classes):
            raise CalibrationError(f"camera {i}: classes must be in 0..{model.n_classes - 1}")
        out.append(CameraFeatures(g, pos.astype(np.int64), cls.astype(np.int64)))
    if sum(f.g.shape[0] for f in out) == 0:
        raise CalibrationError("no calibration features")
    return CalibrationFeatures(tuple(out))


# ---------------------------------------------------------------- math


def mahalanobis_terms(mu: Float[ArrayLike, "C L K"], var: Float[ArrayLike, "C L K"],
                      chol: Float[ArrayLike, "C L K K"] | None, g: Float[ArrayLike, "N K"]
                      ) -> tuple[Float[Array, "N C L"], Float[Array, "C L"]]:
    """``q[n, c, k] = (g_n - μ)ᵀ Σ⁻¹ (g_n - μ)`` and ``log|2π Σ|[c, k]`` of one
    position of a Gaussian (diagonal ``var`` or, given ``chol``, full
    covariance): its ``scaling_terms``.  ``log p(g|c,k) = -(q + log|2πΣ|) / 2``
    (eq. 4.18-4.19)."""
    return K.gaussian(mu, var, chol).scaling_terms(g)


def _neg_log_posterior(theta: Float[Array, " P"], lik: K.Likelihood, terms,
                       true_cls: Int[Array, " N"], mask: Bool[Array, " N"]) -> Float[Array, " N"]:
    """``-log p'(c*_n | g_n)`` per image under factors ``exp(theta)`` (broadcast to L),
    for one position's likelihood ``lik`` and its ``scaling_terms``."""
    th = jnp.broadcast_to(theta, (lik.n_levels,))
    ll = lik.scaled_log_density(terms, th)                               # [N, C, L]
    log_c = jax.nn.logsumexp(ll, axis=-1)                                # [N, C]
    log_post = jnp.take_along_axis(log_c, true_cls[:, None], axis=1)[:, 0] - \
        jax.nn.logsumexp(log_c, axis=-1)
    return jnp.where(mask, -log_post, 0.0)


@eqx.filter_jit
def _fit_positions(lik, terms, true_cls, mask, prior_sd, max_iter, tol, log_min, *, n_params: int):
    """vmap over positions (of the camera's likelihood ``lik`` and its
    ``scaling_terms``) of the L-BFGS fit: ``(theta [V, P], iters [V],
    converged [V], nll0 [V], nll1 [V])``.  ``prior_sd``, ``max_iter``, ``tol``,
    ``log_min`` are traced scalars (changing them does not recompile).  The
    unconstrained optimum is clipped to ``theta >= log_min`` afterwards (exact
    for one factor per position, where ``J_v`` is unimodal in practice)."""

    def fit_one(lik, terms, true_cls, mask):
        dtype = lik.dtype
        n = jnp.maximum(jnp.sum(mask), 1).astype(dtype)

        def loss(theta):
            nll = _neg_log_posterior(theta, lik, terms, true_cls, mask)
            return (jnp.sum(nll) + 0.5 * jnp.sum(theta * theta) / prior_sd**2) / n

        opt = optax.lbfgs()   # zoom line search (a backtracking one stalls near the optimum in float32)
        value_and_grad = optax.value_and_grad_from_state(loss)
        theta0 = jnp.zeros((n_params,), dtype)

        def body(carry):
            theta, state, it = carry
            value, grad = value_and_grad(theta, state=state)
            updates, state = opt.update(grad, state, theta, value=value, grad=grad, value_fn=loss)
            return optax.apply_updates(theta, updates), state, it + 1

        def cond(carry):
            theta, state, it = carry
            grad = optax.tree_utils.tree_get(state, "grad")
            gnorm = jnp.linalg.norm(grad)
            return (it == 0) | ((it < max_iter) & (gnorm >= tol))

        theta, state, it = jax.lax.while_loop(cond, body, (theta0, opt.init(theta0), jnp.asarray(0)))
        gnorm = jnp.linalg.norm(jax.grad(loss)(theta))
        theta = jnp.maximum(theta, log_min)
        nll0 = jnp.sum(_neg_log_posterior(theta0, lik, terms, true_cls, mask)) / n
        nll1 = jnp.sum(_neg_log_posterior(theta, lik, terms, true_cls, mask)) / n
        return theta, it, gnorm < tol, nll0, nll1

    return jax.vmap(fit_one)(lik, terms, true_cls, mask)


def fit_factors(camera: CameraModel, features: CameraFeatures, *, per_level: bool = False,
                prior_sd: float = 1.0, max_iter: int = 100, tol: float = 1e-5,
                min_factor: float | None = 1.0):
    """Fit one camera's variance factors ``s [V, L]`` (module docstring).

    Args:
        camera: the camera's (possibly already calibrated) model.
        features: its held-out features.
        per_level: one factor per (position, level) instead of per position.
        prior_sd: sd ``σ`` of the Gaussian prior on ``log s``.
        max_iter, tol: L-BFGS iteration cap and gradient-norm tolerance (on the
            per-image mean objective).
        min_factor: lower bound on ``s`` (default 1: inflate only, never make the
            model surer than trained); ``None`` = unbounded.

    Returns:
        ``(s [V, L], iterations [V], converged [V], nll_before [V], nll_after [V], n_images [V])``
        as NumPy arrays.
    """
    if not prior_sd > 0 or not max_iter >= 1 or not tol > 0 or not (min_factor is None or min_factor > 0):
        raise ValueError(f"need prior_sd > 0, max_iter >= 1, tol > 0, min_factor > 0 or None "
                         f"(got {prior_sd}, {max_iter}, {tol}, {min_factor})")
    lik = camera.likelihood
    V, L, dim = camera.n_positions, lik.n_levels, lik.dim
    counts = np.bincount(features.position, minlength=V)
    n_max = 1 << max(int(counts.max()) - 1, 0).bit_length()   # power of two: fewer recompiles
    # group by position into padded [V, n_max] slots
    order = np.argsort(features.position, kind="stable")
    pos = features.position[order]
    slot = np.arange(pos.size) - np.searchsorted(pos, pos)
    idx = np.zeros((V, n_max), np.int64)
    mask = np.zeros((V, n_max), bool)
    idx[pos, slot] = order
    mask[pos, slot] = True
    dtype = lik.dtype
    g = jnp.asarray(features.g, dtype)[idx] if features.g.shape[0] else jnp.zeros((V, n_max, dim), dtype)
    cls = jnp.asarray(features.cls[idx] if features.cls.size else np.zeros((V, n_max), np.int64))
    terms = jax.vmap(lambda lik_v, g_v: lik_v.scaling_terms(g_v))(lik, g)
    theta, it, conv, nll0, nll1 = _fit_positions(
        lik, terms, cls, jnp.asarray(mask), jnp.asarray(prior_sd, dtype), jnp.asarray(int(max_iter)),
        jnp.asarray(tol, dtype), jnp.asarray(-jnp.inf if min_factor is None else math.log(min_factor), dtype),
        n_params=L if per_level else 1)
    s = np.broadcast_to(np.exp(np.asarray(theta, np.float64)), (V, L)).astype(np.float32)
    if not np.all(np.isfinite(s)):
        raise FloatingPointError("calibration diverged (non-finite factor)")
    return (s, np.asarray(it), np.asarray(conv), np.asarray(nll0, np.float64),
            np.asarray(nll1, np.float64), counts)


# ---------------------------------------------------------------- apply


def calibration_factors(model: SensorModel) -> tuple[np.ndarray, ...]:
    """Each camera's accumulated factors ``[V, L]`` (ones when uncalibrated)."""
    return tuple(np.ones((c.n_positions, model.n_levels), np.float32) if c.calibration is None
                 else np.asarray(c.calibration) for c in model.cameras)


def apply_calibration(model: SensorModel, factors: Sequence) -> SensorModel:
    """A new model whose likelihoods are ``scaled(s)`` per position (the
    Gaussians: ``var · s`` and ``chol · sqrt(s)``) per camera.

    ``factors[i]`` is ``[V_i, L]``, ``[V_i]`` or a scalar (broadcast), all > 0.
    The stored ``calibration`` becomes the product with any earlier factors.
    """
    if len(factors) != model.n_cameras:
        raise ValueError(f"{len(factors)} factor arrays for {model.n_cameras} cameras")
    cams = []
    for i, (cam, f) in enumerate(zip(model.cameras, factors)):
        V, L = cam.n_positions, model.n_levels
        f = np.asarray(f, np.float32)
        if f.ndim == 1:
            f = f[:, None]
        try:
            s = np.broadcast_to(f, (V, L))
        except ValueError:
            raise ValueError(f"camera {i}: factors of shape {f.shape}, expected [{V}, {L}]") from None
        if not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise ValueError(f"camera {i}: factors must be finite and > 0")
        sj = jnp.asarray(s, cam.likelihood.dtype)
        lik = jax.vmap(lambda lik_v, s_v: lik_v.scaled(s_v))(cam.likelihood, sj)
        total = sj if cam.calibration is None else cam.calibration * sj
        cams.append(dataclasses.replace(cam, likelihood=lik, calibration=total))
    return eqx.tree_at(lambda m: m.cameras, model, tuple(cams))


def uncalibrated(model: SensorModel) -> SensorModel:
    """The model with its calibration undone (``calibration = None``)."""
    if all(c.calibration is None for c in model.cameras):
        return model
    inv = [1.0 / f for f in calibration_factors(model)]
    out = apply_calibration(model, inv)
    cams = tuple(dataclasses.replace(c, calibration=None) for c in out.cameras)
    return eqx.tree_at(lambda m: m.cameras, out, cams)


def calibrate_model(model: SensorModel, calib, *, per_level: bool = False, prior_sd: float = 1.0,
                    max_iter: int = 100, tol: float = 1e-5, min_factor: float | None = 1.0,
                    split: str = "calib") -> tuple[SensorModel, CalibrationInfo]:
    """Fit variance factors on held-out views and return the calibrated model.

    Args:
        model: a trained (possibly already calibrated) :class:`SensorModel`.
        calib: an :class:`~jaxrecog.database.ImageDatabase` or its folder (its
            ``split`` rows are used), or :class:`CalibrationFeatures`.
        per_level: one factor per (position, occlusion level) instead of per position.
        prior_sd: sd of the Gaussian prior on ``log s`` (smaller = stay nearer 1).
        max_iter, tol: L-BFGS cap and gradient-norm tolerance.
        min_factor: lower bound on the factors (default 1: inflation only); ``None`` = unbounded.
        split: which rows of a database to use.

    Returns:
        ``(calibrated model, CalibrationInfo)``; the model's ``calibration``
        holds the accumulated factors, ``info.factors`` this fit's.
    """
    feats = _as_features(model, calib, split)
    res = [fit_factors(cam, f, per_level=per_level, prior_sd=prior_sd, max_iter=max_iter, tol=tol,
                       min_factor=min_factor)
           for cam, f in zip(model.cameras, feats.cameras)]
    out = apply_calibration(model, [r[0] for r in res])
    info = CalibrationInfo(
        factors=tuple(r[0] for r in res), iterations=tuple(r[1] for r in res),
        converged=tuple(r[2] for r in res), nll_before=tuple(r[3] for r in res),
        nll_after=tuple(r[4] for r in res), n_images=tuple(r[5] for r in res),
        settings={"per_level": per_level, "prior_sd": prior_sd, "max_iter": max_iter, "tol": tol,
                  "min_factor": min_factor, "split": split},
    )
    return out, info
