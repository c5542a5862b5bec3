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

Shape parameters.  A family may have per-level shape parameters beside its
dispersion (``Likelihood.calibration_shapes``; the Student-t: its degrees of
freedom ``nu``, as an offset ``δ`` on ``log(ν - 2)``).  Then ``θ`` also holds
``δ`` (one per position, or per level with ``per_level``), with the same
Gaussian prior (sd ``σ``, pulling ``δ`` toward 0, the trained value), and the
objective reads the family's ``calibrated_log_density(terms, θ_s, δ)``.  The
bound ``s >= min_factor`` applies to the variance factors only: when the
unconstrained optimum violates it, the factors are clipped and ``δ`` is
re-fitted with them held.  The fitted offsets are applied by
``Likelihood.shape_shifted`` and reported in :class:`CalibrationInfo`
(``shape``); ``uncalibrated`` undoes the variance factors only (the fitted
``ν`` is the model's own parameter from then on).

A calibrated model is an ordinary :class:`~jaxrecog.sensor_model.SensorModel`
(``Likelihood.scaled``; for the Gaussians ``var · s``, ``chol · sqrt(s)``), so
every kernel and planner uses it unchanged; the factors are kept in
``CameraModel.calibration`` ``[V, L]`` and saved in the model file (format
version 2).

Public entry for the CLI: :func:`calibrate_model`.  The held-out features
(:func:`features_from_database`, :func:`holdout_calibration`) live in
:mod:`jaxrecog.calibration_data` and are re-exported here.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from . import kernels as K
from .calibration_data import (CalibrationError, CalibrationFeatures, CameraFeatures,  # noqa: F401 (re-exported)
                               checked_features, features_from_database, holdout_calibration)
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
    "fit_camera",
    "CameraFit",
    "apply_shape",
    "apply_calibration",
    "calibration_factors",
    "uncalibrated",
    "calibrate_model",
    "pooled_log_factors",
]


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
        shape: ``[V, L, P]`` shape offsets applied this time (per camera; ``P = 0``
            for a family without shape parameters), see the module docstring.
        shape_names: the names of the ``P`` shape parameters, per camera.
    """

    factors: tuple[np.ndarray, ...]
    iterations: tuple[np.ndarray, ...]
    converged: tuple[np.ndarray, ...]
    nll_before: tuple[np.ndarray, ...]
    nll_after: tuple[np.ndarray, ...]
    n_images: tuple[np.ndarray, ...]
    settings: dict
    shape: tuple[np.ndarray, ...] = ()
    shape_names: tuple[tuple[str, ...], ...] = ()

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
            "shape": lst(self.shape),
            "shape_names": [list(x) for x in self.shape_names],
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
                f"factors {f.min():.3g}..{f.max():.3g} (median {np.median(f):.3g}"
                f"{', pooled per camera' if self.settings.get('pool') else ''}), "
                f"NLL {nb:.3f} -> {na:.3f}, L-BFGS iterations <= {int(self.iterations[i].max())}, "
                f"converged {int(self.converged[i].sum())}/{len(n)}"
            )
            if i < len(self.shape) and self.shape[i].size:
                sh = self.shape[i]
                for j, name in enumerate(self.shape_names[i]):
                    lines.append(f"camera {i}: {name} offsets (on its unconstrained scale) "
                                 f"{sh[..., j].min():.3g}..{sh[..., j].max():.3g}")
        return "\n".join(lines)


# ---------------------------------------------------------------- math (the data: calibration_data.py)


def mahalanobis_terms(mu: Float[ArrayLike, "C L K"], var: Float[ArrayLike, "C L K"],
                      chol: Float[ArrayLike, "C L K K"] | None, g: Float[ArrayLike, "N K"]
                      ) -> tuple[Float[Array, "N C L"], Float[Array, "C L"]]:
    """``q[n, c, k] = (g_n - μ)ᵀ Σ⁻¹ (g_n - μ)`` and ``log|2π Σ|[c, k]`` of one
    position of a Gaussian (diagonal ``var`` or, given ``chol``, full
    covariance): its ``scaling_terms``.  ``log p(g|c,k) = -(q + log|2πΣ|) / 2``
    (eq. 4.18-4.19)."""
    return K.gaussian(mu, var, chol).scaling_terms(g)


def _split_theta(theta: Float[Array, " P"], n_levels: int, n_shape: int):
    """``theta [(1 + S) G]`` (``G`` = 1 or L groups, ``S`` shape parameters) ->
    ``(log factors [L], shape offsets [L, S])``."""
    t = theta.reshape(1 + n_shape, theta.shape[0] // (1 + n_shape))
    return jnp.broadcast_to(t[0], (n_levels,)), jnp.broadcast_to(t[1:].T, (n_levels, n_shape))


def _neg_log_posterior(theta: Float[Array, " P"], lik: K.Likelihood, terms,
                       true_cls: Int[Array, " N"], mask: Bool[Array, " N"], n_shape: int = 0) -> Float[Array, " N"]:
    """``-log p'(c*_n | g_n)`` per image under factors ``exp(theta)`` (broadcast to L)
    and, with ``n_shape`` shape parameters, the shape offsets in ``theta``
    (:func:`_split_theta`), for one position's likelihood ``lik`` and its ``scaling_terms``."""
    if n_shape:
        th, shape = _split_theta(theta, lik.n_levels, n_shape)
        ll = lik.calibrated_log_density(terms, th, shape)                # [N, C, L]
    else:
        th = jnp.broadcast_to(theta, (lik.n_levels,))
        ll = lik.scaled_log_density(terms, th)                           # [N, C, L]
    log_c = jax.nn.logsumexp(ll, axis=-1)                                # [N, C]
    log_post = jnp.take_along_axis(log_c, true_cls[:, None], axis=1)[:, 0] - \
        jax.nn.logsumexp(log_c, axis=-1)
    return jnp.where(mask, -log_post, 0.0)


def _lbfgs(loss, x0, max_iter, tol):
    """Minimise ``loss`` from ``x0`` with ``optax.lbfgs`` in a ``lax.while_loop``:
    ``(x, iterations)``."""
    opt = optax.lbfgs()   # zoom line search (a backtracking one stalls near the optimum in float32)
    value_and_grad = optax.value_and_grad_from_state(loss)

    def body(carry):
        x, state, it = carry
        value, grad = value_and_grad(x, state=state)
        updates, state = opt.update(grad, state, x, value=value, grad=grad, value_fn=loss)
        return optax.apply_updates(x, updates), state, it + 1

    def cond(carry):
        x, state, it = carry
        grad = optax.tree_utils.tree_get(state, "grad")
        gnorm = jnp.linalg.norm(grad)
        return (it == 0) | ((it < max_iter) & (gnorm >= tol))

    x, _, it = jax.lax.while_loop(cond, body, (x0, opt.init(x0), jnp.asarray(0)))
    return x, it


@eqx.filter_jit
def _fit_positions(lik, terms, true_cls, mask, prior_sd, max_iter, tol, log_min, *, n_params: int,
                   n_shape: int = 0):
    """vmap over positions (of the camera's likelihood ``lik`` and its
    ``scaling_terms``) of the L-BFGS fit: ``(theta [V, P], iters [V],
    converged [V], nll0 [V], nll1 [V], free [V, G], info [V, G])`` (``free``:
    the unconstrained log factors, ``info``: 1 / their posterior variances,
    NaN where not positive; :func:`pooled_log_factors`), ``P = n_params`` (``(1 + n_shape)``
    groups: the log factors, then each shape offset).  ``prior_sd``,
    ``max_iter``, ``tol``, ``log_min`` are traced scalars (changing them does
    not recompile).  The unconstrained optimum's log factors are clipped to
    ``>= log_min`` afterwards (exact for one factor per position, where ``J_v``
    is unimodal in practice); with shape offsets, those are then re-fitted
    with the clipped factors held."""
    groups = n_params // (1 + n_shape)

    def fit_one(lik, terms, true_cls, mask):
        dtype = lik.dtype
        n = jnp.maximum(jnp.sum(mask), 1).astype(dtype)

        def loss(theta):
            nll = _neg_log_posterior(theta, lik, terms, true_cls, mask, n_shape)
            return (jnp.sum(nll) + 0.5 * jnp.sum(theta * theta) / prior_sd**2) / n

        theta0 = jnp.zeros((n_params,), dtype)
        theta, it = _lbfgs(loss, theta0, max_iter, tol)
        free = theta[:groups]
        # each log factor's posterior variance at the unconstrained optimum, under the
        # fit's own weak prior: the diagonal of the inverse Hessian of the whole negative
        # log posterior (n x the per-image mean; the shape offsets, if any, are correlated
        # with it).  With the prior's share taken out, a position whose views say little
        # about its factor (all classified with a wide margin) got the pool's value: on
        # the rig's jitter case every position 4.59 and 93.75 % (docs/results.md)
        h = n * jax.hessian(loss)(theta)
        var = jnp.diagonal(jnp.linalg.inv(h))[:groups]
        curv = jnp.where(var > 0, 1.0 / var, jnp.nan)
        scale = jnp.maximum(free, log_min)
        if n_shape:
            shape, it2 = _lbfgs(lambda sh: loss(jnp.concatenate([scale, sh])), theta[groups:], max_iter, tol)
            theta, it = jnp.concatenate([scale, shape]), it + it2
            gnorm = jnp.linalg.norm(jax.grad(lambda sh: loss(jnp.concatenate([scale, sh])))(shape))
        else:
            gnorm = jnp.linalg.norm(jax.grad(loss)(theta))
            theta = scale
        nll0 = jnp.sum(_neg_log_posterior(theta0, lik, terms, true_cls, mask, n_shape)) / n
        nll1 = jnp.sum(_neg_log_posterior(theta, lik, terms, true_cls, mask, n_shape)) / n
        return theta, it, gnorm < tol, nll0, nll1, free, curv

    return jax.vmap(fit_one)(lik, terms, true_cls, mask)


@eqx.filter_jit
def _mean_nll(lik, terms, true_cls, mask, theta, *, n_shape: int = 0):
    """``[V]`` mean ``-log p'(c* | g)`` per position under ``theta [V, P]``
    (:func:`_neg_log_posterior`), e.g. for factors pooled after the fit."""
    def one(lik, terms, true_cls, mask, th):
        n = jnp.maximum(jnp.sum(mask), 1).astype(lik.dtype)
        return jnp.sum(_neg_log_posterior(th, lik, terms, true_cls, mask, n_shape)) / n

    return jax.vmap(one)(lik, terms, true_cls, mask, theta)


class CameraFit(NamedTuple):
    """One camera's calibration fit (:func:`fit_camera`), NumPy arrays.

    Attributes:
        factors: ``[V, L]`` variance factors ``s``.
        shape: ``[V, L, P]`` shape offsets (``P = 0`` without shape parameters).
        iterations, converged, nll_before, nll_after, n_images: ``[V]`` (see
            :class:`CalibrationInfo`).
    """

    factors: np.ndarray
    shape: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    nll_before: np.ndarray
    nll_after: np.ndarray
    n_images: np.ndarray


#: elements of a family's per-feature intermediates (``V x chunk x C x L x K`` for the
#: Gaussians) that :func:`_scaling_terms` lets one product hold: 64 MB of float32
_TERMS_BUDGET = 1 << 24


def _scaling_terms(lik: K.Likelihood, g: Float[Array, "V N K"], budget: int = _TERMS_BUDGET):
    """``vmap`` over positions of ``lik.scaling_terms(g[v])``, bit for bit, in
    chunks of the ``N`` features (a power of two): the Gaussians' ``[V, N, C,
    L, K]`` differences, 1.2 GB (held three times over) at 200 objects x 4
    poses, 18 positions and ``N`` = 1024, are made ``budget`` elements at a
    time.  The terms with an ``N`` axis (found by their shapes at two ``N``)
    are concatenated along it, the others (``log|2πΣ|``) taken once."""
    terms_of = jax.vmap(lambda lik_v, g_v: lik_v.scaling_terms(g_v))
    V, N, dim = g.shape
    per_feature = V * lik.n_classes * lik.n_levels * dim
    chunk = 1 << max(0, (budget // max(per_feature, 1)).bit_length() - 1)
    if chunk >= N or N % chunk:
        return terms_of(lik, g)
    full = jax.tree_util.tree_leaves(jax.eval_shape(terms_of, lik, g))
    host = np.asarray(g)   # sliced on the host: a device slice compiles once per offset
    parts = [terms_of(lik, jnp.asarray(host[:, j:j + chunk])) for j in range(0, N, chunk)]
    flat = [jax.tree_util.tree_leaves(p) for p in parts]
    out = []
    for i, want in enumerate(full):
        got = flat[0][i].shape
        axis = next((a for a, (x, y) in enumerate(zip(want.shape, got)) if x != y), None)
        out.append(flat[0][i] if axis is None else jnp.concatenate([f[i] for f in flat], axis=axis))
    return jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(parts[0]), out)


def pooled_log_factors(theta: Float[ArrayLike, "V G"], curvature: Float[ArrayLike, "V G"],
                       n_images: Int[ArrayLike, " V"]) -> np.ndarray:
    """Per-position log factors ``θ[v, g]`` shrunk toward their camera's
    pooled value (a random-effects estimate, DerSimonian & Laird 1986), per
    group ``g`` (one, or one per level).

    Each position's ``θ_v`` is its own (unconstrained) fit, with sampling
    variance ``e_v² = 1 / H_v`` from the curvature ``H_v`` of its negative log
    posterior.  With the fixed-effect weights ``w_v = 1 / e_v²`` over the ``m``
    positions that have images::

        θ_FE = Σ w θ / Σ w,   Q = Σ w (θ - θ_FE)²,
        τ² = max(0, (Q - (m - 1)) / (Σ w - Σ w² / Σ w))          (spread between positions)
        θ̄ = Σ w* θ / Σ w*,   w*_v = 1 / (e_v² + τ²)
        θ'_v = θ̄ + τ² / (τ² + e_v²) · (θ_v - θ̄)

    A position whose few images say little (large ``e_v``) keeps little of its
    own value; with no spread beyond the sampling noise (``τ² = 0``) every
    position takes ``θ̄``; a position without images, or whose images carry no
    information on ``θ`` (curvature not positive or not finite), takes ``θ̄``.
    Fewer than two positions with information: ``θ`` unchanged.  A position
    with images and a non-finite ``θ`` stays non-finite (the caller's check
    says the fit diverged).  :func:`fit_camera` gives ``θ_v`` as the fit's MAP
    estimate under its weak prior ``N(0, prior_sd²)`` and ``1 / H_v`` as its
    posterior variance: a position whose views say little about its factor
    stays near 1 and counts as such (the prior's share is not taken out).
    """
    theta = np.array(theta, np.float64)
    curvature = np.asarray(curvature, np.float64)
    out = theta.copy()
    images = np.asarray(n_images) > 0
    for g in range(theta.shape[1]):
        th, h = theta[:, g], curvature[:, g]
        have = images & np.isfinite(th) & np.isfinite(h) & (h > 0)
        if have.sum() < 2:
            continue
        e2, t = 1.0 / h[have], th[have]
        w = 1.0 / e2
        fixed = np.sum(w * t) / np.sum(w)
        q = np.sum(w * (t - fixed) ** 2)
        tau2 = max(0.0, (q - (t.size - 1)) / (np.sum(w) - np.sum(w * w) / np.sum(w)))
        ws = 1.0 / (e2 + tau2)
        mean = np.sum(ws * t) / np.sum(ws)
        out[:, g] = np.where(images & ~np.isfinite(th), th, mean)
        out[have, g] = mean + tau2 / (tau2 + e2) * (t - mean)
    return out


def fit_camera(camera: CameraModel, features: CameraFeatures, *, per_level: bool = False,
               prior_sd: float = 1.0, max_iter: int = 100, tol: float = 1e-5,
               min_factor: float | None = 1.0, fit_shape: bool = True, pool: bool = False) -> CameraFit:
    """Fit one camera's variance factors ``s [V, L]`` and, with ``fit_shape``,
    its likelihood's shape offsets (module docstring).

    Args:
        camera: the camera's (possibly already calibrated) model.
        features: its held-out features.
        per_level: one factor (and shape offset) per (position, level) instead of per position.
        prior_sd: sd ``σ`` of the Gaussian prior on ``log s`` and the shape offsets.
        max_iter, tol: L-BFGS iteration cap and gradient-norm tolerance (on the
            per-image mean objective).
        min_factor: lower bound on ``s`` (default 1: inflate only, never make the
            model surer than trained); ``None`` = unbounded.
        fit_shape: fit the family's ``calibration_shapes`` too (none for the Gaussians).
        pool: shrink each position's factor toward the camera's pooled factor
            (:func:`pooled_log_factors`), so a position whose few held-out
            images happen to fit badly is not inflated alone; a position
            without images takes the pooled factor.  The shape offsets stay
            those fitted beside the positions' own factors.
    """
    if not prior_sd > 0 or not max_iter >= 1 or not tol > 0 or not (min_factor is None or min_factor > 0):
        raise ValueError(f"need prior_sd > 0, max_iter >= 1, tol > 0, min_factor > 0 or None "
                         f"(got {prior_sd}, {max_iter}, {tol}, {min_factor})")
    lik = camera.likelihood
    V, L, dim = camera.n_positions, lik.n_levels, lik.dim
    n_shape = len(lik.calibration_shapes) if fit_shape else 0
    groups = L if per_level else 1
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
    # gathered on the host and put on the device as they are (an eager
    # gather or cast compiles a program per shape)
    g = np.asarray(features.g, dtype)[idx] if features.g.shape[0] else np.zeros((V, n_max, dim), dtype)
    g = jax.device_put(g)
    cls = jax.device_put(np.asarray(features.cls[idx] if features.cls.size else np.zeros((V, n_max)), np.int32))
    terms = _scaling_terms(lik, g)
    mask = jax.device_put(mask)
    log_min = -math.inf if min_factor is None else math.log(min_factor)
    theta, it, conv, nll0, nll1, free, curv = _fit_positions(
        lik, terms, cls, mask, jnp.asarray(prior_sd, dtype), jnp.asarray(int(max_iter)),
        jnp.asarray(tol, dtype), jnp.asarray(log_min, dtype),
        n_params=groups * (1 + n_shape), n_shape=n_shape)
    theta = np.array(theta, np.float64).reshape(V, 1 + n_shape, groups)   # a copy: written below
    if pool:
        theta[:, 0] = np.maximum(pooled_log_factors(np.asarray(free, np.float64), np.asarray(curv, np.float64),
                                                    counts), log_min)
        nll1 = _mean_nll(lik, terms, cls, mask, jnp.asarray(theta.reshape(V, -1), dtype), n_shape=n_shape)
    s = np.broadcast_to(np.exp(theta[:, 0]), (V, L)).astype(np.float32)
    shape = np.broadcast_to(np.swapaxes(theta[:, 1:], 1, 2), (V, L, n_shape)).astype(np.float32)
    if not np.all(np.isfinite(s)) or not np.all(np.isfinite(shape)):
        raise FloatingPointError("calibration diverged (non-finite factor)")
    return CameraFit(s, shape, np.asarray(it), np.asarray(conv), np.asarray(nll0, np.float64),
                     np.asarray(nll1, np.float64), counts)


def fit_factors(camera: CameraModel, features: CameraFeatures, *, per_level: bool = False,
                prior_sd: float = 1.0, max_iter: int = 100, tol: float = 1e-5,
                min_factor: float | None = 1.0):
    """Fit one camera's variance factors ``s [V, L]`` alone (:func:`fit_camera`
    without shape parameters).

    Returns:
        ``(s [V, L], iterations [V], converged [V], nll_before [V], nll_after [V], n_images [V])``
        as NumPy arrays.
    """
    f = fit_camera(camera, features, per_level=per_level, prior_sd=prior_sd, max_iter=max_iter, tol=tol,
                   min_factor=min_factor, fit_shape=False)
    return f.factors, f.iterations, f.converged, f.nll_before, f.nll_after, f.n_images


def apply_shape(model: SensorModel, shapes: Sequence) -> SensorModel:
    """A new model whose likelihoods are ``shape_shifted(shapes[i][v])`` per
    camera ``i`` and position ``v`` (``[V_i, L, P_i]``; ``P_i = 0``: unchanged)."""
    if len(shapes) != model.n_cameras:
        raise ValueError(f"{len(shapes)} shape arrays for {model.n_cameras} cameras")
    cams = []
    for cam, sh in zip(model.cameras, shapes):
        sh = np.asarray(sh, np.float32)
        if sh.size:
            shj = jnp.asarray(sh, cam.likelihood.dtype)
            cam = dataclasses.replace(cam, likelihood=jax.vmap(lambda lik_v, s_v: lik_v.shape_shifted(s_v))(
                cam.likelihood, shj))
        cams.append(cam)
    return eqx.tree_at(lambda m: m.cameras, model, tuple(cams))


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
                    split: str = "calib", fit_shape: bool = True, pool: bool = False
                    ) -> tuple[SensorModel, CalibrationInfo]:
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
        fit_shape: also fit the likelihood's shape parameters (Student-t: ``ν``).
        pool: shrink the positions' factors toward each camera's pooled one
            (:func:`pooled_log_factors`; recipe part ``calib_pool``).

    Returns:
        ``(calibrated model, CalibrationInfo)``; the model's ``calibration``
        holds the accumulated factors, ``info.factors`` this fit's.
    """
    feats = checked_features(model, calib, split)
    res = [fit_camera(cam, f, per_level=per_level, prior_sd=prior_sd, max_iter=max_iter, tol=tol,
                      min_factor=min_factor, fit_shape=fit_shape, pool=pool)
           for cam, f in zip(model.cameras, feats.cameras)]
    out = apply_shape(apply_calibration(model, [r.factors for r in res]), [r.shape for r in res])
    info = CalibrationInfo(
        factors=tuple(r.factors for r in res), iterations=tuple(r.iterations for r in res),
        converged=tuple(r.converged for r in res), nll_before=tuple(r.nll_before for r in res),
        nll_after=tuple(r.nll_after for r in res), n_images=tuple(r.n_images for r in res),
        settings={"per_level": per_level, "prior_sd": prior_sd, "max_iter": max_iter, "tol": tol,
                  "min_factor": min_factor, "split": split, "fit_shape": fit_shape, "pool": pool},
        shape=tuple(r.shape for r in res),
        shape_names=tuple(tuple(c.likelihood.calibration_shapes) if fit_shape else () for c in model.cameras),
    )
    return out, info
