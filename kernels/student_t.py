"""A robust sensor model: the multivariate Student-t with a diagonal scale
(a likelihood that stays honest off the training grid).

    p(g | c, k, v) = t_nu(g; mu, diag(s2))
    log p = lgamma((nu + K)/2) - lgamma(nu/2) - K/2 log(nu pi) - 1/2 sum_d log s2_d
            - (nu + K)/2 log(1 + q / nu),        q = sum_d (g_d - mu_d)^2 / s2_d

with ``mu = mu[v, c, k]``, ``s2 = scale2[v, c, k]`` and ``nu = nu[v, k]`` (one
number of degrees of freedom per position and occlusion level, shared by the
classes).  For ``nu -> inf`` it is the thesis's diagonal Gaussian (eq. 4.22).

Why the *multivariate* t and not K independent 1-D t's: it is a Gaussian
scale mixture, ``g = mu + diag(s) x / sqrt(w / nu)`` with ``x ~ N(0, I)`` and
one ``w ~ chi2_nu`` per draw, so one unmodelled deviation (an occluder, a view
between training positions) inflates ``q`` for *every* class alike and the
log-likelihood grows like ``(nu + K)/2 log q`` instead of ``q / 2``: the
differences between classes, hence the posterior, stay bounded.  It keeps the
Mahalanobis structure the calibration uses (``scaling_terms`` = ``q`` and
``log|s2|``, as for the Gaussians), and the sampler needs one extra normal
number per draw, not one per dimension.

Moments: ``E g = mu``, ``Cov g = nu / (nu - 2) diag(s2)`` (``nu > 2``; the
model file rejects ``nu <= 2``, so every component has a finite covariance,
which the planners' summaries and the variance inflation assume).

Fit (:meth:`StudentT.fit`): ``mu`` = the sample mean; the scale is moment
matched, ``s2 = max(var, floor) (nu - 2) / nu``, so the covariance equals the
diagonal Gaussian's (eq. 4.24) whatever ``nu``; ``nu`` is given
(``nu=5.0``) or ``"auto"``: per level, the value of :data:`NU_GRID` with the
highest log-likelihood of the held-out fifth of the training samples
(:meth:`StudentT.holdout_fraction`; training keeps them out of the moments).
Held-out *augmented* samples only see the augmentation's tails (shifts,
noise, occluders); calibration on held-out *views* moves ``nu`` further
(``calibration_shapes``: an offset on ``log(nu - 2)``, fitted with the
variance factor by :mod:`jaxrecog.calibration`).

Sampling from standard normals (``noise_dim = K + 1``): ``x = z[:K]``, and
``w = F^-1_{chi2_nu}(Phi(u))`` from ``u = z[K]``, the exact quantile transform
(computed by :func:`chi2_from_normal`: a Wilson-Hilferty start and Newton
steps on the log tail probability).  Common random numbers survive: the same
``z`` gives the same draw at every position, smoothly in ``nu``.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammainc, gammaincc, gammaln, log_ndtr
from jaxtyping import Array, ArrayLike, Float

from .likelihood import Likelihood, register_likelihood

__all__ = ["StudentT", "NU_GRID", "DEFAULT_NU", "chi2_from_normal", "student_t_log_density"]

NU_GRID: tuple[float, ...] = (2.5, 3.0, 4.0, 5.0, 7.0, 10.0, 15.0, 25.0, 50.0)
"""Degrees of freedom tried by ``nu="auto"`` (held-out log-likelihood per level).
Capped at 50: above it the t is a Gaussian for typical deviations, and the
log-likelihood is so flat in ``nu`` that calibration's offset on
``log(nu - 2)`` gets almost no gradient; from at most 50 it can still move
``nu`` down to what held-out views need."""

DEFAULT_NU = 25.0
"""``nu`` of a level that has no held-out samples (close to Gaussian, still robust far out)."""

_LOG_PI = math.log(math.pi)
_LOG_2 = math.log(2.0)


def _lift(x, n: int):
    """``x`` with ``n`` leading unit axes (explicit broadcasting)."""
    return x.reshape((1,) * n + x.shape)


def student_t_log_density(q, logdet, nu, k: int):
    """log t_nu in ``k`` dimensions from ``q = (g - mu)^T S^-1 (g - mu)`` and
    ``log|S|`` (same shapes, broadcast against ``nu``)."""
    return (gammaln(0.5 * (nu + k)) - gammaln(0.5 * nu) - 0.5 * k * (jnp.log(nu) + _LOG_PI)
            - 0.5 * logdet - 0.5 * (nu + k) * jnp.log1p(q / nu))


def chi2_from_normal(u: Float[ArrayLike, "*B"], nu: Float[ArrayLike, "*B"], steps: int = 8) -> Float[Array, "*B"]:
    """``w = F^-1_{chi2_nu}(Phi(u))``: a chi-square draw with ``nu`` degrees of
    freedom from one standard-normal number ``u`` (exact quantile transform).

    Start: Wilson-Hilferty, ``w ~ nu (1 - 2/(9 nu) + u sqrt(2/(9 nu)))^3`` (its
    base clipped at 0.05), or for ``u < 0`` the small-``w`` asymptote of the
    lower tail where it is smaller; then ``steps`` Newton steps in ``y = log w`` on the
    log of the tail on ``u``'s side (``log P(nu/2, w/2) = log Phi(u)`` for
    ``u < 0``, the upper tail otherwise), each step clipped to ``|dy| <= 1``.
    Branch-free (both tails are computed; ``where`` picks one)."""
    a = 2.0 / (9.0 * nu)
    base = jnp.maximum(1.0 - a + u * jnp.sqrt(a), 0.05)
    y = jnp.log(nu) + 3.0 * jnp.log(base)
    lower = u < 0
    target = jnp.where(lower, log_ndtr(u), log_ndtr(-u))
    half = 0.5 * nu
    # far in the lower tail P(nu/2, w/2) ~ (w/2)^(nu/2) / Gamma(nu/2 + 1): start there when lower
    y_small = _LOG_2 + (target + gammaln(half + 1.0)) / half
    y = jnp.where(lower, jnp.minimum(y, y_small), y)
    tiny = jnp.finfo(jnp.result_type(y)).tiny
    for _ in range(steps):
        x = jnp.exp(y)
        p = jnp.maximum(gammainc(half, 0.5 * x), tiny)
        q = jnp.maximum(gammaincc(half, 0.5 * x), tiny)
        log_tail = jnp.where(lower, jnp.log(p), jnp.log(q))
        log_px = half * (y - _LOG_2) - 0.5 * x - gammaln(half)   # log(pdf(w) w)
        slope = jnp.where(lower, jnp.exp(log_px - jnp.log(p)), -jnp.exp(log_px - jnp.log(q)))
        y = y - jnp.clip((log_tail - target) / slope, -1.0, 1.0)
    return jnp.exp(y)


@register_likelihood
class StudentT(Likelihood):
    """t_nu(g; mu[c, k], diag(scale2[c, k])) with ``nu[k]`` (module docstring).

    Attributes:
        mu: ``[V, C, L, K]`` locations (= means).
        scale2: ``[V, C, L, K]`` squared scales, strictly positive
            (covariance ``nu / (nu - 2) scale2``).
        nu: ``[V, L]`` degrees of freedom, ``> 2``.
    """

    kind: ClassVar[str] = "student-t"
    field_shapes: ClassVar[dict[str, str]] = {"mu": "V C L K", "scale2": "V C L K", "nu": "V L"}
    second_moments: ClassVar[str] = "diag"
    fit_options: ClassVar[tuple[str, ...]] = ("nu",)
    calibration_shapes: ClassVar[tuple[str, ...]] = ("nu",)

    mu: Float[ArrayLike, "*V C L K"]
    scale2: Float[ArrayLike, "*V C L K"]
    nu: Float[ArrayLike, "*V L"]

    @property
    def noise_dim(self) -> int:
        """K normal numbers for the direction, one for the chi-square."""
        return self.dim + 1

    def log_density(self, g: Float[ArrayLike, "*B K"]) -> Float[Array, "*B C L"]:
        n = g.ndim - 1
        d = g[..., None, None, :] - _lift(self.mu, n)
        q = jnp.sum(d * d / _lift(self.scale2, n), axis=-1)
        logdet = _lift(jnp.sum(jnp.log(self.scale2), axis=-1), n)
        return student_t_log_density(q, logdet, _lift(self.nu[None, :], n), self.dim)

    def sample(self, z: Float[ArrayLike, "C L J Z"]) -> Float[Array, "C L J K"]:
        """g = mu + sqrt(scale2) x / sqrt(w / nu), ``x = z[..., :K]``,
        ``w = chi2_from_normal(z[..., K], nu)``."""
        k = self.dim
        w = chi2_from_normal(z[..., k], jnp.broadcast_to(self.nu[None, :, None], z.shape[:-1]))
        r = jnp.sqrt(self.nu[None, :, None] / w)
        return self.mu[:, :, None, :] + jnp.sqrt(self.scale2)[:, :, None, :] * z[..., :k] * r[..., None]

    def mean(self) -> Float[Array, "C L K"]:
        return self.mu

    def variance(self) -> Float[Array, "C L K"]:
        """``nu / (nu - 2) scale2``."""
        return self.scale2 * (self.nu / (self.nu - 2.0))[None, :, None]

    def covariance(self) -> Float[Array, "C L K K"]:
        v = self.variance()
        return jnp.einsum("...k,kl->...kl", v, jnp.eye(v.shape[-1], dtype=v.dtype))

    def scaled(self, factor: Float[ArrayLike, " L"]) -> "StudentT":
        """scale2[c, k] * factor[k] (the covariance scales with it; nu unchanged)."""
        return StudentT(self.mu, self.scale2 * factor[None, :, None], self.nu)

    def shape_shifted(self, shape: Float[ArrayLike, "L P"]) -> "StudentT":
        """``nu' = 2 + (nu - 2) exp(shape[:, 0])`` (an offset on ``log(nu - 2)``), scale kept."""
        return StudentT(self.mu, self.scale2, 2.0 + (self.nu - 2.0) * jnp.exp(shape[:, 0]))

    def scaling_terms(self, g: Float[ArrayLike, "N K"]):
        """``(q [N, C, L], log|scale2| [C, L])``."""
        d = g[:, None, None, :] - self.mu[None]
        return jnp.sum(d * d / self.scale2[None], axis=-1), jnp.sum(jnp.log(self.scale2), axis=-1)

    def scaled_log_density(self, terms, log_factor):
        return self.calibrated_log_density(terms, log_factor, jnp.zeros((log_factor.shape[0], 1), log_factor.dtype))

    def calibrated_log_density(self, terms, log_factor, shape):
        """``scaled(exp(log_factor)).shape_shifted(shape).log_density(g)`` from the terms."""
        q, logdet = terms
        nu = (2.0 + (self.nu - 2.0) * jnp.exp(shape[:, 0]))[None, None, :]
        return student_t_log_density(q * jnp.exp(-log_factor)[None, None, :],
                                     (logdet + self.dim * log_factor[None, :])[None], nu, self.dim)

    def problems(self) -> list[tuple[str, str]]:
        out = []
        nu = np.asarray(self.nu)
        if np.any(nu <= 0):
            out.append(("nu", "has non-positive degrees of freedom"))
        elif np.any(nu <= 2):
            out.append(("nu", "has degrees of freedom <= 2 (no finite covariance)"))
        if np.any(np.asarray(self.scale2) <= 0):
            out.append(("scale2", "has non-positive scales"))
        return out

    @classmethod
    def holdout_fraction(cls, nu="auto", **options) -> float:
        """A fifth of the samples when ``nu`` is chosen on held-out samples."""
        return 0.2 if nu == "auto" else 0.0

    @classmethod
    def fit(cls, mean, second, floor, *, nu="auto", holdout=None) -> "StudentT":
        """``mu = mean``, ``scale2 = max(var, floor) (nu - 2) / nu`` (moment matched)
        and ``nu`` given or, for ``"auto"``, per level the :data:`NU_GRID` value of
        the highest held-out log-likelihood (:data:`DEFAULT_NU` without held-out
        samples at that level).

        Raises:
            ValueError: ``nu`` is neither ``"auto"`` nor a number > 2.
        """
        mean, var = np.asarray(mean, np.float64), np.asarray(second, np.float64)
        floor = np.asarray(floor, np.float64)[..., None]
        var = np.maximum(var, floor)
        c, n_levels, k = mean.shape
        if nu == "auto":
            nus = np.full(n_levels, DEFAULT_NU)
            if holdout is not None:
                g, cls_, lev = (np.asarray(x) for x in holdout)
                for level in range(n_levels):
                    sel = lev == level
                    if np.any(sel):
                        nus[level] = _best_nu(g[sel], mean[cls_[sel], level], var[cls_[sel], level],
                                              floor[cls_[sel], level], k)
        else:
            try:
                value = float(nu)
            except (TypeError, ValueError):
                value = float("nan")
            if not value > 2.0 or not math.isfinite(value):
                raise ValueError(f"student-t: nu must be 'auto' or a number > 2, got {nu!r}")
            nus = np.full(n_levels, value)
        scale2 = np.maximum(var * ((nus - 2.0) / nus)[None, :, None], floor)
        return cls(mean, scale2, nus)


def _best_nu(g, mu, var, floor, k: int) -> float:
    """The :data:`NU_GRID` value of the highest summed log-density of the rows ``g``
    under their components (moment-matched scale), NumPy float64."""
    from scipy.special import gammaln as np_gammaln  # training only: `import jaxrecog` does not load SciPy

    d2 = (g - mu) ** 2
    best, best_ll = DEFAULT_NU, -np.inf
    for nu in NU_GRID:
        s2 = np.maximum(var * (nu - 2.0) / nu, floor)
        q = np.sum(d2 / s2, axis=-1)
        ll = np.sum(np_gammaln(0.5 * (nu + k)) - np_gammaln(0.5 * nu) - 0.5 * k * math.log(nu * math.pi)
                    - 0.5 * np.sum(np.log(s2), axis=-1) - 0.5 * (nu + k) * np.log1p(q / nu))
        if ll > best_ll:
            best, best_ll = nu, ll
    return float(best)
